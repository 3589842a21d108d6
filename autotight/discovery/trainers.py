"""Training instances of a discovery and the one way they are solved.

A ``Trainer`` is one training instance: its candidate pairs (learned on it, or carried to it by the
templates of a set learned elsewhere) and every tightness result known for it.  ``Solves`` runs every
training solve through ``autotight.pipeline.solve_instance`` (the function ``solve`` and ``check`` use,
with its block scaling and verdict), counts the solver calls per stage and caches each result per
instance: tightness is monotone in the constraint set, so a set containing a known tight set is tight
and a set inside a known loose one is loose.  An undecided verdict stands here: it is not solved again at a
tighter tolerance (``solve_instance``'s ``retry_undecided``), since to the selection it already means "not shown
tight" (the pair stays).  Held-out validation and ``check`` still make that solve, so what the set is judged by is
``solve``'s verdict.

An open cost gap is a proof for every subset.  A verdict whose bracket says "not tight" (``Verdict.cost_outcome``:
U − P > tol + accuracy, P = ⟨Q, X⟩ of the SDP's solution X of the set S) holds for every S′ ⊆ S: X is feasible
for S′'s relaxation, whose optimum is then at most P as well, against the same feasible cost U.  So a set
inside one with an open gap is not tight as certainly as the verdict was, with no solve of its own
(``Trainer.known``, even where a loose result otherwise decides only for exactly its set: undecided verdicts and
rank-only ones prove nothing for subsets).  A better feasible point found later lowers U and voids that
evidence (``Solves.solve`` drops it).

Seeds: the first training instance at the first point has the discovery's seed (it is the instance
``solve --seed`` solves there); training instance t at point i otherwise has SeedSequence((seed, i, t, 1));
held-out instances
SeedSequence((seed, i, t, 2)) (``heldout_seed``); ``check`` uses SeedSequence((seed, i, t)), so none of
a discovery's instances is one of ``check``'s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import AutotightError
from ..model import Constraint, Model, frobenius
from ..pipeline import LocalSearch, SolveResult, feasible_points, local_search, seeds, solve_instance
from ..problem import Instance, Problem
import autotight.sdp as sdp
from ..sdp.config import SolverConfig
from ..tightness import Criteria
from ..unbounded import UNBOUNDED_STATUSES, is_unbounded, unbounded_blocks
from ..validity import VALID_RTOL, relative_violations
from .catalog import Catalog, Pair, by_pair, learn
from .discovered import DiscoveredSet
from .learn import LearnOptions


def training_seed(seed: int, point: int, trial: int) -> int:
    """Seed of training instance ``trial`` at point ``point``: ``seed`` itself for the first one (the instance
    ``solve --seed SEED`` solves at the first point), else SeedSequence((seed, point, trial, 1))."""
    if point == 0 and trial == 0:
        return int(seed)
    return int(np.random.SeedSequence([seed, point, trial, 1]).generate_state(1, np.uint32)[0])


def heldout_seed(seed: int, point: int, trial: int) -> int:
    """Seed of held-out instance ``trial`` at point ``point``: SeedSequence((seed, point, trial, 2))."""
    return int(np.random.SeedSequence([seed, point, trial, 2]).generate_state(1, np.uint32)[0])


@dataclass
class Trainer:
    """One training instance: its candidate pairs and every tightness result known for it."""

    point: int
    seed: int
    inst: Instance
    model: Model
    local: LocalSearch
    pairs: dict[Pair, list[Constraint]]
    catalog: Catalog | None = None  # what was learned on it (None: carried by templates)
    #: "training", "replacement" (drawn for a training instance no candidate makes tight) or "held-out" (a failing
    #: held-out instance taken in)
    origin: str = "training"
    reached: bool = True
    message: str = ""
    #: not reached for a reason another instance of the problem shares (``select``: an unbounded block no candidate
    #: bounds, or rank 1 out of reach under ``accept="rank"``): replacing it by a fresh instance cannot help
    structural: bool = False
    tight_sets: list[frozenset] = field(default_factory=list)
    loose_sets: list[frozenset] = field(default_factory=list)
    #: the loose sets whose bracket found the cost gap open at the current U (module docstring)
    gap_open_sets: list[frozenset] = field(default_factory=list)
    last: SolveResult | None = None
    tight_result: SolveResult | None = None  # the last tight solve, with its pairs in order
    tight_pairs: list[Pair] = field(default_factory=list)
    _norms: dict[int, tuple[Constraint, float]] = field(default_factory=dict, repr=False)  # ``_norm``'s cache

    def known(self, chosen: frozenset, exact: bool = False) -> bool | None:
        """Tightness with ``chosen`` if a known result decides it (monotonicity), else None.

        exact: a loose result decides only for exactly this set (a tight one still for any superset, an open
        cost gap for any subset: module docstring)."""
        if any(t <= chosen for t in self.tight_sets):
            return True
        if any(chosen <= s for s in self.gap_open_sets):
            return False
        if any((chosen == s) if exact else (chosen <= s) for s in self.loose_sets):
            return False
        return None

    def violations(self, X: np.ndarray | sp.csr_array, pairs: Sequence[Pair]) -> dict[Pair, float]:
        """Per pair, max over its constraints on this instance of |⟨A,X⟩ − b| / (‖A‖_F ‖X‖_F); X dense, or sparse
        holding at least the constraints' entries.  X's entries are gathered once for every pair (a sparse X's
        indexing costs far more than the products); each ⟨A,X⟩ is the dot product of ``Constraint.value``."""
        if not pairs:
            return {}
        nx = frobenius(X)
        cons = [c for p in pairs for c in self.pairs[p]]
        rows = np.concatenate([c.A.row for c in cons])
        cols = np.concatenate([c.A.col for c in cons])
        vals = np.asarray(X[rows, cols]).ravel() if sp.issparse(X) else np.asarray(X)[rows, cols]
        out: dict[Pair, float] = {}
        at = 0
        for p in pairs:
            worst = []
            for c in self.pairs[p]:
                got = float(np.dot(c.A.data, vals[at:at + c.A.nnz]) - c.b)
                at += c.A.nnz
                worst.append(abs(got) / (self._norm(c) * nx))
            out[p] = max(worst)
        return out

    def _norm(self, c: Constraint) -> float:
        """‖A‖_F of a constraint, computed once (the cache holds the constraint: its id is not reused)."""
        hit = self._norms.get(id(c))
        if hit is None or hit[0] is not c:
            hit = self._norms[id(c)] = (c, float(np.sqrt((c.A.multiply(c.A)).sum())))
        return hit[1]

    def importance(self) -> dict[Pair, float]:
        """Σ|yᵢ|‖Aᵢ‖_F per pair of the last tight solve, normalised to sum 1 over its pairs."""
        out = {p: 0.0 for p in self.tight_pairs}
        res = self.tight_result.sdp if self.tight_result is not None else None
        if res is None or res.y is None:
            return out
        k = len(self.model.primary())
        for p in self.tight_pairs:
            for c in self.pairs[p]:
                out[p] += abs(float(res.y[k])) * self._norm(c)
                k += 1
        total = sum(out.values())
        return {p: v / total for p, v in out.items()} if total > 0 else out


class Solves:
    """The training solves of one discovery: counts per stage, a log, the per-instance cache."""

    def __init__(self, problem: Problem, config: Any, criteria: Criteria):
        self.problem, self.config, self.criteria = problem, config, criteria
        self.n_solves = 0
        self.by_stage: dict[str, int] = {}
        self.sdp_s = 0.0
        self.log: list[dict[str, Any]] = []

    def count(self, stage: str, n: int) -> None:
        self.n_solves += n
        self.by_stage[stage] = self.by_stage.get(stage, 0) + n

    def solve(self, tr: Trainer, chosen: Sequence[Pair], stage: str, with_ray: bool = True) -> bool:
        """Solve ``tr`` with the primary constraints and ``chosen`` (``solve_instance``); True when tight.
        An unbounded SDP is judged not tight here (its ray ranks the pairs that bound it; a caller
        that needs only the verdict, ``with_ray`` False, such as the reduction, gets no ray from the plain data)."""
        chosen = list(chosen)
        cons = [c for p in chosen for c in tr.pairs.get(p, [])]
        r = solve_instance(self.problem, tr.inst, cons, config=self.config, criteria=self.criteria,
                           model=tr.model, local=tr.local, raise_unbounded=False, retry_undecided=False)
        self.count(stage, max(1, len(r.attempts)))
        self.sdp_s += r.times.get("sdp_total_s", 0.0)
        if with_ray and not r.sdp.usable and any(a["status"] in UNBOUNDED_STATUSES for a in r.attempts):
            # the ray of the plain data ranks the pairs that bound it (``select``), also where the scaled solve
            # found one (that ray, in another frame, would rank them differently); the verdict stays not tight
            ray = sdp.solve_model(tr.model, tr.model.primary() + cons, self.config or SolverConfig(), None)
            self.count(stage, 1)
            if is_unbounded(ray):
                r = replace(r, sdp=ray)
        if r.refined is not None and r.refined.cost < tr.local.best.cost:  # a better feasible point: a lower U
            tr.local = LocalSearch(tr.local.from_truth, [*tr.local.from_random, r.refined])
            tr.gap_open_sets.clear()  # judged against the higher U
        tight = r.outcome == "tight"
        (tr.tight_sets if tight else tr.loose_sets).append(frozenset(chosen))
        if not tight and r.verdict.cost_outcome == "not tight":  # (accept="certified" can call it tight all the same)
            tr.gap_open_sets.append(frozenset(chosen))
        tr.last = r
        if tight:
            tr.tight_result, tr.tight_pairs = r, chosen
        self.log.append({"stage": stage, "point": tr.point, "seed": tr.seed, "n_pairs": len(chosen),
                         "outcome": r.outcome, "log_svr": r.log_svr, "status": r.sdp.status,
                         "unbounded": is_unbounded(r.sdp) or bool(unbounded_blocks(tr.model, r.sdp))})
        return tight

    def tight_on_all(self, trainers: list[Trainer], chosen: Sequence[Pair], stage: str,
                     exact: bool = False) -> tuple[bool, Trainer | None]:
        """Tight on every trainer (cached results first; the first one to break is returned).  The verdicts only:
        no ray of an unbounded solve (``solve``'s ``with_ray``)."""
        key = frozenset(chosen)
        for tr in trainers:
            known = tr.known(key, exact)
            if known is None:
                known = self.solve(tr, chosen, stage, with_ray=False)
            if not known:
                return False, tr
        return True, None


def candidates(trainers: list[Trainer], carried: bool) -> list[Pair]:
    """Pairs known on every training instance, in the first one's order.  carried (training at other sizes than
    learning): only pairs learned on every factor of their type (else their name is factor-specific)."""
    everywhere = set.intersection(*(set(tr.pairs) for tr in trainers))
    if carried:
        everywhere = {p for p in everywhere if all(on_every_factor(tr.model, p, tr.pairs[p]) for tr in trainers)}
    return [p for p in trainers[0].pairs if p in everywhere]


def on_every_factor(model: Model, pair: Pair, constraints: Sequence[Constraint]) -> bool:
    """Whether every factor of the pair's type has it (a pair found on some factors only does not carry)."""
    return len({c.factor for c in constraints}) == len(model.factor_types().get(pair[0], ()))


def make_trainer(prob: Problem, params: dict[str, Any], point: int, seed: int, groups: Any, opts: LearnOptions,
                 n_random: int, source: DiscoveredSet | None = None, origin: str = "training",
                 given: DiscoveredSet | None = None) -> Trainer:
    """The instance (params, seed) with its candidate pairs: learned on it, or (``source``) every pair of a set
    learned elsewhere, its templates evaluated on this instance.  ``given``: the set a held-out check failed on
    this instance; its pairs get the constraints that check solved (``DiscoveredSet.apply`` with the instance's
    constraint generator, as ``evaluate`` instantiates it), so the trainer starts from the verdict that failed,
    not from a re-learned copy whose numerics can judge the same set differently (where no exact template
    carries the pair, a re-learned relation differs in its last digits, and a borderline verdict with it)."""
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    loc = local_search(prob, inst, seeds(seed).local(), n_random)
    cat = None
    if source is None:
        cat = learn(prob, inst, model, seeds(seed).constraints(), groups, opts)
        pairs = cat.by_pair()
    else:
        pairs = by_pair(source.apply(prob, inst, model, seeds(seed).constraints(), skip_invalid=True))
    if given is not None:
        try:
            pairs.update(by_pair(given.apply(prob, inst, model, seeds(seed).constraints())))
        except AutotightError:  # check could not instantiate it either: the learned candidates stand
            pass
    pairs = valid_pairs(pairs, feasible_points(prob, inst, loc, seeds(seed).validity()))
    return Trainer(point, seed, inst, model, loc, pairs, cat, origin)


def valid_pairs(pairs: dict[Pair, list[Constraint]], points: dict[str, np.ndarray]) -> dict[Pair, list[Constraint]]:
    """The pairs whose every constraint holds at every point (``validity.relative_violations`` ≤
    ``validity.VALID_RTOL``): the feasible points ``solve_instance`` checks a set on before its verdict (the
    truth, fresh samples, the local solutions), so that no candidate of the instance makes its solves fail that
    check (a template carried to a size where its fit is off at some local solution, say).  A pair is a type-level
    relation: one factor's constraint off is the pair off."""
    cons = [c for cs in pairs.values() for c in cs]
    if not cons:
        return pairs
    ok = np.all(relative_violations(cons, list(points.values())) <= VALID_RTOL, axis=0)
    out, k = {}, 0
    for p, cs in pairs.items():
        if ok[k:k + len(cs)].all():
            out[p] = cs
        k += len(cs)
    return out


def learned_source(prob: Problem, params: dict[str, Any], seed: int, groups: Any, opts: LearnOptions,
                   over: dict[str, list] | None, say: Callable[[str, str], None]) -> DiscoveredSet:
    """Every pair learned on every factor of one instance at ``params`` (seed ``training_seed(seed, 0, 0)``),
    with its templates fitted at ``params`` over ``over``: what carries candidates to other sizes."""
    s = training_seed(seed, 0, 0)
    inst = prob.generate(params, s)
    model = prob.build(inst)
    cat = learn(prob, inst, model, seeds(s).constraints(), groups, opts)
    pairs = [p for p, cs in cat.by_pair().items() if on_every_factor(model, p, cs)]
    say("learn", f"{len(pairs)} pairs at {params}; templates")
    src = DiscoveredSet(prob.name, dict(params), int(seed), pairs, asdict(opts), {"range": {"over": over or {}}},
                        groups if isinstance(groups, str) else [list(g) for g in groups])
    src.template_set(prob)
    return src
