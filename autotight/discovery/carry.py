"""Where plain ``discover`` selects a set that carries to any size: a problem module's ``CARRY``.

A set is learned once and applied to instances of any size by evaluating its templates.  Learning
carries: every identity of a factor type is found on one small instance.  *Selection* need not: a
discrete trajectory of 5 poses is tight with one pair, which is not tight at K = 100, and no selection
on 5-pose chains is tight at K = 1000, while a selection on 20-pose chains over the noise range, checked
on 200-pose chains, is (``docs/performance.md``).  A module whose selection does not carry
declares where it does::

    CARRY = {"at_least": {"K": 20}, "over": {"sigma": [0.001, 0.00316, 0.01, 0.0316, 0.1, 0.316]},
             "validate_at": {"K": 200}, "solver": "ipm"}

Then ``discover`` without a range option (``--range``, ``--sigmas``, ``--train-param``,
``--learn-param``, ``--validate``…) runs the range flow (``discovery.range``) planned here:

- the candidates and their templates are learned once at the given parameters (``learn_params``: the
  ``at_least`` parameters at their given values, e.g. K = 5);
- the set is selected on training instances whose ``at_least`` parameters are raised to at least
  those values (K = max(given, 20)), over the ``over`` range of every parameter not given with ``-p``
  (a given one stays fixed, and the plan says so);
- the selected set is then checked on one instance per point at the ``validate_at`` parameters (where
  they exceed the selection's), and tightened and reduced again where it is not tight there (up to
  three rounds: ``discover_range``'s ``n_validate``, ``validate_params``).  Two sets can both be
  irreducible over the K = 20 instances, and only one carry: a set of one unary and four odometry pairs is
  tight there and at K = 100, and not at K = 200 with σ = 0.316 nor at K = 1000 with σ = 0.1, where the
  six unary pairs of the other are;
- every solve uses the ``solver`` backend unless the caller chose one (``--solver``; Python: ``solver=``):
  the IPM for long chains, where Clarabel's own decomposition takes minutes per K = 200 solve.

``--no-carry`` (Python: ``discover(..., carry=False)``) selects at the given parameters alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from numbers import Real
from typing import Any

from ..errors import ParameterError, ProblemDefinitionError
from ..problem import Problem

#: options of the range flow; given any of them, the caller chose where to select and CARRY does not apply
RANGE_OPTIONS = ("over", "train_params", "learn_params", "n_validate", "validate_params")


@dataclass(frozen=True)
class CarryPlan:
    """Where a discovery learns and selects.  params: the selection instances' parameters (with the
    ``at_least`` minimums applied); over: the range selected over; learn_params: where the candidates are
    learned; fixed: ``over`` parameters left out because ``-p`` gave them; validate_params: where the selected
    set is checked, one instance per point (empty: no check)."""

    params: dict[str, Any]
    over: dict[str, list[Any]]
    learn_params: dict[str, Any]
    fixed: dict[str, Any] = field(default_factory=dict)
    validate_params: dict[str, Any] = field(default_factory=dict)
    solver: str | None = None

    @property
    def n_validate(self) -> int:
        return 1 if self.validate_params else 0

    def record(self) -> dict[str, Any]:
        return {"selected_at": self.params, "over": self.over, "learned_at": self.learn_params,
                "fixed_by_user": self.fixed, "validated_at": self.validate_params, "solver": self.solver}

    def range_options(self) -> dict[str, Any]:
        """The options of ``discover_range`` beyond (params, over) that carry out the plan."""
        return {"learn_params": self.learn_params, "n_validate": self.n_validate,
                "validate_params": self.validate_params}

    def mark(self, result: Any) -> None:
        """Record the plan in a ``RangeDiscoveryResult``'s set (``info["carry"]``, also in its summary)."""
        result.discovered.info["carry"] = self.record()

    def describe(self) -> str:
        """One line for the CLI: what was learned where, where it is selected, and how to opt out."""
        over = "; ".join(f"{k} ∈ {{{', '.join(f'{v:g}' for v in vs)}}}" for k, vs in self.over.items())
        size = ", ".join(f"{k}={v}" for k, v in self.params.items() if k in self.learn_params)
        text = (f"carry-over (the problem module's CARRY): candidates learned at "
                f"{', '.join(f'{k}={v}' for k, v in self.learn_params.items())}, the set selected at {size}"
                + (f" over {over}" if over else "")
                + (f", checked at {', '.join(f'{k}={v}' for k, v in self.validate_params.items())}"
                   if self.validate_params else "")
                + (f", solved with {self.solver} unless --solver is given" if self.solver else ""))
        if self.fixed:
            given = ", ".join(f"{k}={v:g}" for k, v in self.fixed.items())
            text += f"; {given} given, so not varied (the set may not carry to other values)"
        return text + "; --no-carry selects at -p alone"


