"""discover(): learn → tighten greedily → reduce → check on held-out instances → compare with the paper."""

from __future__ import annotations

from ..threads import single_blas_thread
import time
from pathlib import Path
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..constraint_set import ConstraintSet, ConstraintsLike
from ..model import Constraint, Model
from ..pipeline import local_search, seeds, solve_instance
from ..problem import Instance, Problem, load
from ..sdp.config import SolverConfig
from ..tightness import Criteria, Verdict
from ..unbounded import UnboundedRelaxation, rank_out_of_reach
from ..validate import check_instance
from .catalog import Catalog, instantiate, learn
from .compare import paper_in_span, resemblance
from .discovered import DiscoveredSet
from .learn import LearnOptions
from .oracle import Oracle
from .reduce import ReduceResult, reduce_pairs
from .tighten import TightenResult, tighten


@dataclass
class HeldOut:
    """Tightness of a constraint set re-instantiated on fresh instances at the same parameters."""

    seeds: list[int]
    tight: list[bool]
    log_svr: list[float]
    rel_gap: list[float]
    status: list[str]
    issues: list[str] = field(default_factory=list)
    primary_tight: list[bool] = field(default_factory=list)

    @property
    def fraction(self) -> float:
        return float(np.mean(self.tight)) if self.tight else float("nan")

    @property
    def primary_fraction(self) -> float:
        """The primary constraints' own fraction on the same instances (what the set adds is the difference)."""
        return float(np.mean(self.primary_tight)) if self.primary_tight else float("nan")


@dataclass
class DiscoveryResult:
    problem: str
    params: dict[str, Any]
    seed: int
    instance: Instance
    model: Model
    catalog: Catalog
    tightened: TightenResult
    reduction: ReduceResult | None
    discovered: DiscoveredSet
    constraints: list[Constraint]
    heldout: HeldOut
    paper_heldout: HeldOut | None
    paper_tight: bool | None
    paper_span: dict[str, dict]
    resembles: dict[str, str]
    n_solves: int
    times: dict[str, float]
    best_local_cost: float
    final_log_svr: float
    final_verdict: Verdict | None = None
    final_status: str = ""
    accept: str = "rank"

    @property
    def tight(self) -> bool:
        """Tight under the acceptance used (``accept``: rank, or cost only)."""
        return self.tightened.tight

    @property
    def constraint_set(self) -> ConstraintSet:
        """The discovered set, ready for ``autotight.solve(constraints=…)`` on any instance."""
        return ConstraintSet(self.discovered)

    def save(self, path: str | Path, replace: bool = False) -> Path:
        """The set as JSON with the learning instance's constraints and this run's summary; an existing file
        is kept unless ``replace`` (``DiscoveredSet.save``).  Returns the path written."""
        return self.discovered.save(path, self.model, self.constraints, {"summary": self.summary()}, replace=replace)

    def explanation(self) -> str:
        """Why the result is what it is, in one line (for rank acceptance that is not reached: why)."""
        v = self.final_verdict or self.tightened.verdict
        if self.tight:
            return f"{self.accept}-tight: {self.tightened.message}"
        out_of_reach = rank_out_of_reach(self.model, self.model.all_constraints() + self.constraints)
        why = f"; {out_of_reach}" if out_of_reach else ""
        if self.accept == "rank" and v.cost_tight:
            return (f"rank {self.model.d} is not reached: {v.reason} with every learned candidate that cuts the "
                    f"SDP solution{why}; the relaxation is cost-tight (relative gap {v.rel_gap:.1e}): its optimum "
                    "is not unique in the lifting, so use --accept cost")
        if self.accept == "rank":
            return f"rank {self.model.d} is not reached: {v.reason}; {self.tightened.message}{why}"
        return f"not {self.accept}-tight: {v.reason}; {self.tightened.message}"

    def summary(self) -> dict[str, Any]:
        """The JSON summary (``autotight discover --json``)."""
        n_prim = len(self.model.primary())
        return {
            "problem": self.problem, "params": self.params, "seed": self.seed, "tight": self.tight,
            "accept": self.accept, "message": self.tightened.message, "explanation": self.explanation(),
            "log_svr": self.final_log_svr,
            "final_rel_gap": None if self.final_verdict is None else self.final_verdict.rel_gap,
            "final_cost_tight": None if self.final_verdict is None else self.final_verdict.cost_tight,
            "final_rank_tight": None if self.final_verdict is None else self.final_verdict.rank_tight,
            "final_status": self.final_status,
            "primary_unbounded_blocks": self.tightened.primary_unbounded,
            "log_svr_primary": self.tightened.primary_verdict.log_svr,
            "n_primary": n_prim, "n_paper": len(self.model.paper_constraints()),
            "n_candidates": len(self.catalog.candidates()), "n_candidate_pairs": len(self.catalog.by_pair()),
            "n_rejected_heldout": len(self.catalog.rejected()),
            "n_greedy_pairs": len(self.tightened.chosen),
            "n_minimal": len(self.constraints), "n_minimal_pairs": len(self.discovered.pairs),
            "minimal_is_reduced": self.reduction is not None,
            "irreducible": bool(self.reduction and self.reduction.irreducible),
            "n_reduce_solves": None if self.reduction is None else self.reduction.n_solves,
            "n_verify_solves": None if self.reduction is None else self.reduction.n_verify_solves,
            "irreducibility_proof": None if self.reduction is None else self.reduction.proof,
            "heldout_tight_fraction": self.heldout.fraction, "heldout_instances": len(self.heldout.seeds),
            "heldout_primary_tight_fraction": self.heldout.primary_fraction,
            "paper_tight": self.paper_tight,
            "paper_heldout_tight_fraction": None if self.paper_heldout is None else self.paper_heldout.fraction,
            "paper_in_span": self.paper_span, "resembles": self.resembles,
            "pairs": [f"{t}:{i}" for t, i in self.discovered.pairs], "n_solves": self.n_solves,
            "best_local_cost": self.best_local_cost, "times": self.times,
            "spectral_gaps": {g.group.name: g.gap_decades for g in self.catalog.groups},
            "spectral_gaps_ignored": {g.group.name: g.gaps()["ignored"] for g in self.catalog.groups
                                      if g.ignored_gap_decades is not None},
        }


