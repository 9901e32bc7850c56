"""scipy side of the stiff-flow benchmark in BENCHMARKS.md: Van der Pol mu = 1000 to T = 3000
at rtol 1e-6, atol 1e-9 (hybsim's defaults) with the exact Jacobian, best of 5 per method, and the
error of x(3000) against tests/data/stiff_reference.json.
Run: python benches/stiff_scipy.py tests/data/stiff_reference.json"""
import time, json, sys
import numpy as np
from scipy.integrate import solve_ivp
MU = 1000.0
def f(t, y): return [y[1], MU*(1-y[0]**2)*y[1] - y[0]]
def jac(t, y): return [[0, 1], [-2*MU*y[0]*y[1] - 1, MU*(1-y[0]**2)]]
ref = json.load(open(sys.argv[1]))["van_der_pol_mu1000_t3000"]["rtol_1e-12"]
for m in ["Radau", "BDF", "LSODA"]:
    best = 1e9
    for _ in range(5):
        t0 = time.perf_counter()
        s = solve_ivp(f, (0, 3000), [2.0, 0.0], method=m, rtol=1e-6, atol=1e-9, jac=jac)
        best = min(best, time.perf_counter() - t0)
    err = abs(s.y[0, -1] - ref[0])
    print(f"{m}: status {s.status} best-of-5 {best*1e3:.1f} ms, steps {len(s.t)-1}, nfev {s.nfev}, njev {s.njev}, nlu {s.nlu}, |x(3000)-ref| {err:.1e}")
