"""Plots render with the Agg backend; runs release the GIL and stop on
Ctrl-C."""

import os
import signal
import threading
import time

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import hybsim  # noqa: E402
import hybsim.plot  # noqa: E402


@pytest.fixture(scope="module")
def ball(models):
    return hybsim.load(models / "bouncing_ball.hyb").run()


def test_plots_render(ball, tmp_path):
    axes = hybsim.plot.flows(ball)
    assert len(axes) == 2 and axes[-1].get_xlabel() == "t"
    # One solid line per component and one dashed line for all jumps.
    styles = [ln.get_linestyle() for ln in axes[0].get_lines()]
    assert styles.count("-") == 1 and styles.count("--") == 1
    dashed = [ln for ln in axes[0].get_lines() if ln.get_linestyle() == "--"][0]
    xs = dashed.get_xdata()
    assert len(xs) == 3 * len(ball.jumps)
    # Flow lines break at jumps (NaN between intervals).
    solid = [ln for ln in axes[0].get_lines() if ln.get_linestyle() == "-"][0]
    assert np.isnan(solid.get_ydata()).sum() == len(np.unique(ball.j)) - 1
    axes[0].figure.savefig(tmp_path / "flows.png")
    ax = hybsim.plot.jumps(ball, "h")
    assert ax.get_xlabel() == "j"
    ax.figure.savefig(tmp_path / "jumps.png")
    ax = hybsim.plot.hybrid(ball, "h")
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_zlabel()) == ("t", "j", "h")
    ax.figure.savefig(tmp_path / "hybrid.png")
    ax = hybsim.plot.phase(ball)
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("h", "v")
    ax.figure.savefig(tmp_path / "phase.png")
    # An output component, into a given axes.
    fig, one = plt.subplots()
    assert hybsim.plot.flows(ball, "energy", ax=one) is one
    for name in ("flows", "jumps", "hybrid", "phase"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    plt.close("all")


def test_phase_takes_its_pair_as_one_list(ball):
    # `phase(sol, ["v", "h"])` was "a solution is indexed by a component's name (str), not list".
    ax = hybsim.plot.phase(ball, ["v", "h"])
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("v", "h")
    with pytest.raises(ValueError, match=r"phase\(\) draws two components, got 3"):
        hybsim.plot.phase(ball, ["h", "v", "energy"])
    with pytest.raises(TypeError, match=r"phase\(\): components are named by str, not int"):
        hybsim.plot.phase(ball, 0, 1)
    plt.close("all")


LONG = """model slow
state x = 1
flow { x' = -x }
sim { T = 1e9; max_step = 1e-3; max_step_count = 1e13 }  # a run long enough to interrupt: raise the step limit
"""


def test_runs_release_the_gil():
    m = hybsim.load(LONG)
    result = {}

    def work():
        result["sol"] = m.run(T=300.0, dt_out=1e-2, exact_affine=False)

    ticks = 0
    th = threading.Thread(target=work)
    th.start()
    while th.is_alive():
        ticks += 1
        time.sleep(0.0005)
    th.join()
    assert len(result["sol"]) > 30000
    # The main thread kept running while the other simulated.
    assert ticks > 5


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to self")
@pytest.mark.parametrize("dt_out", [None, 1e4])
def test_ctrl_c_interrupts_a_run(dt_out):
    # With a dt_out of 10^7 steps the interrupt was only seen at a sample,
    # about 10 s later (minutes for a longer dt_out); it is polled after
    # every step.
    m = hybsim.load(LONG)
    grid = {} if dt_out is None else {"dt_out": dt_out}
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    try:
        # Bounded (~25 s, ~0.7 GB of samples): a missed interrupt fails the
        # test instead of running until memory is exhausted.
        with pytest.raises(KeyboardInterrupt):
            m.run(T=2e4, exact_affine=False, **grid)
    finally:
        timer.cancel()
    assert time.monotonic() - start < 5.0
    # The model still runs afterwards.
    assert m.run(T=0.01).termination.cause == "horizon_t"
