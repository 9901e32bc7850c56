"""`Model.sweep` runs what `hybsim sweep` runs: the same rows, seeds and
metric values bit for bit, the model's `sweep` block as defaults, failures
as rows and bad grids as exceptions."""

import csv
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

import hybsim

# A ball dropped from a random height: each run's metrics depend on its seed.
BALL = """model ball
param g = 9.81, lambda = 0.8
state h = uniform(1, 2), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
metric bounces = count(impact), peak = max(h)
sim { T = 2 }
sweep { lambda in [0.7, 0.9]; runs = 3; seed = 11 }
"""


@pytest.fixture
def ball_file(tmp_path):
    path = tmp_path / "ball.hyb"
    path.write_text(BALL)
    return path


def number(text):
    """A CSV cell as a float: the shortest round-trip text is the exact value; empty is missing."""
    return float(text) if text else np.nan


def assert_exactly(got, texts, what):
    expect = np.array([number(v) for v in texts])
    np.testing.assert_array_equal(np.asarray(got, dtype=np.float64), expect, err_msg=what)
    finite = np.isfinite(expect)
    assert np.asarray(got, dtype=np.float64)[finite].tobytes() == expect[finite].tobytes(), what


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_rows_equal_the_command_line_sweep(hybsim_bin, ball_file, tmp_path):
    out = tmp_path / "out"
    subprocess.run(
        [str(hybsim_bin), "sweep", str(ball_file), "-o", str(out), "-q",
         "--grid", "lambda=0.5:0.2:0.9", "--runs", "4", "--seed", "5"],
        check=True,
        capture_output=True,
    )
    sw = hybsim.load(ball_file).sweep(grid={"lambda": "0.5:0.2:0.9"}, runs=4, seed=5, threads=2)
    header, rows = read_csv(out / "runs.csv")
    assert list(sw.runs) == header
    assert len(sw.runs) == len(rows) == 12
    cols = dict(zip(header, zip(*rows)))
    np.testing.assert_array_equal(sw.runs["seed"], np.array([int(s) for s in cols["seed"]], dtype=np.uint64))
    assert list(sw.runs["status"]) == list(cols["status"])
    assert list(sw.runs["command"]) == list(cols["command"])
    # lambda = 0.5 goes Zeno before T = 2: those runs ended early, without metrics, in both.
    assert {"ended", "completed"} <= set(cols["status"])
    for m in ("lambda", "bounces", "peak"):
        assert_exactly(sw.runs[m], cols[m], m)
    pheader, prow = read_csv(out / "points.csv")
    assert list(sw.points) == pheader
    for k, name in enumerate(pheader):
        assert_exactly(sw.points[name], [r[k] for r in prow], name)


def test_the_sweep_block_gives_the_defaults(ball_file):
    sw = hybsim.sweep(ball_file)
    assert sw.axes == ["lambda"] and sw.metrics == ["bounces", "peak"]
    assert (sw.seed, sw.runs_per_point) == (11, 3)
    assert len(sw.points) == 2 and len(sw.runs) == 6
    assert list(sw.points["completed"]) == [3, 3]
    # A less lively ball bounces more often before T = 2 (its bounces are shorter).
    assert sw.points["bounces_mean"][0] > sw.points["bounces_mean"][1]
    # Explicit arguments win over the block; no grid at all is a plain Monte Carlo.
    mc = hybsim.load(ball_file).sweep(grid=[], runs=5)
    assert mc.axes == [] and len(mc.points) == 1 and len(mc.runs) == 5
    # Same seed, same rows, whatever the number of threads.
    one = hybsim.load(ball_file).sweep(threads=1)
    assert one.runs["peak"].tobytes() == sw.runs["peak"].tobytes()


def test_tables_convert_to_pandas(ball_file):
    pd = pytest.importorskip("pandas")
    sw = hybsim.sweep(ball_file)
    df = sw.runs.to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == 6
    assert df["seed"].dtype == np.uint64 and df["peak"].dtype == np.float64
    assert list(sw.points.to_pandas().columns)[:4] == ["point", "lambda", "runs", "completed"]


