"""Evaluate constraint sets on instances: one build and one local search per instance, shared by the sets.

``evaluate_instance`` is the loop that ``check`` (``check.solve_points``), discovery's held-out validation
(``discovery.heldout.solve_one``) and a report trial (``report.trial``) run on each instance:

1. build the instance's model (unless given) and run one local search (unless given), shared by every set;
2. per set, in the order of ``sets``: a learned ``ConstraintSet`` is instantiated on the instance first
   (``ConstraintSet.apply``); failing to (an ``AutotightError``) is a failure of this instance with this set
   only (``NotInstantiated``), unless ``catch_instantiate`` is False (then the error propagates);
3. with a ``shortcut`` certifier, a set whose constraints the local solution's certificate proves tight is
   ``Certified`` without the SDP (after the checks of ``pipeline.prepare``: data, and every constraint on
   the feasible points); every other set is solved by ``pipeline.solve_instance`` (a ``SolveResult``).

Seeds follow ``pipeline.seeds``: the local starts draw from ``rng_local`` (default: ``seeds(s).local()``, s the
instance's seed); a learned set is instantiated from ``rng_constraints`` when one is given (one generator
shared by the sets, in their order), else from a fresh ``seeds(s).constraints()`` per set.

``evaluate`` generates the instance of (params, seed) and evaluates it with the seed scheme's generators.
``summary`` is the plain per-set row (outcome, log SVR, reason, …) the counting of ``check`` uses.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Optional, Protocol, Union

import numpy as np

from . import sdp
from .constraint_set import ConstraintSet, ConstraintsLike, set_name
from .errors import AutotightError
from .model import Constraint, Model
from .pipeline import LocalSearch, Prepared, SolveResult, local_search, prepare, seeds, solve_instance, solve_prepared
from .problem import Instance, Problem
from .sdp.config import SolverConfig
from .tightness import Criteria


class Proof(Protocol):
    """What a shortcut certifier returns when it proves a set tight: a relative bound on the cost gap and a
    one-line reason (``discovery.shortcut.Shortcut`` is one)."""

    @property
    def rel_bound(self) -> float: ...

    def reason(self) -> str: ...


#: certifier(model, constraints, Θ̂, criteria, gap) → Proof or None: proves the SDP with ``constraints`` (all of
#: them, primary included) tight at the lifted local solution Θ̂ (d × N) for a solver of relative gap ``gap``;
#: None when it does not decide (``discovery.shortcut.certified_tight``)
Certifier = Callable[[Model, Sequence[Constraint], np.ndarray, Criteria, float], Optional[Proof]]


@dataclass(frozen=True)
class NotInstantiated:
    """A learned set that could not be instantiated on the instance: a failure of the instance ("not tight")."""

    error: AutotightError

    @property
    def reason(self) -> str:
        return f"cannot instantiate the set: {self.error}"


@dataclass(frozen=True)
class Certified:
    """A set proved tight by the certificate of the local solution, without the SDP (the ``shortcut``).
    n_constraints: every constraint of the SDP that would have been solved (primary included)."""

    n_constraints: int
    proof: Proof


#: the result of one set on one instance
SetResult = Union[SolveResult, NotInstantiated, Certified]


@dataclass
class InstanceEvaluation:
    """Every set evaluated on one instance.

    results: set name → ``SetResult``, in the order of the ``sets`` given; model, local: the model and the
    local search the sets shared; times: ``build_s`` (building the model; 0 when it was given) and ``local_s``
    (the local search; 0 when it was given), in seconds.
    """

    instance: Instance
    model: Model
    local: LocalSearch
    results: dict[str, SetResult]
    times: dict[str, float] = field(default_factory=dict)


def instantiate(problem: Problem, inst: Instance, model: Model, constraints: ConstraintsLike,
                rng: np.random.Generator) -> ConstraintsLike:
    """``constraints`` as ``solve_instance`` takes them on ``inst``: a learned ``ConstraintSet`` becomes its
    constraints on ``inst`` (``ConstraintSet.apply``, without the primary ones; a set of another problem is an
    ``AutotightError``); anything else is returned as it is."""
    if not isinstance(constraints, ConstraintSet):
        return constraints
    return constraints.apply(problem, inst, model, rng)


def certify_local(problem: Problem, inst: Instance, prep: Prepared, certifier: Certifier,
                  criteria: Criteria) -> Certified | None:
    """``Certified`` when ``certifier`` proves the prepared constraints (``pipeline.prepare``: data and every
    constraint checked on the feasible points) tight at the local search's best solution, else None.  The
    certifier's gap is the relative gap of the solver the SDP would use (``sdp.effective_tol``)."""
    gap = sdp.effective_tol(prep.config)
    proof = certifier(prep.model, prep.constraints, problem.lift(inst, prep.local.best.state), criteria, gap)
    return None if proof is None else Certified(len(prep.constraints), proof)


