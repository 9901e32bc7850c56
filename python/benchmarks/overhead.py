"""Overhead of the Python package over the Rust library (BENCHMARKS.md,
section "Python").

    .venv/bin/python python/benchmarks/overhead.py

1. The bouncing ball up to its Zeno guard: `Model.run` (GIL release, run,
   columns moved into numpy, the `Solution` object) against the Rust
   `engine::simulate_arc` call on the same compiled model, fastest of N.
2. The 10-s consensus run (models/consensus_estimation.hyb: 100 000
   Euler-Maruyama steps, 182 states) loaded as arrays: `Model.run` wall time.
"""

import pathlib
import time

import hybsim

ROOT = pathlib.Path(__file__).resolve().parents[2]


def best(f, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        f()
        times.append(time.perf_counter() - start)
    return min(times)


def ball_ratio(repeats=200):
    """(Model.run seconds, simulate_arc seconds), fastest of `repeats`
    each, the ball running to its Zeno guard."""
    ball = hybsim.load(ROOT / "models" / "bouncing_ball.hyb")
    sim = {"T": 10.0, "J": 10_000}
    rust = ball._native._simulate_arc_seconds(None, dict(sim), repeats)
    py = best(lambda: ball.run(**sim), repeats)
    return py, rust


def main():
    py, rust = ball_ratio()
    sol = hybsim.load(ROOT / "models" / "bouncing_ball.hyb").run(T=10.0, J=10_000)
    print(
        f"ball to the Zeno guard ({len(sol.jumps)} jumps, {len(sol)} samples): "
        f"Model.run {py * 1e6:.0f} us, simulate_arc {rust * 1e6:.0f} us, ratio {py / rust:.2f}"
    )
    model = hybsim.load(ROOT / "models" / "consensus_estimation.hyb")
    start = time.perf_counter()
    sol = model.run()
    wall = time.perf_counter() - start
    print(
        f"consensus 10 s: {len(sol)} samples x {sol.x.shape[1]} states "
        f"({sol.x.nbytes / 1e6:.0f} MB) as arrays in {wall:.2f} s"
    )


if __name__ == "__main__":
    main()
