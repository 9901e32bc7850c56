"""Reference solutions of the stiff test problems (tests/it/stiff.rs), computed once
with scipy's Radau (order 5) at rtol 1e-12 and exact Jacobians, and a second time at
rtol 1e-11 to show the digits that hold. Run: python stiff_reference.py > stiff_reference.json
(scipy 1.x; printed values are the final states). The problems are imported from here by
benches/stiff_scipy.py."""
import json

import scipy
from scipy.integrate import solve_ivp

MU = 1000.0


def vdp(t, y):
    return [y[1], MU * (1 - y[0] ** 2) * y[1] - y[0]]


def vdp_jac(t, y):
    return [[0.0, 1.0], [-2 * MU * y[0] * y[1] - 1, MU * (1 - y[0] ** 2)]]


def rob(t, y):
    return [
        -0.04 * y[0] + 1e4 * y[1] * y[2],
        0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2,
        3e7 * y[1] ** 2,
    ]


def rob_jac(t, y):
    return [
        [-0.04, 1e4 * y[2], 1e4 * y[1]],
        [0.04, -1e4 * y[2] - 6e7 * y[1], -1e4 * y[1]],
        [0.0, 6e7 * y[1], 0.0],
    ]


def final(fun, jac, t_end, y0, rtol, atol):
    s = solve_ivp(fun, (0.0, t_end), y0, method="Radau", rtol=rtol, atol=atol, jac=jac)
    assert s.status == 0, s.message
    return s.y[:, -1].tolist()


if __name__ == "__main__":
    out = {"generator": "scipy.integrate.solve_ivp(method='Radau', jac=exact)", "scipy": scipy.__version__}
    out["van_der_pol_mu1000_t3000"] = {
        "y0": [2.0, 0.0],
        "rtol_1e-12": final(vdp, vdp_jac, 3000.0, [2.0, 0.0], 1e-12, 1e-14),
        "rtol_1e-11": final(vdp, vdp_jac, 3000.0, [2.0, 0.0], 1e-11, 1e-13),
    }
    for t_end in (40.0, 1e5):
        out[f"robertson_t{t_end:g}"] = {
            "y0": [1.0, 0.0, 0.0],
            "rtol_1e-12": final(rob, rob_jac, t_end, [1.0, 0.0, 0.0], 1e-12, 1e-20),
            "rtol_1e-11": final(rob, rob_jac, t_end, [1.0, 0.0, 0.0], 1e-11, 1e-19),
        }
    print(json.dumps(out, indent=1))