Maker = Callable[[Instance, Model, np.random.Generator], tuple[ConstraintsLike, list[str]]]


def heldout_check(problem: Problem, params: dict[str, Any], seeds_: Sequence[int], sets: dict[str, Maker],
                  criteria: Criteria, config: SolverConfig, n_random: int = 1) -> dict[str, HeldOut]:
    """For each fresh instance (one local search each, shared by the sets), solve it with every set's
    constraints through the per-instance pipeline (``autotight.pipeline.solve_instance``)."""
    out = {name: HeldOut([], [], [], [], []) for name in sets}
    for s in seeds_:
        inst = problem.generate(params, s)
        model = problem.build(inst)
        loc = local_search(problem, inst, seeds(s).local(), n_random)
        for name, make in sets.items():
            cons, issues = make(inst, model, seeds(s).constraints())
            r = solve_instance(problem, inst, cons, config=config, criteria=criteria, model=model, local=loc,
                               raise_unbounded=False)
            h = out[name]
            h.issues += [f"seed {s}: {i}" for i in issues]
            h.seeds.append(int(s)); h.tight.append(r.tight); h.log_svr.append(r.log_svr)
            h.rel_gap.append(r.verdict.rel_gap); h.status.append(r.sdp.status)
    return out


def default_train(problem: Problem) -> int:
    """The module's ``DEFAULT_TRAIN`` (training instances the set is reduced over; 1 if absent)."""
    from .. import module_parts

    return module_parts.default_train(problem)


def n_training(problem: Problem, n_train: int | None, ranged: bool) -> int:
    """The training instances a discovery uses: ``n_train`` if given, else 2 over a range, else the
    module's ``DEFAULT_TRAIN``; more than 1 (or a range) means the range flow."""
    n = n_train if n_train is not None else (2 if ranged else default_train(problem))
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        from ..errors import ParameterError

        raise ParameterError(f"the number of training instances must be an int ≥ 1, got {n!r}")
    return int(n)


def default_groups(problem: Problem, groups: str | Sequence[Sequence[str]] | None) -> str | Sequence[Sequence[str]]:
    """``groups``, or when None the problem module's ``DEFAULT_GROUPS`` (else "factors")."""
    from .. import module_parts

    return module_parts.default_groups(problem) if groups is None else groups


