"""The one pipeline for one instance: build → constraints → local search → SDP → recover → judge → errors.

``solve_instance`` is what ``autotight.solve`` runs, and what ``autotight.evaluate`` runs per constraint set
for ``check``, every trial of a report sweep and discovery's held-out check.  Its steps are functions of
their own: ``prepare`` (model, constraints, local search, checks) → ``solve_relaxation`` (the SDP) →
``recover_estimate`` (the SDP's estimate and its refinement) → ``judge_relaxation`` (polish, certificate,
verdict).

Seeds (one scheme everywhere, see ``seeds``): an instance with seed s is
``generate(params, default_rng(s))``; its random local starts draw from ``default_rng([s, 1])``,
re-instantiating a learned set draws from ``default_rng([s, 2])`` and the fresh samples of the validity
check from ``default_rng([s, 3])``.

Before any verdict every constraint of the SDP is evaluated at the feasible points held
(``feasible_points``, ``autotight.validity``): a set that cuts one of them off is an
``InvalidConstraintError``, never a verdict.  The upper bound U of a verdict is the lowest cost of a
feasible point found: the local solves (from the ground truth and from random starts), the state
recovered from the SDP solution (its own cost), and one local solve started there.  When the SDP's
estimate beats every local search, the random start counts as trapped and the relaxation can still be
judged tight.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from collections.abc import Sequence
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from .certificate import Certificate, certificate
from .constraint_set import ConstraintsLike, resolve, set_name
from .dual_polish import polished
from .errors import ProblemModuleError
from .unbounded import rank_out_of_reach
from .model import Constraint, Model
from .pretty import column_names
from .problem import Instance, LocalResult, Problem
import autotight.sdp as sdp
from .sdp.backend import SettledRule
from .sdp.config import SolverConfig
from .sdp.result import SDPResult, Status
from .sdp.scaling import block_scale
from .svec import reusing_entries
from .threads import single_blas_thread
from .tightness import NOT_TIGHT, Criteria, Verdict, accuracy_of, bracket, judge
from .unbounded import UnboundedRelaxation, is_unbounded, unbounded_blocks, unbounded_message
from .validate import check_instance
from .validity import check_valid

#: relative cost excess over U above which a local solve counts as trapped in a worse minimum
TRAP_RTOL = 1e-4


@dataclass(frozen=True)
class Seeds:
    """The generators of one instance seed s (see the module docstring)."""

    instance: int

    def local(self) -> np.random.Generator:
        return np.random.default_rng([self.instance, 1])

    def constraints(self) -> np.random.Generator:
        return np.random.default_rng([self.instance, 2])

    def validity(self) -> np.random.Generator:
        return np.random.default_rng([self.instance, 3])


def seeds(instance_seed: int) -> Seeds:
    return Seeds(int(instance_seed))


@dataclass
class LocalSearch:
    """Local solves from the ground truth and from random starts; ``best`` is the lowest cost."""

    from_truth: LocalResult
    from_random: list[LocalResult]

    @property
    def best(self) -> LocalResult:
        return min([self.from_truth, *self.from_random], key=lambda r: r.cost)


def local_search(problem: Problem, inst: Instance, rng: np.random.Generator, n_random: int = 1) -> LocalSearch:
    truth = problem.local_solve(inst, inst.truth)
    rand = [problem.local_solve(inst, problem.random_state(inst, rng)) for _ in range(n_random)]
    return LocalSearch(truth, rand)


def is_trapped(cost: float, global_cost: float, rtol: float = TRAP_RTOL, floor: float = 1e-9) -> bool:
    """A local cost above the global cost by more than ``rtol`` relative (floored at ``floor``)."""
    if not np.isfinite(cost):
        return True
    return bool(cost - global_cost > rtol * max(abs(global_cost), floor))


@dataclass
class SolveResult:
    """One instance solved with one constraint set.  Plain attributes; ``record()`` is the JSON form.

    upper: U, the best feasible cost found (local solves, the SDP's estimate and its refinement);
    refined: the local solve started at the SDP's estimate (None when X was unusable);
    certificate: what the SDP's multipliers prove about the point of cost U (``certified``, ``bound``);
    log_svr_marginal: log SVR of the problem's own reduced X (a module's optional ``marginal_log_svr``,
    e.g. continuous time's marginalised X whichever formulation was solved), else None;
    attempts: every SDP solve made (a second one when the first verdict was undecided).
    """

    problem: str
    instance: Instance
    constraint_set: str
    n_constraints: int
    sdp: SDPResult
    verdict: Verdict
    local: LocalSearch
    estimate: dict[str, np.ndarray] | None
    refined: LocalResult | None
    upper: float
    errors_sdp: dict[str, float]
    errors_local: dict[str, float]
    certificate: Certificate | None = None
    log_svr_marginal: float | None = None
    attempts: list[dict[str, Any]] = field(default_factory=list)
    times: dict[str, float] = field(default_factory=dict)

    @property
    def tight(self) -> bool:
        return self.verdict.tight

    @property
    def log_svr(self) -> float:
        return self.sdp.log_svr

    @property
    def outcome(self) -> str:
        """"tight", "not tight" or "undecided"."""
        return getattr(self.verdict, "outcome", "tight" if self.verdict.tight else "not tight")

    @property
    def trapped(self) -> bool:
        """Whether the (first) random-start local solve ended above U."""
        rand = self.local.from_random
        return bool(rand) and is_trapped(rand[0].cost, self.upper)

    @property
    def sdp_beats_local(self) -> bool:
        """The SDP's estimate (refined) is better than every local search: the local search was trapped."""
        return self.upper < self.local.best.cost and is_trapped(self.local.best.cost, self.upper)

    def record(self) -> dict[str, Any]:
        lt, v = self.local.from_truth, self.verdict
        return {
            "problem": self.problem, "params": self.instance.params, "seed": self.instance.seed,
            "constraint_set": self.constraint_set, "n_constraints": self.n_constraints,
            "solver": self.sdp.solver, "status": self.sdp.status, "outcome": self.outcome, "tight": v.tight,
            "accept": v.accept, "rank_tight": v.rank_tight, "cost_tight": v.cost_tight, "verdict": v.reason,
            "log_svr": self.sdp.log_svr, "sdp_cost": self.sdp.primal_cost, "sdp_dual_cost": self.sdp.dual_cost,
            "sdp_dual_cost_raw": None if np.isnan(self.sdp.dual_cost_raw) else self.sdp.dual_cost_raw,
            "local_cost": lt.cost, "local_cost_random": [r.cost for r in self.local.from_random],
            "best_local_cost": self.local.best.cost,
            "refined_cost": None if self.refined is None else self.refined.cost,
            "upper_bound": self.upper, "rel_gap": v.rel_gap, "trapped": self.trapped,
            "sdp_beats_local": self.sdp_beats_local, "solve_time_s": self.sdp.solve_time_s,
            "undecided": v.undecided, "bracket": {"lower": v.lower, "primal": v.primal, "upper": v.upper,
                                                  "accuracy": v.accuracy, "tolerance": v.tolerance,
                                                  "frame": v.frame},
            "log_svr_marginal": self.log_svr_marginal,
            "certified": None if self.certificate is None else self.certificate.certified,
            "certificate": None if self.certificate is None else self.certificate.record(),
            "errors_sdp": self.errors_sdp, "errors_local": self.errors_local, "attempts": self.attempts,
            "times": self.times,
        }


def _attempt(res: SDPResult, verdict: Verdict | None) -> dict[str, Any]:
    return {"status": res.status, "primal_cost": res.primal_cost, "dual_cost": res.dual_cost,
            "dual_cost_raw": None if np.isnan(res.dual_cost_raw) else res.dual_cost_raw,
            "log_svr": res.log_svr, "solve_time_s": res.solve_time_s, "outcome": getattr(verdict, "outcome", None),
            "message": res.message}


def has_marginal(problem: Problem) -> bool:
    """Whether the module reports log SVR on its own reduced X (an optional ``marginal_log_svr``)."""
    return hasattr(problem.module, "marginal_log_svr")


def marginal_svr(problem: Problem, inst: Instance, res: SDPResult) -> float | None:
    """The module's ``marginal_log_svr(instance, X, cliques)`` when it defines one and X is usable."""
    if not has_marginal(problem) or not res.usable or res.X is None:
        return None
    return problem.marginal_log_svr(inst, res.X, res.cliques)


def dual_certificate(problem: Problem, inst: Instance, model: Model, cons: list, res: SDPResult,
                     best: LocalResult, criteria: Criteria) -> tuple[SDPResult, Certificate | None]:
    """``res`` with the better of its own multipliers and their polish at the best feasible point
    (``autotight.dual_polish``), and what the kept y proves about that point
    (``autotight.certificate``; None when the solve returned no y)."""
    return polished(model.Q, cons, res, problem.lift(inst, best.state), d=model.d, tol=criteria.gap_tol,
                    floor=criteria.cost_atol / criteria.gap_tol,  # the bracket's absolute tolerance
                    names=column_names(model.variables))


def certifies_local(problem: Problem, inst: Instance, model: Model, cons: list, best: LocalResult,
                    criteria: Criteria) -> Callable[[np.ndarray], bool]:
    """The SDP solve's stop rule (``sdp.solve``'s ``stop``): whether multipliers y certify the best local solution
    x̂ (``certificate.certificate`` at its lifting, with the bracket's tolerances).  Then x̂ is globally optimal
    to the certificate's bound, the relaxation's optimum is f(x̂) to that bound, and more accuracy of the solve
    cannot move the verdict's bracket; the verdict itself is still judged as usual from the iterate returned."""
    Th = problem.lift(inst, best.state)

    def rule(y: np.ndarray) -> bool:
        if not np.all(np.isfinite(y)):
            return False
        cert = certificate(model.Q, cons, y, Th, d=model.d, tol=criteria.gap_tol,
                           floor=criteria.cost_atol / criteria.gap_tol)
        return bool(cert.certified)

    return rule


@dataclass(frozen=True)
class GapSettled:
    """The SDP solve's retry rule (``sdp.solve``'s ``settled``): whether a result, usable or the best iterate of a
    solve that stopped early, already proves the relaxation not tight against the best feasible cost U = ``upper``
    (``tightness.bracket`` on its own accuracy, in the frame it was solved in; ``partial`` for the iterate).  Another
    solve cannot change that verdict: a retry replaces a usable result only when Solved, and then its P is the
    relaxation's optimum to its accuracy, below U by more than the tolerance whenever this one's is (both within
    their accuracies of the same optimum); so is the fallback's."""

    upper: float
    criteria: Criteria

    def __call__(self, res: SDPResult, Q: sp.csr_array, As: Sequence[sp.coo_array], b: np.ndarray) -> bool:
        if res.X is None or res.y is None or not np.all(np.isfinite(res.y)):
            return False
        return bracket(res, self.upper, self.criteria, accuracy_of(res, Q, As, b), partial=True)[0] == NOT_TIGHT


@dataclass(frozen=True)
class EarlyGapSettled(GapSettled):
    """``GapSettled``, also asked of an iterative solver's iterates (``sdp.backend.EarlySettle``): the solve ends at
    the first iterate whose bracket proves the relaxation not tight, the evidence a finished solve would give (the
    bracket of an iterate counts its residuals in its accuracy).  ``may_settle``: U − P > gap_tol·|U| +
    cost_atol·scale/2 + |P − D| (scale = max|Q_ij|·tr X), which the bracket's "not tight" implies: its tolerance is
    gap_tol·|U| + cost_atol·scale and its accuracy at least |P − D| (the half spares a trace read off the iterate's
    blocks, which agree on shared columns only to its residuals)."""

    def may_settle(self, primal: float, dual: float, scale: float) -> bool:
        c = self.criteria
        return self.upper - primal > c.gap_tol * abs(self.upper) + 0.5 * c.cost_atol * scale + abs(primal - dual)


def gap_settled(upper: float, criteria: Criteria, early: bool = False) -> SettledRule:
    """``GapSettled`` at U = ``upper``; ``early``: ``EarlyGapSettled`` (the solve may end at an iterate)."""
    return (EarlyGapSettled if early else GapSettled)(float(upper), criteria)


#: fresh feasible states (the module's sampler around the truth) on which every constraint is checked
N_VALIDITY_SAMPLES = 2


def feasible_points(problem: Problem, inst: Instance, local: LocalSearch,
                    rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The lifted feasible points held before the SDP (label → Θ), on which ``validity.check_valid`` checks
    every constraint: the ground truth, ``N_VALIDITY_SAMPLES`` fresh states of the sampler around it (drawn
    from ``rng``), the local solution from the truth and those from random starts."""
    points = {"the ground truth": problem.lift(inst, inst.truth)}
    for k in range(N_VALIDITY_SAMPLES):
        points[f"fresh feasible sample {k}"] = problem.lift(inst, problem.sample(inst, rng))
    points["the local solution from the truth"] = problem.lift(inst, local.from_truth.state)
    for k, r in enumerate(local.from_random):
        points[f"the local solution from random start {k}"] = problem.lift(inst, r.state)
    return points


def block_scale_at(problem: Problem, inst: Instance, model: Model, state: dict[str, np.ndarray],
                   config: SolverConfig) -> np.ndarray | None:
    """The SDP's diagonal scaling D from the lifted ``state`` (``sdp.scaling.block_scale``), or
    None when ``config.scale`` is "none"."""
    if config.scale == "none":
        return None
    return block_scale(model.variables, [problem.lift(inst, state)])


@dataclass
class Prepared:
    """One instance ready for its SDP (``prepare``): every input built, resolved and checked.

    model: the instance's ``Model``; config: the solver configuration sized for it
    (``SolverConfig.for_size``: "auto" picks the backend); constraints: every constraint of the SDP
    (homogenisation, primary and the set's own, ``constraint_set.resolve``); local: the local searches;
    times: ``build_s`` (model and constraint set), ``constraints_s`` (the set alone), ``local_s`` (the local
    searches and the checks), in seconds.
    """

    model: Model
    config: SolverConfig
    constraints: list[Constraint]
    local: LocalSearch
    times: dict[str, float]


def prepare(problem: Problem, inst: Instance, constraints: ConstraintsLike = None, *,
            config: SolverConfig | None = None, n_random: int = 1, model: Model | None = None,
            local: LocalSearch | None = None, rng_local: np.random.Generator | None = None,
            rng_constraints: np.random.Generator | None = None) -> Prepared:
    """Build (unless ``model`` is given), resolve ``constraints``, search locally (unless ``local`` is given),
    then check the instance's data (``validate.check_instance``) and every constraint on the feasible points
    held (``feasible_points``, ``validity.check_valid``: an ``InvalidConstraintError`` for a set that cuts
    one off).  In this order; the generators default to the seed scheme of the module docstring."""
    config = SolverConfig() if config is None else config
    s = seeds(inst.seed if inst.seed is not None else 0)
    t0 = time.perf_counter()
    model = model if model is not None else problem.build(inst)
    config = config.for_size(model.variables.N)  # "auto" picks the backend by the model's size
    tm = time.perf_counter()
    cons = resolve(constraints, problem, inst, model, rng_constraints or s.constraints())
    t1 = time.perf_counter()
    local = local if local is not None else local_search(problem, inst, rng_local or s.local(), n_random)
    check_instance(problem, inst, model, local)  # NaN/inf data, or a cost that does not match its lifting
    check_valid(problem.name, cons, feasible_points(problem, inst, local, s.validity()))
    t2 = time.perf_counter()
    # build_s: the model and its constraint set; constraints_s: the set alone (templates applied, or re-learned)
    return Prepared(model, config, cons, local, {"build_s": t1 - t0, "constraints_s": t1 - tm, "local_s": t2 - t1})


@dataclass
class Relaxation:
    """The SDP step's solves (``solve_relaxation``).  res: the solve kept (scaled unless only the plain data
    gave a usable solution); unscaled: the other solve when a second one was made, else None; scale: the
    diagonal D of X = D X' D the scaled solve used (None: no scaling); certified: when the scaled solve was
    not usable, ``dual_certificate`` of its multipliers at the best local solution (the polished solve and
    the certificate), else None."""

    res: SDPResult
    unscaled: SDPResult | None
    scale: np.ndarray | None
    certified: tuple[SDPResult, Certificate | None] | None = None


def solve_relaxation(problem: Problem, inst: Instance, prep: Prepared, *, raise_unbounded: bool = True,
                     criteria: Criteria = Criteria(), settle_early: bool = False) -> Relaxation:
    """The SDP of ``prep`` in the frame of ``block_scale_at`` at the best local solution, and once more on the
    plain data when that solve is not usable, unless it found a ray (unbounded in either frame) or its multipliers,
    polished at the best local solution, certify that solution (``dual_certificate``): the relaxation's optimum is
    then known to the certificate's bound and another solve cannot change the verdict.  A solve whose bracket
    already says not tight (``gap_settled``) is not solved again: not retried when usable, and, when it stopped
    early with its best iterate, neither by the fallback backend nor on the plain data.
    A ray of unboundedness in either solve raises ``UnboundedRelaxation`` (naming the unbounded blocks) when
    ``raise_unbounded``."""
    model, cons, config = prep.model, prep.constraints, prep.config
    scale = block_scale_at(problem, inst, model, prep.local.best.state, config)
    stop = certifies_local(problem, inst, model, cons, prep.local.best, criteria)
    settled = gap_settled(prep.local.best.cost, criteria, settle_early)
    res = sdp.solve_model(model, cons, config, scale, stop=stop, settled=settled)
    unscaled, certified = None, None
    if not res.usable and res.y is not None and not is_unbounded(res):
        certified = dual_certificate(problem, inst, model, cons, res, prep.local.best, criteria)
    if (scale is not None and not res.usable and not is_unbounded(res) and not res.settled
            and not (certified and certified[1] and certified[1].certified)):
        # the scaling did not help this solve: the plain data (a ray proves unboundedness in either frame)
        unscaled = sdp.solve_model(model, cons, config, None, stop=stop, settled=settled)
        if unscaled.usable:
            res, unscaled, certified = unscaled, res, None
    ray = next((r for r in (res, unscaled) if r is not None and is_unbounded(r)), None)
    if raise_unbounded and ray is not None:  # a ray proves unboundedness whichever data it was found with
        blocks = unbounded_blocks(model, ray)
        raise UnboundedRelaxation(unbounded_message(model, ray, blocks), blocks)
    return Relaxation(res, unscaled, scale, certified)


@dataclass
class Recovery:
    """What the SDP's solution gives as a feasible point (``recover_estimate``).  estimate: the state
    recovered from X (None when X was unusable or recovery failed); refined: the local solve started there;
    best: the lowest-cost feasible point held (local searches, estimate, refined); note: text for the
    verdict's reason ("" or "; recovery failed …")."""

    estimate: dict[str, np.ndarray] | None
    refined: LocalResult | None
    best: LocalResult
    note: str = ""


def recover_estimate(problem: Problem, inst: Instance, prep: Prepared, res: SDPResult,
                     criteria: Criteria) -> Recovery:
    """Recover a state from ``res``'s X, refine it by a local solve and check every constraint at both.  A
    recovery error on an X of log SVR ≤ ``criteria.min_log_svr`` (far from rank d) is noted, else raised."""
    estimate = refined = None
    best = prep.local.best
    note = ""
    if res.Theta is not None and res.usable:
        try:
            estimate = problem.recover(inst, res.Theta)
        except ProblemModuleError as e:  # on an X far from rank d this is reported, not raised
            if not res.log_svr <= criteria.min_log_svr:
                raise
            note = f"; recovery failed on a solution of rank > d: {e}"
        else:
            refined = problem.local_solve(inst, estimate)
            rounded = LocalResult(estimate, problem.lifted_cost(inst, estimate, prep.model), 0, True,
                                  message="the SDP's estimate")
            check_valid(problem.name, prep.constraints, {"the SDP's estimate": problem.lift(inst, estimate),
                                                         "the refined SDP estimate": problem.lift(inst, refined.state)})
            best = min(best, refined, rounded, key=lambda r: r.cost)
    return Recovery(estimate, refined, best, note)


@dataclass
class Judgement:
    """The verdict on one relaxation (``judge_relaxation``).  res: the solve judged (multipliers polished);
    certificate: what its multipliers prove about the best point; attempts: every SDP solve made (as
    ``SolveResult.attempts``); note: text for the verdict's reason ("" or "; " + why rank d is out of reach)."""

    res: SDPResult
    verdict: Verdict
    certificate: Certificate | None
    attempts: list[dict[str, Any]]
    note: str = ""


def judge_relaxation(problem: Problem, inst: Instance, prep: Prepared, relax: Relaxation, best: LocalResult,
                     criteria: Criteria, retry_undecided: bool = True) -> Judgement:
    """Polish the multipliers at ``best`` and certify it (``dual_certificate``), judge against U = best.cost
    (``tightness.judge``); an undecided verdict of a solve that reached its tolerance (Solved) is solved
    once more at a 100× tighter tolerance where the backend can go tighter (kept when that solve is
    usable).  A solve that stopped short of its tolerance is not: it would stop short of a tighter one
    too (Clarabel's steps do not depend on its stopping tolerances: it retraces the same path to the same
    stop).  ``retry_undecided`` False: no such solve (the undecided verdict stands).  A verdict neither rank nor
    cost tight notes blocks that can grow at no cost (``unbounded.rank_out_of_reach``)."""
    model, cons, config, scale = prep.model, prep.constraints, prep.config, relax.scale
    upper = best.cost
    if relax.certified is not None and best is prep.local.best:  # made by ``solve_relaxation`` at this point
        res, cert = relax.certified
    else:
        res, cert = dual_certificate(problem, inst, model, cons, relax.res, best, criteria)
    verdict = judge(res, upper, criteria, cert, Q=model.Q, constraints=cons, scale=scale)
    attempts = ([] if relax.unscaled is None else [_attempt(relax.unscaled, None)]) + [_attempt(res, verdict)]
    tighter = replace(config, tol=max(config.tol / 100, 1e-13))
    # once more at a tighter tolerance, unless the solve stopped short of its own, or the backend cannot
    # go tighter (the IPM's floor): either way the same solve again
    if (retry_undecided and getattr(verdict, "undecided", False) and res.status == Status.SOLVED
            and sdp.effective_tol(tighter) < sdp.effective_tol(config)):
        res2 = sdp.solve_model(model, cons, tighter, scale)
        res2, cert2 = dual_certificate(problem, inst, model, cons, res2, best, criteria)
        verdict2 = judge(res2, upper, criteria, cert2, Q=model.Q, constraints=cons, scale=scale)
        attempts.append(_attempt(res2, verdict2))
        if res2.usable:
            res, verdict, cert = res2, verdict2, cert2
    note = ""
    if not verdict.rank_tight and not verdict.tight and (cert is None or cert.recession):
        out_of_reach = rank_out_of_reach(model, cons)  # '' unless some block can grow at no cost
        note = f"; {out_of_reach}" if out_of_reach else ""
    return Judgement(res, verdict, cert, attempts, note)


@single_blas_thread
def solve_instance(problem: Problem, inst: Instance, constraints: ConstraintsLike = None, *,
                   config: SolverConfig | None = None, criteria: Criteria = Criteria(), n_random: int = 1,
                   model: Model | None = None, local: LocalSearch | None = None,
                   rng_local: np.random.Generator | None = None,
                   rng_constraints: np.random.Generator | None = None,
                   raise_unbounded: bool = True, settle_early: bool = False,
                   retry_undecided: bool = True) -> SolveResult:
    """Solve ``inst`` with ``constraints`` (see ``autotight.constraint_set``) and judge tightness.

    ``model`` and ``local`` may be given to share them between several constraint sets of one
    instance; the generators default to the seed scheme of the module docstring.  The SDP is
    solved in the variables X' of X = D X' D with D from the best local solution's lifting
    (``block_scale_at``): every block of X' is then O(1), which the solver's relative accuracy needs
    when residual blocks are O(σ); the verdict may take its bracket's dual correction in that frame
    (``tightness.judge``'s ``scale``).  A verdict left undecided by a Solved solve's accuracy is solved once
    more at a 100× tighter tolerance (``judge_relaxation``); ``attempts`` records both.  An unbounded SDP
    (DualInfeasible: nothing bounds some blocks) raises ``UnboundedRelaxation`` naming those blocks in one
    line, unless ``raise_unbounded`` is False (then it is judged not tight, as discovery's held-out check
    needs for the primary constraints of a problem such as robust pose averaging).  ``settle_early``,
    ``retry_undecided``: ``solve_prepared``'s.

    The steps, in order: ``prepare`` (model, constraints, local search, checks) → ``solve_relaxation`` (the
    SDP) → ``recover_estimate`` (estimate, refinement, U) → ``judge_relaxation`` (polish, certificate,
    verdict, the retry).
    """
    with reusing_entries():  # the checks, the SDP's cover and the certificate read the same stacked entries
        prep = prepare(problem, inst, constraints, config=config, n_random=n_random, model=model, local=local,
                       rng_local=rng_local, rng_constraints=rng_constraints)
        return solve_prepared(problem, inst, prep, set_name(constraints, prep.model), criteria=criteria,
                              raise_unbounded=raise_unbounded, settle_early=settle_early,
                              retry_undecided=retry_undecided)


@single_blas_thread
def solve_prepared(problem: Problem, inst: Instance, prep: Prepared, name: str, *, criteria: Criteria = Criteria(),
                   raise_unbounded: bool = True, settle_early: bool = False,
                   retry_undecided: bool = True) -> SolveResult:
    """``solve_instance`` after its ``prepare`` step (``prep``; ``name``: the set's name in the result), for a
    caller that prepared the instance already (e.g. to try a certificate first).  ``settle_early``: an iterative
    solver may end at the first iterate whose bracket proves the relaxation not tight (``EarlyGapSettled``; the
    verdict is the same, its P, log SVR and reason are the iterate's).  ``retry_undecided`` False: an undecided
    verdict is not solved again at a tighter tolerance (``judge_relaxation``), for a caller to whom undecided
    already means "not shown tight" (discovery's training solves)."""
    t2 = time.perf_counter()
    relax = solve_relaxation(problem, inst, prep, raise_unbounded=raise_unbounded, criteria=criteria,
                             settle_early=settle_early)
    t3 = time.perf_counter()
    rec = recover_estimate(problem, inst, prep, relax.res, criteria)
    jd = judge_relaxation(problem, inst, prep, relax, rec.best, criteria, retry_undecided)
    jd.verdict.reason += rec.note + jd.note
    t4 = time.perf_counter()
    local = prep.local
    times = {**prep.times, "sdp_total_s": t3 - t2, "sdp_solve_s": jd.res.solve_time_s, "refine_s": t4 - t3,
             "local_truth_s": local.from_truth.time_s}
    return SolveResult(problem.name, inst, name, len(prep.constraints), jd.res, jd.verdict,
                       local, rec.estimate, rec.refined, rec.best.cost,
                       problem.errors(inst, rec.estimate) if rec.estimate is not None else {},
                       problem.errors(inst, local.from_truth.state), jd.certificate,
                       marginal_svr(problem, inst, jd.res), jd.attempts, times)
