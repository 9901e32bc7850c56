"""Solutions as arrays equal what `hybsim run --csv` writes, bit for bit."""

import csv
import subprocess

import numpy as np
import pytest

import hybsim


def run_csv(hybsim_bin, model, tmp_path, *flags):
    out = tmp_path / "run.csv"
    subprocess.run(
        [str(hybsim_bin), "run", str(model), "--no-mcap", "-q", "--csv", str(out), *flags],
        check=True,
        capture_output=True,
    )
    with open(out, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def assert_same_as_csv(sol, header, rows):
    assert header[:3] == ["t", "j", "kind"]
    assert header[3:] == sol.names + sol.output_names
    assert len(rows) == len(sol)
    # float() of Rust's shortest round-trip text is the exact value.
    cols = list(zip(*rows))
    np.testing.assert_array_equal(sol.t, np.array([float(v) for v in cols[0]]))
    np.testing.assert_array_equal(sol.j, np.array([int(v) for v in cols[1]]))
    assert list(sol.kind) == list(cols[2])
    for k, name in enumerate(header[3:]):
        expect = np.array([float(v) for v in cols[3 + k]])
        got = sol[name]
        assert got.tobytes() == expect.tobytes(), name


def test_ball_bit_for_bit(hybsim_bin, models, tmp_path):
    header, rows = run_csv(hybsim_bin, models / "bouncing_ball.hyb", tmp_path)
    sol = hybsim.load(models / "bouncing_ball.hyb").run()
    assert_same_as_csv(sol, header, rows)
    assert len(sol.jumps) == sum(1 for r in rows if r[2] == "pre_jump") == 6
    assert sol.termination.cause == "horizon_t"


def test_ball_overrides_and_flags_bit_for_bit(hybsim_bin, models, tmp_path):
    header, rows = run_csv(
        hybsim_bin,
        models / "bouncing_ball.hyb",
        tmp_path,
        "--set",
        "lambda=0.7",
        "--T",
        "1.5",
        "--dt-out",
        "0.01",
        "--solver",
        "dop853",
        "--rtol",
        "1e-9",
    )
    sol = hybsim.load(models / "bouncing_ball.hyb", set={"lambda": 0.7}).run(
        T=1.5, dt_out=0.01, solver="dop853", rtol=1e-9
    )
    assert_same_as_csv(sol, header, rows)
    assert sol.termination.cause == "horizon_t"


def test_paper_model_with_random_initial_values_bit_for_bit(hybsim_bin, models, tmp_path):
    # Trimpe & D'Andrea: initial state and noise drawn from the run's seed.
    header, rows = run_csv(
        hybsim_bin, models / "variance_triggering.hyb", tmp_path, "--seed", "7", "--T", "20.5"
    )
    sol = hybsim.load(models / "variance_triggering.hyb").run(seed=7, T=20.5)
    assert_same_as_csv(sol, header, rows)
    assert sol.seed == 7
    # Another seed gives another solution.
    other = hybsim.load(models / "variance_triggering.hyb").run(seed=8, T=20.5)
    assert not np.array_equal(other.x, sol.x)


def test_jumps_table_matches_the_samples(models):
    sol = hybsim.load(models / "bouncing_ball.hyb").run()
    pre = sol.kind == "pre_jump"
    post = sol.kind == "post_jump"
    np.testing.assert_array_equal(sol.jumps.t, sol.t[pre])
    np.testing.assert_array_equal(sol.jumps.j, sol.j[pre])
    np.testing.assert_array_equal(sol.jumps.pre, sol.x[pre])
    np.testing.assert_array_equal(sol.jumps.post, sol.x[post])
    assert set(sol.jumps.rule_name) == {"impact"}
    # v+ = -lambda * v at every impact.
    np.testing.assert_allclose(sol.jumps.post[:, 1], -0.8 * sol.jumps.pre[:, 1])
    df = sol.jumps.to_pandas()
    assert list(df.columns) == ["rule", "t", "j", "pre.h", "pre.v", "post.h", "post.v"]
    # The jump states are gathered from the samples on first use; a
    # restriction keeps them paired with their jumps.
    part = sol.restrict_t(0.5, 3.0)
    keep = (sol.jumps.t >= 0.5) & (sol.jumps.t <= 3.0)
    assert 0 < keep.sum() < len(sol.jumps)
    np.testing.assert_array_equal(part.jumps.pre, sol.jumps.pre[keep])
    np.testing.assert_array_equal(part.jumps.post, sol.jumps.post[keep])
    np.testing.assert_array_equal(part.jumps.pre, part.x[part.kind == "pre_jump"])


FAMILY_MODEL = """model rooms
subsystem Room(a = 0.5, x0 = 20) {
    state x = x0, q = 1
    flow { x' = -a * (x - 5) + 12 * q } in (q == 1 && x <= 22) || (q == 0 && x >= 18)
    jump off when q == 1 && x >= 22 { q+ = 0 }
    jump on when q == 0 && x <= 18 { q+ = 1 }
    output heating = q, excess = x - 20
}
for i in 1..3 { r[i] = Room(x0 = 18 + i) }
state n = 0
noise d ~ normal(0, 1) every 0.5
every 1 { n+ = n + 1 }
output load = sum(i in 1..3: r[i].heating) + 0 * d
sim { T = 4 }
"""


def test_to_pandas_is_the_csv_of_a_model_with_families_and_timers(hybsim_bin, tmp_path):
    # Families of instances with two states each (grouped by family in the CSV, interleaved
    # in the state vector), `every` and held `noise` (their timers are not CSV columns).
    model = tmp_path / "rooms.hyb"
    model.write_text(FAMILY_MODEL)
    header, rows = run_csv(hybsim_bin, model, tmp_path, "--log-rules", "*")
    df = hybsim.load(model).run().to_pandas()
    assert list(df.columns) == header
    assert len(df) == len(rows)
    cols = list(zip(*rows))
    for k, name in enumerate(header):
        if name == "kind":
            assert list(df[name]) == list(cols[k])
        else:
            expect = np.array([float(v) for v in cols[k]])
            assert df[name].to_numpy(dtype=float).tobytes() == expect.tobytes(), name


def test_solutions_show_only_the_declared_states(hybsim_bin, tmp_path):
    # The timers the language adds for `every` and held `noise` (`step.timer`, `d.redraw.timer`)
    # are not states of the user's: not in `names`, `x`, the jump table, nor the model's names.
    model = tmp_path / "rooms.hyb"
    model.write_text(FAMILY_MODEL)
    m = hybsim.load(model)
    sol = m.run()
    header, _ = run_csv(hybsim_bin, model, tmp_path, "--log-rules", "*")
    states = header[3 : 3 + len(sol.names)]
    assert sol.names == states == m.state_names
    assert not any("timer" in n for n in sol.names)
    assert sol.x.shape == (len(sol), len(sol.names))
    np.testing.assert_array_equal(sol["n"], sol.x[:, sol.names.index("n")])
    jumps = sol.jumps.to_pandas()
    assert list(jumps.columns) == ["rule", "t", "j"] + [f"pre.{n}" for n in states] + [
        f"post.{n}" for n in states
    ]
    assert sol.jumps.pre.shape == (len(sol.jumps), len(states))
    # `every 1 { n+ = n + 1 }`: n counts the `step` jumps.
    steps = jumps[jumps.rule == "step"]
    np.testing.assert_array_equal(steps["post.n"], steps["pre.n"] + 1)
    # The outputs are still evaluated from these states.
    np.testing.assert_array_equal(sol["r.heating[1]"], sol["r.q[1]"])
    part = sol.restrict_t(1.0, 2.0)
    assert part.names == sol.names and part.x.shape[1] == len(states)


def test_to_pandas_has_the_csv_columns(hybsim_bin, models, tmp_path):
    header, _ = run_csv(hybsim_bin, models / "bouncing_ball.hyb", tmp_path)
    df = hybsim.load(models / "bouncing_ball.hyb").run().to_pandas()
    assert list(df.columns) == header
    try:
        import polars  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="polars"):
            hybsim.load(models / "bouncing_ball.hyb").run().to_polars()
