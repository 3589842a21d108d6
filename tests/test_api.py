"""The public API: a bug in a problem module raises (never a status); verdicts at low noise."""

from __future__ import annotations

import traceback

import pytest

import autotight as at
from autotight.errors import ProblemModuleError
from autotight.testing import assert_sufficient


def test_a_valueerror_in_build_raises_with_its_traceback(tmp_path):
    path = tmp_path / "broken_build.py"
    path.write_text("from problems.rotation_averaging import *  # noqa: F401,F403\n"
                    "NAME = 'broken_build'\n"
                    "def build(inst):\n"
                    "    raise ValueError('shape (3,) does not match (4,)')\n")
    with pytest.raises(ProblemModuleError) as e:
        at.solve(str(path), {"M": 3}, seed=0)
    cause = e.value.__cause__
    assert isinstance(cause, ValueError) and "shape (3,)" in str(cause)
    frames = traceback.extract_tb(cause.__traceback__)
    assert frames[-1].name == "build" and frames[-1].filename == str(path)  # the module's own line


@pytest.mark.slow
def test_pose_averaging_paper_set_at_low_noise_is_tight_on_10_seeds():
    """σ = 0.001: the paper's R1 + R2 are tight (or certified) on ≥ 98 % of instances, and
    no instance is judged "not tight" (undecided verdicts are allowed and reported)."""
    rep = assert_sufficient("pose_averaging", "paper", sigmas=[0.001], instances=10, params={"M": 10},
                            min_fraction=0.98, n_random=0)
    point = rep.points[0]
    assert point.count("not tight") == 0
    assert point.count("tight") >= 10 - point.count("undecided") and point.count("tight") >= 9
