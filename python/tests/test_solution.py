"""Solution helpers: columns, restrict_t, restrict_j, interpolate."""

import pathlib

import numpy as np
import pytest

import hybsim

# A ball with a known domain: impacts at t1 = sqrt(2 h0 / g) and then every
# 2 * lambda^k * v1 / g; an exact (affine) flow, samples every 0.01.
BALL = """model ball
param g = 9.81, lambda = 0.8
state h = 1, v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
output e = 0.5 * v^2 + g * h
sim { T = 2; dt_out = 0.01 }
"""


@pytest.fixture(scope="module")
def sol():
    return hybsim.load(BALL).run()


def test_columns(sol):
    assert sol.names == ["h", "v"] and sol.output_names == ["e"]
    assert sol.x.shape == (len(sol), 2) and sol.y.shape == (len(sol), 1)
    np.testing.assert_array_equal(sol["h"], sol.x[:, 0])
    np.testing.assert_array_equal(sol["e"], sol.y[:, 0])
    assert sol.j.dtype == np.int64 and sol.t.dtype == np.float64
    assert sol.kind[0] == "initial" and sol.kind[-1] == "final"
    assert "h" in sol and "nope" not in sol
    with pytest.raises(KeyError, match="states are h, v"):
        sol["nope"]
    t1 = np.sqrt(2 / 9.81)
    assert abs(sol.jumps.t[0] - t1) < 1e-12
    assert sol.termination.cause == "horizon_t" and sol.end[0] == 2.0


def test_restrict(sol):
    r = sol.restrict_t(0.5, 1.0)
    assert r.t.min() >= 0.5 and r.t.max() <= 1.0
    assert len(r.jumps) == np.count_nonzero((sol.jumps.t >= 0.5) & (sol.jumps.t <= 1.0))
    r = sol.restrict_j(1, 2)
    assert set(r.j) == {1, 2}
    assert list(r.jumps.j) == [1]  # the jump from j = 1 to j = 2
    r = sol.restrict_j(j_min=3)
    assert r.j.min() == 3 and len(r) == np.count_nonzero(sol.j >= 3)


def test_reversed_or_nan_intervals_are_value_errors(sol):
    # Were empty solutions, silently.
    with pytest.raises(ValueError, match="t_min = 2 is greater than t_max = 1"):
        sol.restrict_t(2, 1)
    with pytest.raises(ValueError, match="NaN"):
        sol.restrict_t(float("nan"), 1)
    with pytest.raises(ValueError, match="j_min = 3 is greater than j_max = 1"):
        sol.restrict_j(3, 1)
    # A one-point interval is not reversed.
    assert len(sol.restrict_t(0, 0)) == 1 and set(sol.restrict_j(2, 2).j) == {2}
    # A bound that is not a number was a numpy TypeError about `isnan`.
    with pytest.raises(TypeError, match="restrict_t: t_min is a number or None, not str"):
        sol.restrict_t("0.5", 1)
    with pytest.raises(TypeError, match="restrict_j: j_max is a number or None, not list"):
        sol.restrict_j(0, [2])
    assert len(sol.restrict_t(np.float64(0), np.int64(0))) == 1


def test_interpolate_exact_at_samples_and_linear_between(sol):
    flow = sol.kind == "flow"
    ts = sol.t[flow][:20]
    i = sol.interpolate(ts)
    np.testing.assert_array_equal(i.x, sol.x[flow][:20])
    # Midway between two samples of one interval: the mean.
    a, b = np.flatnonzero(flow)[3:5]
    assert sol.j[a] == sol.j[b]
    mid = sol.interpolate([(sol.t[a] + sol.t[b]) / 2])
    np.testing.assert_allclose(mid.x[0], (sol.x[a] + sol.x[b]) / 2, rtol=1e-12)
    assert mid.j[0] == sol.j[a]


def test_interpolate_at_jumps(sol):
    tj = sol.jumps.t[0]
    pre, post = sol.jumps.pre[0], sol.jumps.post[0]
    grid = [tj / 2, tj, (tj + sol.jumps.t[1]) / 2]
    start = sol.interpolate(grid, at_jump="start")
    end = sol.interpolate(grid, at_jump="end")
    nan = sol.interpolate(grid, at_jump="nan")
    both = sol.interpolate(grid, at_jump="both")
    np.testing.assert_array_equal(start.x[1], pre)
    np.testing.assert_array_equal(end.x[1], post)
    assert (start.j[1], end.j[1]) == (0, 1)
    assert np.isnan(nan.x[1]).all() and not np.isnan(nan.x[[0, 2]]).any()
    np.testing.assert_array_equal(both.t, [grid[0], tj, tj, grid[2]])
    np.testing.assert_array_equal(both.x[1], pre)
    np.testing.assert_array_equal(both.x[2], post)
    np.testing.assert_array_equal(both.j, [0, 0, 1, 1])
    for s in (start, end, nan):
        np.testing.assert_array_equal(s.x[[0, 2]], both.x[[0, 3]])
    # Outside the domain: NaN, j = -1.
    out = sol.interpolate([-1.0, 3.0])
    assert np.isnan(out.x).all() and list(out.j) == [-1, -1]
    with pytest.raises(ValueError, match="at_jump"):
        sol.interpolate(grid, at_jump="middle")
    with pytest.raises(ValueError, match="nondecreasing"):
        sol.interpolate([1.0, 0.5])


