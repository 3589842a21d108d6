"""Pytest helpers: ``assert_sufficient`` fails a test, listing the failing seeds and their verdicts,
when a constraint set is not tight often enough over a range (``autotight.check``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from .check import SufficiencyReport, check_sufficient
from .constraint_set import ConstraintsLike
from .problem import Problem


def assert_sufficient(problem: str | Problem, constraints: ConstraintsLike = "paper", *,
                      sigmas: Sequence[float] | None = None, instances: int = 5, min_fraction: float = 1.0,
                      params: Mapping[str, Any] | None = None, seed: int = 0, solver: Any = None,
                      over: Mapping[str, Sequence[Any]] | None = None, **kwargs: Any) -> SufficiencyReport:
    """Assert that ``constraints`` are tight on ≥ ``min_fraction`` of the decided instances at every point.

    Same arguments and seeds as ``autotight.check.check_sufficient``; returns its report so a test
    can assert more (e.g. ``report.points[0].log_svr``).
    """
    rep = check_sufficient(problem, constraints, sigmas, instances, min_fraction, params, seed, solver,
                           over=over, **kwargs)
    if not rep.passed:
        raise AssertionError(rep.failure_message())
    return rep
