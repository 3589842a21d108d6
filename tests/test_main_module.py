"""``python -m autotight`` is the same command line as the ``autotight`` script."""

from __future__ import annotations

import json
import subprocess
import sys

from autotight.problem import available


def test_python_m_autotight_lists_every_problem():
    proc = subprocess.run([sys.executable, "-m", "autotight", "list", "--json"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert [row["name"] for row in json.loads(proc.stdout)] == list(available())


def test_python_m_autotight_reports_bad_input_with_exit_2():
    proc = subprocess.run([sys.executable, "-m", "autotight", "solve", "no_such_problem"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith("autotight: error: unknown problem 'no_such_problem'")
