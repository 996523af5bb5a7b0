"""Shared fixtures: paths, a seeded generator, and helpers to run the CLI as a user would."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def feltool(*args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the ``feltool`` command in a fresh interpreter, as a user would."""
    return subprocess.run([sys.executable, "-m", "feltool.cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)