def evaluate_instance(problem: Problem, inst: Instance, sets: Mapping[str, ConstraintsLike], *,
                      config: SolverConfig | None = None, criteria: Criteria = Criteria(),
                      model: Model | None = None, local: LocalSearch | None = None,
                      rng_local: np.random.Generator | None = None,
                      rng_constraints: np.random.Generator | None = None, n_random: int = 1,
                      shortcut: Certifier | None = None, raise_unbounded: bool = True,
                      catch_instantiate: bool = True, settle_early: bool = False) -> InstanceEvaluation:
    """Every set of ``sets`` (name → "paper", "primary", a ``ConstraintSet`` or a list of ``Constraint``) on
    ``inst``, as the module docstring says: one model and one local search (``n_random`` random starts) shared
    by the sets.  ``raise_unbounded`` is ``solve_instance``'s, ``settle_early`` ``solve_prepared``'s; any error
    other than a failed instantiation propagates (the sets after it are not evaluated)."""
    s = seeds(inst.seed if inst.seed is not None else 0)
    t0 = time.perf_counter()
    model = model if model is not None else problem.build(inst)
    t1 = time.perf_counter()
    local = local if local is not None else local_search(problem, inst, rng_local or s.local(), n_random)
    t2 = time.perf_counter()
    config = SolverConfig() if config is None else config
    results: dict[str, SetResult] = {}
    for name, cons in sets.items():
        rng = rng_constraints if rng_constraints is not None else s.constraints()
        if catch_instantiate:
            try:
                given = instantiate(problem, inst, model, cons, rng)
            except AutotightError as e:
                results[name] = NotInstantiated(e)
                continue
        else:
            given = instantiate(problem, inst, model, cons, rng)
        if shortcut is not None:  # the checks run once, for the certificate and, if it does not decide, the SDP
            prep = prepare(problem, inst, given, config=config, model=model, local=local)
            proved = certify_local(problem, inst, prep, shortcut, criteria)
            results[name] = proved if proved is not None else solve_prepared(
                problem, inst, prep, set_name(given, model), criteria=criteria, raise_unbounded=raise_unbounded,
                settle_early=settle_early)
            continue
        results[name] = solve_instance(problem, inst, given, config=config, criteria=criteria, model=model,
                                       local=local, raise_unbounded=raise_unbounded, settle_early=settle_early)
    return InstanceEvaluation(inst, model, local, results, {"build_s": t1 - t0, "local_s": t2 - t1})


def evaluate(problem: Problem, params: Mapping[str, Any], seed: int, sets: Mapping[str, ConstraintsLike],
             **kw: Any) -> InstanceEvaluation:
    """``evaluate_instance`` on the instance ``problem.generate(params, seed)`` (so its generators default to
    those of ``pipeline.seeds(seed)``); ``kw``: ``evaluate_instance``'s keywords."""
    inst = problem.generate(dict(params), seed)
    return evaluate_instance(problem, inst, sets, **kw)


def summary(result: SetResult) -> dict[str, Any]:
    """The plain row of one set's result, as ``check`` and the held-out validation count it: outcome
    ("tight", "undecided" or "not tight"), log_svr (NaN without an SDP), n_constraints (0 when not
    instantiated), reason, status (the solver's; "not instantiated" or "certified" without an SDP),
    rel_gap (the verdict's, or the certificate's relative bound; NaN when not instantiated) and calls
    (SDP solver calls made: every attempt, at least 1; 0 without an SDP)."""
    if isinstance(result, NotInstantiated):
        return {"outcome": "not tight", "log_svr": math.nan, "n_constraints": 0, "reason": result.reason,
                "status": "not instantiated", "rel_gap": math.nan, "calls": 0}
    if isinstance(result, Certified):
        return {"outcome": "tight", "log_svr": math.nan, "n_constraints": result.n_constraints,
                "reason": result.proof.reason(), "status": "certified", "rel_gap": result.proof.rel_bound,
                "calls": 0}
    return {"outcome": result.outcome, "log_svr": float(result.log_svr), "n_constraints": result.n_constraints,
            "reason": result.verdict.reason, "status": result.sdp.status, "rel_gap": float(result.verdict.rel_gap),
            "calls": max(1, len(result.attempts))}
