"""Pytest helpers.

- ``assert_sufficient`` fails a test, listing the failing seeds and their verdicts, when a constraint set
  is not tight often enough over a range (``autotight.check``);
- ``assert_problem_module`` fails a test, listing every failed named check, when a problem module does not
  keep its contract (``autotight.checks.check_problem``, the checks of ``check-module``): a user's own
  test suite can hold ``def test_my_problem(): assert_problem_module("path/to/my_problem.py")``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from .check import SufficiencyReport, check_sufficient
from .checks import ProblemCheck, check_problem
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


def assert_problem_module(problem: str | Problem, params: Mapping[str, Any] | None = None, *, seed: int = 0,
                          n_samples: int = 5) -> ProblemCheck:
    """Assert that every check of ``check_problem`` passes (warnings allowed); the AssertionError lists each
    failed check on its own line as ``FAIL name: what``.  Returns the result so a test can assert more
    (e.g. ``result.measurements["sample_violation"]``)."""
    res = check_problem(problem, None if params is None else dict(params), seed=seed, n_samples=n_samples)
    if not res.ok:
        raise AssertionError(f"problem {res.problem} fails {len(res.failures)} check(s):\n"
                             + "\n".join(f"FAIL {f}" for f in res.failures))
    return res
