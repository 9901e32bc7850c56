"""Shared fixtures: the checkout's models and the `hybsim` command-line
binary (the reference the arrays are compared with)."""

import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"


@pytest.fixture(scope="session")
def hybsim_bin() -> pathlib.Path:
    """`$HYBSIM_BIN`, else target/release/hybsim (built if missing: CI's
    `cargo test --release` has built it already)."""
    env = os.environ.get("HYBSIM_BIN")
    if env:
        return pathlib.Path(env)
    path = ROOT / "target" / "release" / "hybsim"
    if not path.exists():
        subprocess.run(
            ["cargo", "build", "--release", "--bin", "hybsim"], cwd=ROOT, check=True
        )
    return path


@pytest.fixture(scope="session")
def models() -> pathlib.Path:
    return MODELS
