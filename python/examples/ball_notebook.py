# %% [markdown]
# # hybsim from Python: a notebook-style tour
#
# Run cell by cell in Jupyter / VS Code (`# %%` cells) or as a script:
# `.venv/bin/python python/examples/ball_notebook.py [OUT_DIR]` writes the figures to OUT_DIR
# (default: the current directory). CI runs it (python/tests/test_examples.py).

# %%
import pathlib
import sys

import matplotlib

if __name__ == "__main__" and "ipykernel" not in sys.modules:
    matplotlib.use("Agg")  # as a script: files only

import matplotlib.pyplot as plt
import numpy as np

import hybsim
import hybsim.plot

ROOT = pathlib.Path(__file__).resolve().parents[2] if "__file__" in globals() else pathlib.Path.cwd()
OUT = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 and __name__ == "__main__" else pathlib.Path(".")
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## 1. The bouncing ball: arrays out of a `.hyb` model

# %%
ball = hybsim.load(ROOT / "models" / "bouncing_ball.hyb", set={"lambda": 0.7})
sol = ball.run(T=3, dt_out=0.01)
print(sol)
print("first impacts at t =", np.round(sol.jumps.t[:4], 4))
t1 = np.sqrt(2 * 1.0 / 9.81)
assert abs(sol.jumps.t[0] - t1) < 1e-12  # free fall: exact impact time
print(sol.to_pandas().head())

# Values on a uniform grid, taking the post-jump value at impacts (HyEQ-style helpers).
grid = np.linspace(0, 3, 7)
print(sol.interpolate(grid, at_jump="end")["h"])

# %% [markdown]
# ## 2. A figure with HyEQ's conventions: flows solid, jumps dashed

# %%
fig = plt.figure(figsize=(10, 6))
ax1 = fig.add_subplot(2, 2, 1)
ax2 = fig.add_subplot(2, 2, 2)
ax3 = fig.add_subplot(2, 2, 3)
ax4 = fig.add_subplot(2, 2, 4, projection="3d")
hybsim.plot.flows(sol, "h", ax=ax1)
hybsim.plot.jumps(sol, "v", ax=ax2)
hybsim.plot.phase(sol, "h", "v", ax=ax3)
hybsim.plot.hybrid(sol, "h", ax=ax4)
fig.tight_layout()
fig.savefig(OUT / "ball.png", dpi=80)
print("wrote", OUT / "ball.png")

# %% [markdown]
# ## 3. A design block: an LMI solved when the model compiles

# %%
DESIGN = """model lyapunov
param A = [0, 1; -2, -3]
# A Lyapunov matrix with the smallest trace: A'P + PA <= -I, P >= I.
design lyap {
    sym P[2]
    minimize trace(P)
    P >= eye(2)
    A' * P + P * A <= -eye(2)
    param Pstar = P
}
state x = [1; 0]
flow { x' = A * x }
output V = x' * Pstar * x
sim { T = 5 }
"""
lyap = hybsim.load(DESIGN, name="lyapunov.hyb")
report = lyap.design()["lyap"]
print(report["summary"])
P = report["results"]["Pstar"]
print("P* =\n", P)
A = np.array([[0.0, 1.0], [-2.0, -3.0]])
assert np.linalg.eigvalsh(A.T @ P + P @ A).max() <= -1 + 1e-6
V = lyap.run()["V"]
assert np.all(np.diff(V) <= 1e-12)  # V decreases along the solution

# %% [markdown]
# ## 4. A property test: search for a counterexample, shrink it, replay it

# %%
PROPS = """model ball
param g = 9.81, lambda = 0.8
state h ~ uniform(0, 2), v = 0
flow { h' = v; v' = -g } in h >= 0
jump impact when h <= 0 && v <= 0 { v+ = -lambda * v }
property ground: always h >= -1e-9
property slow: at jumps impact abs(v) <= 5
sim { T = 3 }
"""
tested = hybsim.load(PROPS, name="ball_props.hyb")
report = tested.test(cases=100, seed=1)
print(report)
cx = report.counterexample
assert cx is not None and cx.property == "slow"
# Impact speed sqrt(2 g h) exceeds 5 from h = 25 / (2 g): shrunk onto that boundary.
assert abs(cx.inputs["h"] - 25 / (2 * 9.81)) < 1e-6
replay = hybsim.load(PROPS, set=cx.set).run(**cx.run_kwargs())
assert abs(replay.jumps.pre[0, 1]) > 5
print("replay:", cx.replay)
