"""Bad models and bad settings raise located, typed errors."""

import os
import re

import numpy as np
import pytest

import hybsim

GOOD = """model ball
param g = 9.81
state h = 1, v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
sim { T = 2 }
"""


def test_unknown_name_is_a_model_error_with_file_line_col(tmp_path):
    path = tmp_path / "bad.hyb"
    path.write_text(GOOD.replace("v' = -g", "v' = -gg"))
    with pytest.raises(hybsim.ModelError) as info:
        hybsim.load(path)
    err = info.value
    text = str(err)
    # The rendered report: error[code], `┌─ file:line:col`, the line, a caret.
    assert re.search(r"error\[E\d+\]", text), text
    assert f"{path}:4:" in text, text
    assert "v' = -gg" in text and "^" in text, text
    d = err.diagnostics[0]
    assert d["file"] == str(path)
    assert d["line"] == 4
    assert d["col"] == GOOD.splitlines()[3].index("-g") + 2  # 1-based, at `gg`
    assert d["severity"] == "error" and d["code"].startswith("E")
    assert "gg" in d["message"]


def test_syntax_error_in_source_text_names_the_string():
    with pytest.raises(hybsim.ModelError) as info:
        hybsim.load(GOOD.replace("flow {", "flow {{"), name="inline.hyb")
    assert "inline.hyb:4:" in str(info.value)
    assert info.value.diagnostics[0]["line"] == 4


def test_every_error_is_reported_at_once():
    src = GOOD.replace("v' = -g", "v' = -gg").replace("-0.8 * v", "-0.8 * w")
    with pytest.raises(hybsim.ModelError) as info:
        hybsim.load(src)
    lines = sorted(d["line"] for d in info.value.diagnostics)
    assert lines == [4, 5]


def test_bad_override_is_a_model_error():
    with pytest.raises(hybsim.ModelError, match="override"):
        hybsim.load(GOOD, set={"g": "1 +"})
    with pytest.raises(hybsim.ModelError):
        hybsim.load(GOOD, set={"nope": 1.0})


def test_missing_file():
    with pytest.raises(FileNotFoundError):
        hybsim.load("no/such/model.hyb")


def test_one_line_model_text_is_a_path_and_the_error_says_so():
    # `load("model m; ...")` was "No such file or directory: 'model m; ...'".
    text = "model m; state x = 1; flow { x' = -x }; sim { T = 1 }"
    with pytest.raises(FileNotFoundError, match="a str without a line break is a path") as err:
        hybsim.load(text)
    assert err.value.filename == text
    assert hybsim.load(text + "\n").run().termination.cause == "horizon_t"


@pytest.mark.parametrize(
    "kwargs, key",
    [
        ({"T": -1.0}, "T"),
        ({"rtol": -1.0}, "rtol"),
        ({"atol": -1.0}, "atol"),
        ({"solver": "rk4", "step": -1.0}, "step"),
        ({"dt_out": 0.0}, "dt_out"),
        ({"max_step": 0.0}, "max_step"),
        ({"event_tol": 1.0}, "event_tol"),
        ({"guard_checks": 100}, "guard_checks"),
        ({"zeno_max_rate": -1.0}, "zeno_max_rate"),
        ({"zeno_window": 1}, "zeno_window"),
        ({"max_total_jumps": 0}, "max_total_jumps"),
    ],
)
def test_bad_setting_names_the_keyword(kwargs, key):
    # The error names the keyword the caller passed, never the engine's field
    # (`horizon_t`, `solver.rtol`, `solver.h`).
    m = hybsim.load(GOOD)
    with pytest.raises(ValueError) as err:
        m.run(**kwargs)
    msg = str(err.value)
    assert f"invalid setting `{key}`:" in msg, msg
    assert "horizon_" not in msg and "solver." not in msg, msg


def test_bad_settings():
    m = hybsim.load(GOOD)
    with pytest.raises(TypeError, match="unexpected keyword `dtout`"):
        m.run(dtout=0.1)
    with pytest.raises(ValueError, match="solver `rk5`"):
        m.run(solver="rk5")
    with pytest.raises(ValueError, match="invalid setting `T`: must be finite and > 0, got -1"):
        m.run(T=-1.0)
    with pytest.raises(ValueError, match="`step` applies to the fixed-step solvers"):
        m.run(step=1e-3)
    # A fixed-step solver without a step takes the sim block's default (1e-3).
    a, b = m.run(solver="rk4"), m.run(solver="rk4", step=1e-3)
    assert len(a.jumps.t) > 0 and (a.jumps.t == b.jumps.t).all() and (a["h"] == b["h"]).all()
    with pytest.raises(TypeError, match="`J`"):
        m.run(J="many")
    with pytest.raises(ValueError, match="linear_solver `lu`"):
        m.run(linear_solver="lu")


