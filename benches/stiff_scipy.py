"""scipy side of the stiff-flow benchmark in BENCHMARKS.md (run by `cargo bench --bench stiff`, or
alone): Van der Pol mu = 1000 to T = 3000 (rtol 1e-6, atol 1e-9), Robertson to t = 1e5 (rtol 1e-6,
atol 1e-12) and the stiff relay to T = 24 (rtol 1e-8, atol 1e-10; the tolerances of
benches/models/*.hyb), each with scipy's Radau, BDF and LSODA and the exact Jacobian, best of 5 per
method. Accuracy: the largest error of the final state relative to rtol*|ref| + atol against
tests/data/stiff_reference.json, and for the relay the largest error of the switching times
against their closed form (the relay is integrated flow by flow: a terminal event at the sensor's
threshold, the mode flipped, the integration restarted, as a hybrid simulator does).
Prints rows of the table of `benches/stiff.rs`.
Run: python benches/stiff_scipy.py tests/data/stiff_reference.json"""
import json
import math
import pathlib
import sys
import time

import numpy as np
import scipy
from scipy.integrate import solve_ivp

# The problems as the references were computed (tests/data/stiff_reference.py).
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "data"))
from stiff_reference import rob, rob_jac, vdp, vdp_jac  # noqa: E402

# The relay (benches/models/stiff_relay.hyb): x' = -a (x - xa) + p q, z' = (x - z) / tau, q flips
# when z reaches xhi (q = 1) or xlo (q = 0).
A, XA, P, XLO, XHI, TAU, T_RELAY = 0.5, 5.0, 12.0, 18.0, 22.0, 1e-5, 24.0


def relay_closed_form():
    x, q, t, out = 20.0, 1.0, 0.0, []
    while True:
        big_x = XA + P * q / A
        theta = XHI if q == 1.0 else XLO
        d = math.log((x - big_x) / ((1 - A * TAU) * (theta - big_x))) / A
        if t + d >= T_RELAY:
            return out
        t += d
        x = big_x + (x - big_x) * math.exp(-A * d)
        q = 1.0 - q
        out.append(t)


def relay(method, rtol, atol):
    """Flow by flow to T; returns (switch times, f evaluations, Jacobians, steps)."""
    t, y, q = 0.0, [20.0, 20.0], 1.0
    switches, nfev, njev, steps = [], 0, 0, 0
    while t < T_RELAY:
        qq = q

        def f(_t, y):
            return [-A * (y[0] - XA) + P * qq, (y[0] - y[1]) / TAU]

        def jac(_t, y):
            return [[-A, 0.0], [1 / TAU, -1 / TAU]]

        theta = XHI if q == 1.0 else XLO

        def ev(_t, y):
            return y[1] - theta

        ev.terminal = True
        ev.direction = 1 if q == 1.0 else -1
        s = solve_ivp(f, (t, T_RELAY), y, method=method, rtol=rtol, atol=atol, jac=jac, events=ev)
        assert s.status >= 0, s.message
        nfev, njev, steps = nfev + s.nfev, njev + s.njev, steps + len(s.t) - 1
        if s.status == 1:
            t, y = s.t_events[0][0], list(s.y_events[0][0])
            switches.append(t)
            q = 1.0 - q
        else:
            t = T_RELAY
    return switches, nfev, njev, steps


def best_of(k, fn):
    best, out = math.inf, None
    for _ in range(k):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


ref = json.load(open(sys.argv[1]))
exact_switches = relay_closed_form()
for problem, fun, jac, t_end, y0, rtol, atol, key in [
    ("van_der_pol", vdp, vdp_jac, 3000.0, [2.0, 0.0], 1e-6, 1e-9, "van_der_pol_mu1000_t3000"),
    ("robertson", rob, rob_jac, 1e5, [1.0, 0.0, 0.0], 1e-6, 1e-12, "robertson_t100000"),
    ("stiff_relay", None, None, T_RELAY, None, 1e-8, 1e-10, None),
]:
    for method in ["Radau", "BDF", "LSODA"]:
        if key is None:
            best, (switches, nfev, njev, steps) = best_of(5, lambda: relay(method, rtol, atol))
            if len(switches) != len(exact_switches):
                err = f"{len(switches)} switches (exact {len(exact_switches)})"
            else:
                err = f"{max(abs(a - b) for a, b in zip(switches, exact_switches)):.1e}"
            acc = ("—", err)
        else:
            best, s = best_of(
                5,
                lambda: solve_ivp(fun, (0.0, t_end), y0, method=method, rtol=rtol, atol=atol, jac=jac),
            )
            assert s.status == 0, s.message
            want = np.array(ref[key]["rtol_1e-12"])
            worst = np.max(np.abs(s.y[:, -1] - want) / (rtol * np.abs(want) + atol))
            nfev, njev, steps = s.nfev, s.njev, len(s.t) - 1
            acc = (f"{worst:.2g}", "—")
        print(
            f"| {problem} (rtol {rtol:.0e}, atol {atol:.0e}) | scipy {scipy.__version__} `{method}` "
            f"| {best * 1e3:.1f} ms (wall, best of 5; {steps} steps, {nfev} f, {njev} J) | {acc[0]} | {acc[1]} | — |"
        )