def test_seed_and_parameters():
    src = """model noisy
param g ~ uniform(9, 10)
state h ~ uniform(0, 2), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -0.8 * v }
sim { T = 1; seed = 3 }
"""
    m = hybsim.load(src)
    a, b, c = m.run(), m.run(seed=3), m.run(seed=4)
    assert a.seed == 3 and c.seed == 4
    np.testing.assert_array_equal(a.x, b.x)
    assert a.x[0, 0] != c.x[0, 0]
    assert 9 <= a.parameters["g"] <= 10 and a.parameters["g"] != c.parameters["g"]
    assert m.parameters["g"] == 9.5  # the loaded model holds the centre


def test_matrix_overrides_and_parameters():
    src = """model lin
param K = [1, 2; 3, 4]
param x0 = [1; 0]
state x = x0
flow { x' = -K * x }
sim { T = 0.1 }
"""
    m = hybsim.load(src, set={"K": np.array([[1.0, 0.0], [0.0, 2.0]]), "x0": [2.0, 3.0]})
    np.testing.assert_array_equal(m.parameters["K"], [[1.0, 0.0], [0.0, 2.0]])
    np.testing.assert_array_equal(m.parameters["x0"], [2.0, 3.0])
    sol = m.run()
    assert sol.names == ["x[1]", "x[2]"]
    assert sol["x"].shape == (len(sol), 2)
    np.testing.assert_allclose(sol["x[2]"][-1], 3.0 * np.exp(-0.2), rtol=1e-6)


def test_outputs_are_evaluated_on_first_use(sol):
    fresh = hybsim.load(BALL).run()
    assert fresh._y is None  # not computed by the run
    part = fresh.restrict_t(0.5, 1.0)
    assert part._y is None  # restricting keeps them lazy
    e = 0.5 * part["v"] ** 2 + 9.81 * part["h"]
    np.testing.assert_allclose(part["e"], e, rtol=1e-12)
    np.testing.assert_array_equal(part.y[:, 0], fresh.y[(fresh.t >= 0.5) & (fresh.t <= 1.0), 0])
    with pytest.raises(ValueError, match="outputs need"):
        fresh._output_map(fresh.t[:3], fresh.x[:2])


VDP = """model vdp
param mu = 1000
state x = 2, y = 0
flow { x' = y; y' = mu * (1 - x^2) * y - x }
sim { T = 3 }
"""


def test_auto_solver_switches_are_reported():
    sol = hybsim.load(VDP).run(solver="auto")
    switches = sol.solver_switches
    # Stiff from the start: Dopri5 hands over to Radau5 within the first time unit.
    assert switches and switches[0]["to"] == "radau5"
    assert 0 <= switches[0]["t"] < 1 and switches[0]["j"] == 0
    assert all(s["to"] in ("radau5", "dopri5") for s in switches)
    assert sol.restrict_t(0, 1).solver_switches == switches
    # Without auto, or on a non-stiff flow, nothing switches.
    assert hybsim.load(VDP).run(solver="radau5").solver_switches == []
    assert hybsim.load(VDP, set={"mu": 0.5}).run(solver="auto").solver_switches == []


def test_linear_solver_keyword_chooses_the_implicit_solvers_lu():
    # The stiff heat chain (N = 40 cells, tridiagonal Jacobian) on radau5: the
    # sparse and the dense LU give the same switching times within tolerance.
    root = pathlib.Path(__file__).resolve().parents[2]
    model = hybsim.load(root / "benches" / "models" / "heat_chain.hyb", set={"N": 40})
    runs = {
        ls: model.run(T=3.0, solver="radau5", linear_solver=ls) for ls in ("dense", "sparse", "auto")
    }
    times = {ls: sol.jumps.t for ls, sol in runs.items()}
    assert len(times["dense"]) > 0
    for ls in ("sparse", "auto"):
        assert len(times[ls]) == len(times["dense"])
        np.testing.assert_allclose(times[ls], times["dense"], atol=1e-6)


def test_interpolate_refuses_nan_times(sol):
    # NaN passed the order test and gave a row at no time.
    with pytest.raises(ValueError, match="t_grid holds NaN"):
        sol.interpolate([0.0, float("nan")])