@pytest.mark.parametrize(
    "kwargs, key",
    [
        ({"dt_out": 1e-300}, "dt_out"),
        ({"max_step": 1e-300}, "max_step"),
        ({"solver": "rk4", "step": 1e-300}, "step"),
    ],
)
def test_sizes_forced_by_keywords_are_refused_before_running(kwargs, key):
    # Was a run that never ended: the keywords apply after the model's check.
    m = hybsim.load(GOOD)
    with pytest.raises(ValueError, match=f"`{key}`: .*over the limit of"):
        m.run(**kwargs)


def test_integers_out_of_range_are_value_errors_naming_the_keyword():
    # Were OverflowError / TypeError "can't convert negative int to unsigned".
    m = hybsim.load(GOOD)
    for kwargs, key in [
        ({"J": -1}, "J"),
        ({"guard_checks": -2}, "guard_checks"),
        ({"seed": -1}, "seed"),
        ({"seed": 2**64}, "seed"),
    ]:
        with pytest.raises(ValueError, match=f"`{key}`"):
            m.run(**kwargs)
    with pytest.raises(ValueError, match="`seed`"):
        m.sweep(runs=2, seed=-5)
    with pytest.raises(TypeError, match="`seed`"):
        m.run(seed=1.5)
    assert m.run(seed=2**64 - 1).seed == 2**64 - 1


def test_counts_out_of_range_are_value_errors_naming_the_argument():
    # `test(cases=-1)` was an OverflowError, `cases=0` a vacuous pass.
    m = hybsim.load(GOOD + "property up: always h >= -1e-9\n")
    for kwargs, key in [
        ({"cases": -1}, "cases"),
        ({"cases": 0}, "cases"),
        ({"cases": 2**64}, "cases"),
        ({"max_shrink": -1}, "max_shrink"),
        ({"seed": -1}, "seed"),
    ]:
        with pytest.raises(ValueError, match=f"`{key}`: must be"):
            m.test(**kwargs)
    with pytest.raises(TypeError, match="`cases`"):
        m.test(cases=2.5)
    for kwargs, key in [({"runs": -1}, "runs"), ({"runs": 0}, "runs"), ({"threads": -1}, "threads")]:
        with pytest.raises(ValueError, match=f"`{key}`: must be"):
            m.sweep(**kwargs)
    assert m.test(cases=1, max_shrink=0).cases_run == 1


def test_a_solver_that_cannot_integrate_white_noise_is_a_value_error():
    # Was a SimulationError naming the Rust API's `Solver::EulerMaruyama { h }`.
    ou = hybsim.load("model ou\nnoise w ~ wiener(1)\nstate x = 0\nflow { x' = -x + w }\nsim { T = 0.1 }\n")
    with pytest.raises(ValueError, match='solver="dopri5".*solver="euler_maruyama"'):
        ou.run(solver="dopri5")
    assert ou.run(solver="euler_maruyama").termination.cause == "horizon_t"


def test_runtime_failure_points_at_the_flow_equation():
    src = """model blowup
state x = 1
flow { x' = x^2 }
sim { T = 2 }
"""
    with pytest.raises(hybsim.SimulationError) as info:
        hybsim.load(src, name="blowup.hyb").run()
    err = info.value
    assert "blowup.hyb:3:" in str(err), str(err)
    assert err.diagnostics[0]["line"] == 3
    # The solution up to the failure.
    assert isinstance(err.partial, hybsim.Solution)
    assert len(err.partial) > 0 and err.partial.t[-1] < 1.0 + 1e-3


def test_model_from_a_path_says_to_load_it():
    # A first guess of new users: the class itself, with a path.
    with pytest.raises(TypeError, match=r"hybsim\.load\('ball\.hyb'\)"):
        hybsim.Model("ball.hyb")


