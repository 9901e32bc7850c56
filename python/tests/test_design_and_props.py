"""Design results equal `hybsim design --json`; property tests return the
shrunk counterexample and its replay."""

import json
import subprocess

import numpy as np
import pytest

import hybsim


def design_json(hybsim_bin, model, *flags):
    out = subprocess.run(
        [str(hybsim_bin), "design", str(model), "--json", *flags],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout)


@pytest.mark.parametrize("model", ["appendix_f.hyb"])
def test_design_equals_the_cli_json(hybsim_bin, models, model):
    cli = design_json(hybsim_bin, models / model)
    py = hybsim.load(models / model).design()
    assert list(py) == list(cli)
    for name, block in cli.items():
        got = py[name]
        for key in ("name", "status", "objective"):
            if key in block:
                assert got[key] == block[key], key
        assert list(got["results"]) == list(block["results"])
        for r, value in block["results"].items():
            v = got["results"][r]
            # Bit for bit: JSON numbers are printed in shortest round-trip form.
            assert np.asarray(v).tobytes() == np.asarray(value, dtype=np.float64).tobytes(), r
        assert got["summary"].startswith(("design ", "check "))
        assert got["check_failed"] is False


def test_design_of_a_small_block_and_the_compiled_parameters():
    src = """model m
design d {
    scalar g
    minimize g
    g >= 2
    param gmin = g
}
design lmi {
    sym P[2]
    P >= eye(2)
    minimize trace(P)
    param Pmin = P
}
state x = 0
"""
    m = hybsim.load(src)
    d = m.design()
    assert list(d) == ["d", "lmi"]
    assert abs(d["d"]["results"]["gmin"] - 2.0) < 1e-6
    P = d["lmi"]["results"]["Pmin"]
    assert P.shape == (2, 2)
    np.testing.assert_allclose(P, np.eye(2), atol=1e-6)
    # Results feed the model's parameters (as `hybsim run` compiles them).
    assert m.parameters["gmin"] == d["d"]["results"]["gmin"]
    np.testing.assert_array_equal(m.parameters["Pmin"], P)


FALSE_PROPERTY = """model ball
state h ~ uniform(0, 2), v = 0
flow { h' = v; v' = -9.81 } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
property low: always h <= 1.5
property ground: always h >= -1e-9
sim { T = 2 }
"""


def test_false_property_returns_its_shrunk_counterexample(tmp_path):
    path = tmp_path / "ball.hyb"
    path.write_text(FALSE_PROPERTY)
    m = hybsim.load(path)
    assert m.property_names == ["low", "ground"]
    report = m.test(cases=50, seed=7)
    assert not report and report.outcome == "failed"
    cx = report.counterexample
    assert cx.property == "low"
    # Shrunk to an initial height just above 1.5, failing at (0, 0).
    assert 1.5 < cx.inputs["h"] < 1.5 + 1e-9
    assert cx.sampled["h"] > cx.inputs["h"]
    assert (cx.t, cx.j) == (0.0, 0)
    assert cx.state[0] == cx.inputs["h"]
    assert cx.replay.startswith(f"hybsim run {path} --seed {cx.seed} --set h=")
    assert "counterexample" in str(report) and "replay: hybsim run" in str(report)
    # Replaying the case gives the violation.
    again = hybsim.load(path, set=cx.set).run(**cx.run_kwargs())
    assert again["h"][0] == cx.inputs["h"] > 1.5


def test_a_text_models_replay_reads_its_text_from_stdin(hybsim_bin, tmp_path):
    # A model given as text has no file: its replay command reads `-`, the text on stdin (it
    # named '<string>'), and so do a sweep's commands.
    m = hybsim.load(FALSE_PROPERTY)
    cx = m.test(cases=50, seed=7, properties=["low"]).counterexample
    assert cx.replay_args[:3] == ["hybsim", "run", "-"]
    out = subprocess.run([hybsim_bin, *cx.replay_args[1:], "--csv", "replay.csv"],
                         input=m.source, text=True, capture_output=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rows = (tmp_path / "replay.csv").read_text().splitlines()
    h = rows[0].split(",").index("h")
    assert float(rows[1].split(",")[h]) == cx.inputs["h"]
    sw = m.sweep(grid={"h": [1.0]}, runs=1)
    assert sw.runs["command"][0].startswith("hybsim run - --set h=1 --seed ")


def test_every_failing_property_has_its_counterexample():
    # `low` fails from h > 1.5 at (0, 0); `slow` from the first impact (|v| > 5 needs h > 1.27).
    m = hybsim.load(FALSE_PROPERTY.replace("property ground: always h >= -1e-9",
                                           "property slow: always abs(v) <= 5"))
    report = m.test(cases=50, seed=7)
    assert report.outcome == "failed" and not report
    assert [cx.property for cx in report.counterexamples] == ["low", "slow"]
    assert report.counterexample is report.counterexamples[0]
    slow = report.counterexamples[1]
    assert 5 ** 2 / (2 * 9.81) < slow.inputs["h"] < 5 ** 2 / (2 * 9.81) + 1e-6
    text = str(report)
    assert text.count("FAILED  ") == 2
    assert text.count("replay: hybsim run") == 2 and "2 counterexamples" in text
    # One property failing: one counterexample, as before.
    one = m.test(cases=50, seed=7, properties=["low"])
    assert [cx.property for cx in one.counterexamples] == ["low"] and "counterexample:" in str(one)


def test_true_property_passes_and_names_are_checked():
    m = hybsim.load(FALSE_PROPERTY)
    report = m.test(cases=20, properties=["ground"])
    assert report and report.passed and report.counterexample is None
    assert report.counterexamples == []
    assert report.cases_run == 20
    assert "ok  ground" in str(report)
    with pytest.raises(ValueError, match="it declares: low, ground"):
        m.test(properties=["nope"])
    with pytest.raises(ValueError, match="declares no property"):
        hybsim.load(FALSE_PROPERTY.replace("property", "# property")).test()


def test_a_model_without_random_draws_is_tested_on_one_case():
    # No random initial value, noise or draw: every case would be the same run (as `hybsim test`).
    fixed = "model b\nstate h = 1, v = 0\nflow { h' = v; v' = -9.81 }\n" \
            "jump bounce when h <= 0 && v < 0 { v+ = -0.8 * v }\nsim { T = 2 }\n" \
            "property ground: always h >= -1e-9\n"
    m = hybsim.load(fixed)
    assert m.test().cases_run == 1
    assert m.test(cases=5).cases_run == 5
    # The random model of the tests above keeps the default 100.
    assert hybsim.load(FALSE_PROPERTY).test(properties=["ground"]).cases_run == 100


def test_a_property_named_twice_is_tested_once():
    # properties=["ground", "ground"] tested and listed `ground` twice.
    m = hybsim.load(
        "model ball\nstate h ~ uniform(0, 2), v = 0\nflow { h' = v; v' = -9.81 } in h >= 0\n"
        "jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }\n"
        "property ground: always h >= -1e-9\nsim { T = 1 }\n"
    )
    with pytest.raises(ValueError, match=r"properties=\[\] selects no property"):
        m.test(cases=3, properties=[])
    report = m.test(cases=3, properties=["ground", "ground"])
    assert report.passed and len(report.properties) == 1, report.properties
    assert report.properties[0].startswith("ground:")