@single_blas_thread
def discover(problem: Problem | str, params: dict[str, Any] | None = None, seed: int = 0, *,
             groups: str | Sequence[Sequence[str]] | None = None, learn_options: LearnOptions = LearnOptions(),
             criteria: Criteria = Criteria(), solver: SolverConfig | None = None, n_heldout: int = 10,
             n_random: int = 2, verify: bool = False, compare: bool = True,
             progress: Callable[[str, str], None] | None = None) -> DiscoveryResult:
    """Discover an irreducible set of redundant constraints for ``problem`` at ``params``.

    The learning instance is ``generate(params, seed)``; held-out instances use seeds
    seed + 1 … seed + n_heldout (generators from ``autotight.pipeline.seeds``).  ``solver`` (a
    ``SolverConfig``) is used for every SDP solve, tightening and held-out check alike.  groups: the
    learning groups (None: the module's ``DEFAULT_GROUPS``, else "factors"); the tightening starts as the
    module's ``DEFAULT_TIGHTEN`` says ("greedy" by default, or "all": ``tighten.tighten``).  The reduction's
    irreducibility proof is monotonicity; ``verify`` re-solves to check it numerically.  ``criteria.accept``
    decides what counts as tight (rank and cost, cost only, or certified) for tightening, reduction
    and the held-out check.  Raises UnboundedRelaxation when the SDP stays unbounded and no learned
    candidate bounds its unbounded blocks.  progress(stage, text) is called as work proceeds.
    """
    prob = load(problem) if isinstance(problem, str) else problem
    config = SolverConfig() if solver is None else solver
    groups = default_groups(prob, groups)
    say = progress or (lambda stage, text: None)
    full = prob.parse_params(params)
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    inst = prob.generate(full, seed)
    model = prob.build(inst)
    loc = local_search(prob, inst, seeds(seed).local(), n_random)
    check_instance(prob, inst, model, loc)  # NaN/inf data, or a cost that does not match its lifting
    rng = seeds(seed).constraints()
    times["local_s"] = time.perf_counter() - t0
    cat = learn(prob, inst, model, rng, groups, learn_options, progress=lambda g: say("learn", g))
    times["sampling_s"] = cat.times["sampling_s"]
    times["nullspace_s"] = cat.times["nullspace_s"]
    pairs = cat.by_pair()
    oracle = Oracle(model, pairs, loc.best.cost, criteria, config,
                    best_theta=prob.lift(inst, loc.best.state))
    t = time.perf_counter()
    from .. import module_parts

    start = module_parts.default_tighten(prob)  # the module's tightening start (tighten.tighten)
    tr = tighten(oracle, progress=lambda s: say("tighten", s), start=start)
    times["tighten_s"] = time.perf_counter() - t
    if tr.unbounded:
        raise UnboundedRelaxation(tr.message, tr.unbounded)
    t = time.perf_counter()
    red = None
    chosen = tr.chosen
    if tr.tight and tr.chosen:
        red = reduce_pairs(oracle, tr.chosen, tr.sdp, verify=verify, progress=lambda s: say("reduce", s))
        chosen = red.pairs
    times["reduce_s"] = time.perf_counter() - t
    constraints = [c for p in chosen for c in pairs[p]]
    final_v, final_res = tr.verdict, tr.sdp
    if red is not None:
        final_v, final_res = oracle.solve(chosen, stage="final")
    n_solves = oracle.n_solves
    times["sdp_s"] = oracle.solve_time_s
    ds = DiscoveredSet(prob.name, full, seed, list(chosen), asdict(learn_options),
                       {"criteria": asdict(criteria), "tight": tr.tight, "message": tr.message,
                        "accept": oracle.accept, "reduced": red is not None},
                       groups if isinstance(groups, str) else [list(g) for g in groups])
    t = time.perf_counter()
    held_seeds = [seed + 1 + k for k in range(n_heldout)]
    sets: dict[str, Maker] = {"primary": lambda i, m, r: ("primary", [])}
    if tr.tight and chosen:
        sets["discovered"] = lambda i, m, r: instantiate(prob, i, ds.pairs, r, ds.options(), m, groups, strict=False)
    if compare and model.paper:
        sets["paper"] = lambda i, m, r: ("paper", [])
    held = heldout_check(prob, full, held_seeds, sets, criteria, config, n_random) if tr.tight else {}
    hold = held.get("discovered", held.get("primary", HeldOut([], [], [], [], [])))
    hold.primary_tight = list(held["primary"].tight) if held else []
    times["heldout_s"] = time.perf_counter() - t
    paper_tight, span, like = None, {}, {}
    paper_hold = held.get("paper")
    if compare and model.paper:
        t = time.perf_counter()
        pv, _ = oracle.solve_extra(model.paper_constraints(), stage="paper")
        paper_tight = oracle.ok(pv)
        span = paper_in_span(cat)
        like = {c.name: resemblance(c, cat) for c in constraints}
        times["compare_s"] = time.perf_counter() - t
    times["total_s"] = time.perf_counter() - t0
    say("done", "")
    return DiscoveryResult(prob.name, full, seed, inst, model, cat, tr, red, ds, constraints, hold, paper_hold,
                           paper_tight, span, like, n_solves, times, loc.best.cost, final_res.log_svr, final_v,
                           final_res.status, oracle.accept)