def test_a_solution_past_the_memory_is_a_memory_error():
    # With the output grid's limit lifted, a trillion samples cannot be held in memory: the run
    # stops with MemoryError where a failed allocation aborted the interpreter. In a child
    # process whose address space is capped, so that the machine's memory is not at stake.
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(
        """
        import resource
        import hybsim
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
        m = hybsim.load(
            "model big\\nstate x = zeros(100, 1)\\nflow { x' = -x }\\n"
            "sim { T = 1e9; dt_out = 1e-3; max_output_points = 1e13 }\\n"
        )
        try:
            m.run()
        except MemoryError as e:
            print("MemoryError:", e)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "MemoryError: the solution does not fit in memory" in out.stdout, out.stdout


def test_jump_horizon_is_taken_as_a_sim_block_takes_it():
    # `J = 1e6` and `J = inf` are valid in a sim block and on the command line;
    # run(J=1e6) was a TypeError.
    m = hybsim.load(GOOD)
    assert len(m.run(J=3.0).jumps.t) == len(m.run(J=3).jumps.t) == 3
    assert len(m.run(J=float("inf")).jumps.t) == len(m.run().jumps.t)
    for bad in [2.5, -1.0, float("nan")]:
        with pytest.raises(ValueError, match="`J`: a whole number of jumps"):
            m.run(J=bad)


def test_misused_overrides_and_indices_are_typed_errors_naming_the_value():
    # NaN has no spelling in the model language: it was sent as `nan`, an
    # unknown name (E0508); a list of pairs failed with AttributeError.
    for bad in (float("nan"), [1.0, float("nan")], np.float32("nan")):
        with pytest.raises(ValueError, match=r"set\['g'\]: NaN"):
            hybsim.load(GOOD, set={"g": bad})
    with pytest.raises(TypeError, match="set= takes a dict"):
        hybsim.load(GOOD, set=[("g", 1.0)])
    with pytest.raises(TypeError, match=r"set\['g'\]: a number"):
        hybsim.load(GOOD, set={"g": object()})
    # numpy reads None as NaN: it was refused as "NaN is not a value".
    with pytest.raises(TypeError, match=r"set\['g'\]: None is not a value"):
        hybsim.load(GOOD, set={"g": None})
    sol = hybsim.load(GOOD, set={"g": np.float64(9.81)}).run()
    for key in (0, None, 1.5):
        with pytest.raises(TypeError, match="indexed by a component's name"):
            sol[key]


def test_exact_affine_takes_the_words_of_the_sim_block():
    # Only a bool was taken ("'str' object is not an instance of 'bool'"), so
    # "auto" could not undo a model's `exact_affine = off`.
    m = hybsim.load(GOOD.replace("sim { T = 2 }", "sim { T = 2; exact_affine = off }"))
    base = m.run()
    for word, flag in [("off", False), ("on", True)]:
        a, b = m.run(exact_affine=word), m.run(exact_affine=flag)
        assert a.t.tobytes() == b.t.tobytes() and a.x.tobytes() == b.x.tobytes(), word
    assert m.run(exact_affine="off").x.tobytes() == base.x.tobytes()
    assert len(m.run(exact_affine="auto").jumps) == len(base.jumps)
    with pytest.raises(ValueError, match='exact_affine `yes`: use "auto", "on" or "off"'):
        m.run(exact_affine="yes")
    with pytest.raises(TypeError, match="`exact_affine`: .* or a bool, not float"):
        m.run(exact_affine=1.5)


def test_bools_are_not_numbers_of_the_sim_keywords():
    # Python's bool is an int: `T=True` ran to T = 1, `J=True` one jump.
    m = hybsim.load(GOOD)
    for key in ("T", "J", "max_step", "guard_checks"):
        with pytest.raises(TypeError, match=f"`{key}`: a bool is not a value"):
            m.run(**{key: True})


def test_an_output_read_out_of_range_raises_when_read():
    # `sol.y` held NaN where `hybsim run --csv` stops with E0604 at the index:
    # outputs are evaluated when first read, and the fault went unnoticed.
    src = """model idx
param tk = [1; 2; 3]
state k = 1
every 0.5 { k+ = k + 1 }
output y = tk[k]
sim { T = 3 }
"""
    sol = hybsim.load(src).run()
    assert sol.termination.cause == "horizon_t"  # the run itself never reads `y`
    for read in (lambda: sol.y, lambda: sol["y"], sol.to_pandas):
        with pytest.raises(hybsim.SimulationError) as err:
            read()
        msg = str(err.value)
        assert "E0604" in msg and "index 4 is out of range 1..3 at (t = 1.5, j = 3)" in msg, msg
        d = err.value.diagnostics[0]
        assert (d["code"], d["line"], d["col"]) == ("E0604", 5, 12), d
    # Within range the outputs are the table's entries.
    ok = hybsim.load(src).run(T=1.2)
    assert list(ok["y"]) == list(ok["k"])


def test_a_model_file_is_read_as_the_command_line_reads_it(tmp_path):
    # A file that is not UTF-8 was UnicodeDecodeError at a byte offset; a
    # path that never ends (/dev/zero) was read until the memory ran out.
    bad = tmp_path / "latin.hyb"
    bad.write_bytes(b"model m\nstate x = 1 # caf\xe9\nflow { x' = -x }\n")
    with pytest.raises(ValueError, match=r"latin.hyb`: line 2, column 18: byte 0xe9 is not UTF-8"):
        hybsim.load(bad)
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match="more than 16 MiB, the limit for a model's text"):
            hybsim.load("/dev/zero")
    with pytest.raises(ValueError, match="more than 16 MiB"):
        hybsim.load("model m\n" + "#" * (16 << 20))