def test_failed_runs_are_rows(ball_file):
    # A negative horizon makes the point invalid: its runs fail, the others complete.
    sw = hybsim.load(ball_file).sweep(grid={"T": [1.0, -1.0]}, runs=2)
    assert list(sw.runs["status"]) == ["completed", "completed", "failed", "failed"]
    assert sw.failed == [2, 3]
    assert list(sw.runs["cause"])[2] == "model_error"
    assert np.isnan(sw.runs["bounces"][2])


def test_bad_grids_raise(ball_file):
    model = hybsim.load(ball_file)
    with pytest.raises(hybsim.ModelError) as err:
        model.sweep(grid={"nope": [1, 2]})
    assert "nope" in str(err.value) and err.value.diagnostics[0]["code"] == "E0204"
    with pytest.raises(ValueError, match="set twice"):
        model.sweep(grid=["lambda=[0.1]", "lambda=[0.2]"])
    with pytest.raises(ValueError):
        model.sweep(grid=["lambda=0.5:-0.1:0.9"])
    with pytest.raises(ValueError, match="at least 1"):
        model.sweep(runs=0)
    # A grid point given twice would run twice.
    with pytest.raises(ValueError, match="axis `lambda`: the value 0.5 is given twice"):
        model.sweep(grid={"lambda": [0.5, 0.8, 0.5]})
    with pytest.raises(ValueError, match="set twice"):
        hybsim.load(ball_file, set={"lambda": 0.7}).sweep()


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to self")
def test_ctrl_c_interrupts_a_sweep(ball_file):
    # Endless runs (a lossless ball to T = 1e9), so the interrupt lands while they run.
    model = hybsim.load(ball_file, set={"T": 1e9, "lambda": 1})
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            model.sweep(grid=[], runs=4)
    finally:
        timer.cancel()
    assert time.monotonic() - start < 5.0
    # The model still sweeps afterwards.
    assert len(hybsim.load(ball_file).sweep(runs=1).runs) == 2


def test_grid_values_that_are_not_a_list_of_numbers_are_refused(ball_file):
    # A matrix of values was flattened into a grid of its entries (4 points
    # here), and None was read by numpy as NaN ("`NaN` is not a finite number").
    model = hybsim.load(ball_file)
    with pytest.raises(ValueError, match=r"axis `lambda`: the values of an axis are numbers, got a 2-D array of shape \(2, 2\)"):
        model.sweep(grid={"lambda": [[0.5, 0.6], [0.7, 0.8]]})
    with pytest.raises(TypeError, match="axis `lambda`: None is not a value"):
        model.sweep(grid={"lambda": None})
    with pytest.raises(TypeError, match="axis `lambda`: a number, a sequence of numbers"):
        model.sweep(grid={"lambda": {"a": 1}})
    # A scalar is one value, as `--grid lambda=0.5`.
    assert list(model.sweep(grid={"lambda": 0.5}, runs=1).points["lambda"]) == [0.5]


def test_threads_over_the_limit_are_refused(ball_file):
    # `threads=10000` on 2 cores took over a minute for a sweep of 2 runs:
    # idle workers spend their time looking for work in each other's queues.
    model = hybsim.load(ball_file)
    with pytest.raises(ValueError, match="`threads`: 10000 worker threads: a sweep takes from 1 to 1024"):
        model.sweep(threads=10000)
    start = time.monotonic()
    sw = model.sweep(threads=1024)
    assert len(sw.runs) == 6 and time.monotonic() - start < 20
    assert list(sw.runs["seed"]) == list(model.sweep(threads=1).runs["seed"])


def test_grid_as_name_value_pairs(ball_file):
    # `list(d.items())` was refused as the axis `('lambda', [0.5, 0.6])`, and
    # `grid=5` failed with "'int' object is not iterable".
    model = hybsim.load(ball_file)
    pairs = model.sweep(grid=[("lambda", [0.6, 0.7]), ("g", "9:1:10")], runs=1)
    named = model.sweep(grid={"lambda": [0.6, 0.7], "g": "9:1:10"}, runs=1)
    assert pairs.axes == named.axes == ["lambda", "g"]
    assert list(pairs.runs["seed"]) == list(named.runs["seed"])
    with pytest.raises(TypeError, match="grid= takes"):
        model.sweep(grid=5)
    with pytest.raises(TypeError, match=r"grid axis \(1, 2\): a \(name, values\) pair"):
        model.sweep(grid=[(1, 2)])
