"""The notebook-style examples run as scripts."""

import pathlib
import subprocess
import sys

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def test_ball_notebook_runs_and_draws(tmp_path):
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "ball_notebook.py"), str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "replay: hybsim run" in out.stdout
    assert (tmp_path / "ball.png").stat().st_size > 10_000
