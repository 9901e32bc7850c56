"""The README's Python example runs as written (from the checkout's root,
where its model paths are)."""

import os
import pathlib
import re
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]


def readme_python_block() -> str:
    """The first ```python block of the README's "## Python" section."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "no ```python block in the README's Python section"
    return match.group(1)


def test_the_readme_python_example_runs_as_written():
    code = readme_python_block()
    # Each statement's value checked where the example promises one.
    code += (
        "\nassert report.counterexample is not None"
        "\nassert report.counterexample.replay.startswith('hybsim run models/thermostat.hyb')"
        "\nassert len(sw.runs['command']) == 20\n"
    )
    env = dict(os.environ, MPLBACKEND="Agg")
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr
