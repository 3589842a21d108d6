"""The lint configuration in pyproject.toml ([tool.ruff]) passes on the whole source tree."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_passes():
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "autotight", "problems", "tests",
                          "benchmarks"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, f"ruff check failed (exit {out.returncode}):\n{out.stdout}\n{out.stderr}"