KEYS = ("at_least", "over", "validate_at", "solver")


def carry_spec(problem: Problem) -> tuple[dict[str, Any], dict[str, list[Any]], dict[str, Any], str | None]:
    """The module's ``CARRY`` as (at_least, over, validate_at, solver), validated; empty when it declares none."""
    spec = getattr(problem.module, "CARRY", None)
    if spec is None:
        return {}, {}, {}, None
    where = f"{problem.where()}: CARRY"
    if not isinstance(spec, Mapping) or set(spec) - set(KEYS):
        raise ProblemDefinitionError(f"{where} must be a dict with keys among {', '.join(KEYS)}, got {spec!r}")
    at_least, over, validate_at = (dict(spec.get(k, {})) for k in KEYS[:3])
    solver = spec.get("solver")
    if solver is not None:
        from ..sdp import SolverConfigError, check_solver

        try:
            check_solver(solver)
        except SolverConfigError as e:
            raise ProblemDefinitionError(f"{where}['solver']: {e}") from None
    for key, values in (("at_least", at_least), ("validate_at", validate_at)):
        for k, v in values.items():
            if k not in problem.params or isinstance(v, bool) or not isinstance(v, Real):
                raise ProblemDefinitionError(f"{where}[{key!r}][{k!r}] must be a number for a parameter of the "
                                             f"problem, got {v!r}")
            values[k] = _parsed(problem, f"{where}[{key!r}]", k, v)
    for k, vs in over.items():
        if k not in problem.params or isinstance(vs, (str, bytes)) or not hasattr(vs, "__iter__") or not list(vs):
            raise ProblemDefinitionError(f"{where}['over'][{k!r}] must be a non-empty list of values of a parameter "
                                         f"of the problem, got {vs!r}")
        over[k] = [_parsed(problem, f"{where}['over']", k, v) for v in vs]
    clash = sorted(set(at_least) & set(over))
    if clash:
        raise ProblemDefinitionError(f"{where}: parameter {clash[0]} is both in 'at_least' and in 'over'")
    return at_least, over, validate_at, solver


def _parsed(problem: Problem, where: str, name: str, value: Any) -> Any:
    try:
        return problem.params[name].parse(name, value)
    except ParameterError as e:
        raise ProblemDefinitionError(f"{where}: {e}") from None


def carry_plan(problem: Problem, given: Mapping[str, Any] | None) -> CarryPlan | None:
    """The range flow that selects a carrying set for a discovery at ``given`` (the ``-p`` parameters), or
    None when the module declares no ``CARRY``, or when ``given`` already is where a selection carries."""
    at_least, over, validate_at, solver = carry_spec(problem)
    if not at_least and not over:
        return None
    given = dict(given or {})
    full = problem.parse_params(given)
    raised = {k: max(full[k], v) for k, v in at_least.items()}
    varied = {k: vs for k, vs in over.items() if k not in given}
    if all(raised[k] == full[k] for k in raised) and not varied:
        return None
    selected = full | raised
    validate = {k: v for k, v in validate_at.items() if v > selected[k]}
    return CarryPlan(given | raised, varied, {k: full[k] for k in at_least},
                     {k: full[k] for k in over if k in given}, validate, solver)
