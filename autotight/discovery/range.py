"""Discovery over a range of parameters: one set, tight at every point, irreducible over the range.

``discover_range(problem, params, over)`` (also ``autotight.discover(..., over=…)`` and
``autotight discover PROBLEM --sigmas …``/``--range NAME=…``):

1. **Points** are the product of ``over`` on top of ``params`` (``autotight.check.points_of``).
   Each point has ``n_train`` training instances at the point's parameters, overridden by
   ``train_params`` (e.g. ``{"K": 5}``: learn and tighten on short trajectories; the pairs carry
   over to any K).  Training instance t at point i has the seed SeedSequence((seed, i, t, 1)), so
   it is never one of the held-out instances (SeedSequence((seed, i, t)), those of ``check``).
2. **Learn** every group of every training instance once.  A candidate is a (factor type,
   identity) pair learned on every training instance; its constraints differ per instance (they
   hold that instance's measurements), so a pair is instantiated on each training instance.  With
   ``train_params`` (training at another size), a pair must also be learned on every factor of its
   type: an identity found on some factors only is named after them and would not carry over.
3. **Tighten.**  Solve each training instance with the primary constraints.  In round r, every
   remaining pair is scored by its largest relative violation |⟨A,X⟩|/(‖A‖_F‖X‖_F) over the SDP
   solutions of the training instances that are not yet tight; the 2^r best pairs are added and
   only the instances not yet tight are solved again (adding valid constraints keeps a tight
   relaxation tight).  A training instance that is not tight while no remaining pair cuts its
   solution cannot be made tight by the candidates: it is "not reached" and left out of the
   rest.  A solve that returns no usable X (NumericalError at σ = 0.1 and 0.316 on discrete K = 20
   with one pair) ranks nothing: the instances with a usable X rank the round, and the blind one is
   solved again with the larger set.  Only when every loose instance is blind is every remaining
   pair added at once (the reduction removes those not needed).  A point none of whose training
   instances is reached is reported as such.
4. **Reduce** over the reached training instances: pairs ordered by their largest normalised
   dual importance Σ|yᵢ|‖Aᵢ‖_F on any instance (least important first) are removed in blocks that
   double after a success and halve after a failure, as in ``reduce.reduce_pairs``.  A block
   removal is tried on the *probe* instances only, at first the hardest one (the largest set known
   not to be tight on it).  The result is then solved on the other instances; the first where it is
   not tight joins the probe, gets back the fewest removed pairs that make it tight (ranked by their
   violation of its solution, as in step 3), and the removal runs again on the probe.  So a
   removal costs one solve per probe instance, not one per instance.  Tightness is monotone in the
   set, so every result is cached per instance: a set containing a known tight set is tight, a set
   inside a known loose one is loose, and only sets that no known result decides are solved, the
   instance that broke the last trial first.
5. **Irreducible**: removing any remaining pair breaks tightness on at least one reached training
   instance, checked by a solve on exactly that set (a pair whose removal turns out not to break
   it is dropped, and the check repeats).
6. **Validate** (optional, ``n_validate``): more training instances per point, tightened from the
   set and reduced again where the set is not tight on one of them (at most ``max_rounds`` rounds).
7. **Held out**: ``n_heldout`` instances per point at the point's own parameters, solved with the
   range set and with the paper's families (``autotight.check.solve_points``).

Every SDP solve goes through ``autotight.pipeline.solve_instance``; an "undecided" verdict counts
as not tight while learning (it never lets a pair go) and separately in the held-out counts.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..check import PointResult, parse_over, points_of, solve_points
from ..constraint_set import ConstraintSet
from ..errors import ParameterError
from ..io import jsonable
from ..model import Constraint, Model, frobenius
from ..pipeline import LocalSearch, SolveResult, local_search, seeds, solve_instance
from ..problem import Instance, Problem, load, parse_assignments
from ..sdp.config import SolverConfig
from ..threads import single_blas_thread
from ..tightness import Criteria
from ..unbounded import rank_out_of_reach
from .carry import CarryPlan
from .catalog import Pair, learn
from .discovered import DiscoveredSet
from .learn import LearnOptions
from .pipeline import default_groups


def training_seed(seed: int, point: int, trial: int) -> int:
    """Seed of training instance ``trial`` at point ``point``: SeedSequence((seed, point, trial, 1))."""
    return int(np.random.SeedSequence([seed, point, trial, 1]).generate_state(1, np.uint32)[0])


@dataclass
class Trainer:
    """One training instance: its learned pairs and every tightness result known for it."""

    point: int
    seed: int
    inst: Instance
    model: Model
    local: LocalSearch
    pairs: dict[Pair, list[Constraint]]
    reached: bool = True
    message: str = ""
    tight_sets: list[frozenset] = field(default_factory=list)
    loose_sets: list[frozenset] = field(default_factory=list)
    last: SolveResult | None = None
    tight_result: SolveResult | None = None  # the last tight solve, with its pairs in order
    tight_pairs: list[Pair] = field(default_factory=list)

    def known(self, chosen: frozenset, exact: bool = False) -> bool | None:
        """Tightness with ``chosen`` if a known result decides it (monotonicity), else None.

        exact: a loose result decides only for exactly this set (a tight one still for any subset)."""
        if any(t <= chosen for t in self.tight_sets):
            return True
        if any((chosen == s) if exact else (chosen <= s) for s in self.loose_sets):
            return False
        return None

    def violation(self, X: np.ndarray, pair: Pair) -> float:
        """max over the pair's constraints on this instance of |⟨A,X⟩| / (‖A‖_F ‖X‖_F)."""
        nx = frobenius(X)
        return max(abs(c.value(X)) / (np.sqrt((c.A.multiply(c.A)).sum()) * nx) for c in self.pairs[pair])

    def importance(self) -> dict[Pair, float]:
        """Σ|yᵢ|‖Aᵢ‖_F per pair of the last (tight) solve, normalised to sum 1 over its pairs."""
        out = {p: 0.0 for p in self.tight_pairs}
        res = self.tight_result.sdp if self.tight_result is not None else None
        if res is None or res.y is None:
            return out
        k = len(self.model.primary())
        for p in self.tight_pairs:
            for c in self.pairs[p]:
                out[p] += abs(float(res.y[k])) * float(np.sqrt((c.A.multiply(c.A)).sum()))
                k += 1
        total = sum(out.values())
        return {p: v / total for p, v in out.items()} if total > 0 else out


@dataclass
class RangePoint:
    """One point: its parameters, its training instances (reached or not) and the held-out results."""

    index: int
    varied: dict[str, Any]
    params: dict[str, Any]
    train_seeds: list[int]
    reached: list[bool]
    messages: list[str]
    heldout: PointResult | None = None
    paper: PointResult | None = None
    n_learned: int | None = None  # learned constraints of the range set instantiated at this point
    n_paper: int | None = None  # the paper's redundant constraints at this point

    def record(self) -> dict[str, Any]:
        h, p = self.heldout, self.paper
        return {"varied": self.varied, "params": self.params, "train_seeds": self.train_seeds,
                "reached": self.reached, "messages": self.messages,
                "heldout_fraction": None if h is None else h.fraction,
                "heldout": None if h is None else h.record(),
                "paper_fraction": None if p is None else p.fraction,
                "paper": None if p is None else p.record(), "n_learned": self.n_learned, "n_paper": self.n_paper}


@dataclass
class RangeDiscoveryResult:
    """What ``discover_range`` found; ``constraint_set`` is what ``solve``/``check`` take."""

    problem: str
    params: dict[str, Any]
    over: dict[str, list[Any]]
    train_params: dict[str, Any]
    n_train: int
    seed: int
    points: list[RangePoint]
    candidates: list[Pair]
    not_everywhere: list[Pair]
    greedy: list[Pair]
    pairs: list[Pair]
    irreducible: bool
    dropped_in_verification: list[Pair]
    discovered: DiscoveredSet
    n_solves: int
    solves_by_stage: dict[str, int]
    times: dict[str, float]
    log: list[dict[str, Any]]
    example: tuple[Model, list[Constraint]] | None = None
    validation: list[dict[str, int]] = field(default_factory=list)
    learn_params: dict[str, Any] = field(default_factory=dict)
    validate_params: dict[str, Any] = field(default_factory=dict)

    @property
    def tight(self) -> bool:
        """Tight on every reached training instance (and some instance was reached)."""
        return any(any(p.reached) for p in self.points)

    @property
    def constraint_set(self) -> ConstraintSet:
        return ConstraintSet(self.discovered)

    def save(self, path: str) -> None:
        """The set as JSON (``ConstraintSet.load`` reads it); the range is in ``info["range"]``."""
        model, cons = self.example if self.example is not None else (None, None)
        self.discovered.save(path, model, cons, {"summary": self.summary()})

    def summary(self) -> dict[str, Any]:
        return {"problem": self.problem, "params": self.params, "over": self.over, "train_params": self.train_params,
                "learn_params": self.learn_params, "validate_params": self.validate_params,
                "carry": self.discovered.info.get("carry"),
                "n_train": self.n_train,
                "seed": self.seed, "tight": self.tight,
                "n_candidate_pairs": len(self.candidates),
                "not_learned_everywhere": [f"{t}:{i}" for t, i in self.not_everywhere],
                "n_greedy_pairs": len(self.greedy), "validation_rounds": self.validation, "n_pairs": len(self.pairs),
                "pairs": [f"{t}:{i}" for t, i in self.pairs], "irreducible": self.irreducible,
                "dropped_in_verification": [f"{t}:{i}" for t, i in self.dropped_in_verification],
                "n_solves": self.n_solves, "solves_by_stage": self.solves_by_stage, "times": self.times,
                "points": [p.record() for p in self.points]}

    def table(self) -> str:
        s = self.summary()
        at = f" at {self.validate_params}" if self.validate_params else ""
        lines = [f"problem {self.problem}  params {self.params}  over {self.over}"
                 + (f"  (training at {self.train_params})" if self.train_params else "") + f"  seed {self.seed}",
                 (f"{len(self.candidates)} candidate pairs learned once at {self.learn_params} and carried by their "
                  f"templates to {sum(len(p.reached) for p in self.points)} training instances"
                  if self.learn_params else
                  f"{len(self.candidates)} candidate pairs learned on all {sum(len(p.reached) for p in self.points)} "
                  "training instances") + f"; greedy {len(self.greedy)} pairs"
                 + "".join(f", +{r['new_instances']} instances{at} ({r['not_tight']} not tight, "
                           f"+{r['pairs_added']} pairs)" for r in self.validation)
                 + f" → {len(self.pairs)} pairs "
                 f"({'irreducible over the range' if self.irreducible else 'not verified irreducible'}); "
                 f"{self.n_solves} SDP solves ({', '.join(f'{k} {v}' for k, v in s['solves_by_stage'].items())}); "
                 f"{self.times.get('total_s', float('nan')):.1f} s", "",
                 f"{'point':<18}{'trained':>9}{'range set':>11}{'tight (held-out)':>22}{'paper':>7}"
                 f"{'tight (held-out)':>22}"]
        for p in self.points:
            label = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.varied.items()) \
                or "params"
            tr = f"{sum(p.reached)}/{len(p.reached)}"
            hf = _frac(p.heldout)
            pf = _frac(p.paper)
            lines.append(f"{label:<18}{tr:>9}{_n(p.n_learned):>11}{hf:>22}{_n(p.n_paper):>7}{pf:>22}")
        lines.append("")
        for p in self.points:
            for seed, ok, msg in zip(p.train_seeds, p.reached, p.messages):
                if not ok:
                    lines.append(f"not reached at {p.varied} (training seed {seed}): {msg}")
        none = "none (the primary constraints suffice)" if self.tight else "none (no training instance was reached)"
        lines.append("pairs: " + (", ".join(s["pairs"]) or none))
        return "\n".join(lines)


def _n_added(res: PointResult, n_primary: int) -> int | None:
    """Constraints beyond the primary ones on the point's held-out instances where the set was instantiated
    (None when it was on none: "—" in the table, not a negative count)."""
    made = [n for n, st in zip(res.n_constraints, res.statuses) if st != "not instantiated"]
    return max(made) - n_primary if made else None


def _n(v: int | None) -> str:
    return "—" if v is None else str(v)


def _frac(h: PointResult | None) -> str:
    if h is None or not h.seeds:
        return "—"
    und = h.count("undecided")
    return f"{h.fraction:.0%} of {h.n_decided}" + (f" (+{und} und.)" if und else "")


class _Run:
    """The solves of one range discovery: counts, log, cache updates."""

    def __init__(self, problem: Problem, config: Any, criteria: Criteria):
        self.problem, self.config, self.criteria = problem, config, criteria
        self.n_solves = 0
        self.by_stage: dict[str, int] = {}
        self.sdp_s = 0.0
        self.log: list[dict[str, Any]] = []

    def solve(self, tr: Trainer, chosen: Sequence[Pair], stage: str) -> bool:
        chosen = list(chosen)
        cons = [c for p in chosen for c in tr.pairs.get(p, [])]
        r = solve_instance(self.problem, tr.inst, cons, config=self.config, criteria=self.criteria,
                           model=tr.model, local=tr.local)
        n = max(1, len(r.attempts))
        self.n_solves += n
        self.by_stage[stage] = self.by_stage.get(stage, 0) + n
        self.sdp_s += r.times.get("sdp_total_s", 0.0)
        if r.refined is not None and r.refined.cost < tr.local.best.cost:  # a better feasible point: a lower U
            tr.local = LocalSearch(tr.local.from_truth, [*tr.local.from_random, r.refined])
        tight = r.outcome == "tight"
        key = frozenset(chosen)
        (tr.tight_sets if tight else tr.loose_sets).append(key)
        tr.last = r
        if tight:
            tr.tight_result, tr.tight_pairs = r, chosen
        self.log.append({"stage": stage, "point": tr.point, "seed": tr.seed, "n_pairs": len(chosen),
                         "outcome": r.outcome, "log_svr": r.log_svr, "status": r.sdp.status})
        return tight

    def tight_on_all(self, trainers: list[Trainer], chosen: Sequence[Pair], stage: str,
                     exact: bool = False) -> tuple[bool, Trainer | None]:
        """Tight on every trainer (cached results first; the first one to break is returned)."""
        key = frozenset(chosen)
        for tr in trainers:
            known = tr.known(key, exact)
            if known is None:
                known = self.solve(tr, chosen, stage)
            if not known:
                return False, tr
        return True, None


def _candidates(trainers: list[Trainer], tparams: dict[str, Any]) -> tuple[list[Pair], list[Pair]]:
    """Pairs learned on every training instance (in the first one's order), and the others."""
    everywhere = set.intersection(*(set(tr.pairs) for tr in trainers))
    if tparams:  # carried to other sizes: only pairs learned on every factor of their type
        everywhere = {p for p in everywhere if all(_on_every_factor(tr, p) for tr in trainers)}
    others = sorted(set().union(*(set(tr.pairs) for tr in trainers)) - everywhere)
    return [p for p in trainers[0].pairs if p in everywhere], others


def _on_every_factor(tr: Trainer, pair: Pair) -> bool:
    """Whether every factor of the pair's type learned it (else its name is factor-specific and won't carry over)."""
    return _everywhere(tr.model, pair, tr.pairs[pair])


def _everywhere(model: Model, pair: Pair, constraints: Sequence[Constraint]) -> bool:
    return len({c.factor for c in constraints}) == len(model.factor_types().get(pair[0], ()))


def _learn_trainers(prob: Problem, points: list[tuple[dict, dict]], which: Sequence[int], train_params: dict[str, Any],
                    trials: range, seed: int, groups: Any, opts: LearnOptions, n_random: int,
                    say: Callable, source: DiscoveredSet | None = None) -> list[Trainer]:
    """Training instances with their candidate pairs: learned on each, or (``source``) every pair of a set
    learned elsewhere, applied (its templates evaluated; ``learn_params``)."""
    out = []
    for i in which:
        full, varied = points[i]
        for t in trials:
            s = training_seed(seed, i, t)
            inst = prob.generate(full | train_params, s)
            model = prob.build(inst)
            loc = local_search(prob, inst, seeds(s).local(), n_random)
            if source is None:
                pairs = learn(prob, inst, model, seeds(s).constraints(), groups, opts).by_pair()
            else:
                pairs = {}
                for c in source.apply(prob, inst, model, seeds(s).constraints(), skip_invalid=True):
                    pairs.setdefault(tuple(c.identity.split(":", 1)), []).append(c)
            out.append(Trainer(i, s, inst, model, loc, pairs))
            say("learn", f"{varied} #{t}")
    return out


def _parsed(prob: Problem, values: dict[str, Any]) -> dict[str, Any]:
    """Only the given parameters, each validated and parsed (``Problem.parse_params`` checks the names)."""
    prob.parse_params(values)
    return {k: prob.params[k].parse(k, v) for k, v in values.items()}


def _learned_source(prob: Problem, params: dict[str, Any], seed: int, groups: Any, opts: LearnOptions,
                    say: Callable, over: dict[str, list] | None = None) -> DiscoveredSet:
    """Every pair learned on every factor of one instance at ``params`` (seed: ``training_seed(seed, 0, 0)``),
    with its templates (fitted at ``params`` over the range ``over``, ``DiscoveredSet.template_points``):
    the candidates that ``learn_params`` carries to the training instances."""
    s = training_seed(seed, 0, 0)
    inst = prob.generate(params, s)
    model = prob.build(inst)
    cat = learn(prob, inst, model, seeds(s).constraints(), groups, opts)
    pairs = [p for p, cs in cat.by_pair().items() if _everywhere(model, p, cs)]
    say("learn", f"{len(pairs)} pairs at {params}; templates")
    src = DiscoveredSet(prob.name, dict(params), int(seed), pairs, asdict(opts), {"range": {"over": over or {}}},
                        groups if isinstance(groups, str) else [list(g) for g in groups])
    src.template_set(prob)
    return src


def _tighten(run: _Run, trainers: list[Trainer], candidates: list[Pair], min_violation: float,
             say: Callable, start: Sequence[Pair] = (), stage: str = "primary") -> list[Pair]:
    """Greedy over all training instances from the set ``start`` (module docstring, step 3); marks the
    ones not reached."""
    loose = [tr for tr in trainers if not run.solve(tr, start, stage)]
    chosen: list[Pair] = list(start)
    r = 0
    while loose:
        remaining = [p for p in candidates if p not in set(chosen)]
        score: dict[Pair, float] = {}
        blind = False  # a loose trainer whose solve returned no usable X: nothing ranks the candidates
        for tr in loose:
            X = tr.last.sdp.X if tr.last is not None else None
            if X is None or not tr.last.sdp.usable:
                status = tr.last.sdp.status if tr.last else "?"
                if remaining:
                    blind = True
                else:
                    tr.reached, tr.message = False, f"solver status {status} with every candidate added"
                continue
            v = {p: tr.violation(X, p) for p in remaining}
            if not v or max(v.values()) <= min_violation:
                vd = tr.last.verdict
                why = ("its SDP solution is rank 1 but the cost gap is not closed (solver accuracy?)" if vd.rank_tight
                       else "no remaining candidate cuts its SDP solution")
                if not vd.rank_tight:
                    cons = tr.model.all_constraints() + [c for p in chosen for c in tr.pairs[p]]
                    why = "; ".join(w for w in (why, rank_out_of_reach(tr.model, cons)) if w)
                if vd.cost_tight and run.criteria.accept == "rank":
                    why += f"; the relaxation is cost-tight (relative gap {vd.rel_gap:.1e}): use --accept cost"
                tr.reached, tr.message = False, f"not tight with {len(chosen)} pairs, log SVR {vd.log_svr:.2f}: {why}"
                continue
            for p, x in v.items():
                score[p] = max(score.get(p, 0.0), x)
        loose = [tr for tr in loose if tr.reached]
        ranked = sorted((p for p in score if score[p] > min_violation), key=lambda p: -score[p])
        if not loose or not (ranked or blind):
            break
        if ranked:  # the instances with a usable X rank; a blind one is solved again with the larger set
            chosen += ranked[: 2 ** r]
            r += 1
        else:  # only blind instances left: add every remaining candidate; the reduction removes those not needed
            chosen += remaining
        loose = [tr for tr in loose if not run.solve(tr, chosen, "tighten")]
        say("tighten", f"{len(chosen)} pairs, {len(loose)} not tight")
    return chosen


def _reduce(run: _Run, trainers: list[Trainer], chosen: list[Pair], say: Callable) -> tuple[list[Pair], list[Pair]]:
    """Block removal on the probe instances, widened where the result breaks, then the irreducibility check
    over every reached trainer (module docstring, 4–5)."""
    imp: dict[Pair, float] = {p: 0.0 for p in chosen}
    for tr in trainers:
        for p, v in tr.importance().items():
            imp[p] = max(imp.get(p, 0.0), v)
    probe = [_hardest(trainers)]
    current = list(chosen)
    pending = sorted(chosen, key=lambda p: imp[p])
    breaker: dict[Pair, Trainer] = {}
    while True:
        current = _remove_blocks(run, probe, current, pending, breaker, say)
        ok, bad = run.tight_on_all([tr for tr in trainers if tr not in probe], current, "reduce")
        if ok:
            break
        probe.append(bad)  # type: ignore[arg-type]
        current = _restore(run, bad, current, [p for p in chosen if p not in current])  # type: ignore[arg-type]
        pending = sorted(current, key=lambda p: imp[p])
    order = probe + [tr for tr in trainers if tr not in probe]
    dropped: list[Pair] = []
    changed = True
    while changed:
        changed = False
        for p in list(current):
            rest = [q for q in current if q != p]
            _to_front(order, breaker.get(p))
            ok, bad = run.tight_on_all(order, rest, "verify", exact=True)
            _to_front(order, bad)
            if ok:  # numerically non-monotone: p is not needed after all
                current.remove(p)
                dropped.append(p)
                changed = True
                break
            breaker[p] = bad  # type: ignore[assignment]
    return current, dropped


def _to_front(order: list[Trainer], tr: Trainer | None) -> None:
    """Move ``tr`` (if any) to the front of ``order``: the instance that broke the last trial is solved first."""
    if tr is not None:
        order.remove(tr)
        order.insert(0, tr)


def _hardest(trainers: list[Trainer]) -> Trainer:
    """The trainer with the largest set known not to be tight on it (the first one when none is known)."""
    return max(trainers, key=lambda tr: max((len(s) for s in tr.loose_sets), default=-1))


def _remove_blocks(run: _Run, probe: list[Trainer], current: list[Pair], pending: list[Pair],
                   breaker: dict[Pair, Trainer], say: Callable) -> list[Pair]:
    """``current`` without the ``pending`` pairs (least important first) whose removal keeps it tight on every
    ``probe`` trainer: blocks that double after a success and halve after a failure.  ``breaker`` gets, for each
    pair found necessary, the trainer where removing it broke tightness."""
    order = list(probe)
    chunk = max(1, len(pending) // 2)
    while pending:
        c = min(chunk, len(pending))
        block = set(pending[:c])
        trial = [p for p in current if p not in block]
        ok, bad = run.tight_on_all(order, trial, "reduce")
        _to_front(order, bad)
        say("reduce", f"{len(current)} pairs")
        if ok:
            current, pending, chunk = trial, pending[c:], 2 * c
        elif c == 1:
            breaker[pending[0]] = bad  # type: ignore[assignment]
            pending = pending[1:]
        else:
            chunk = c // 2
    return current


def _restore(run: _Run, tr: Trainer, current: list[Pair], removed: list[Pair]) -> list[Pair]:
    """``current`` plus the fewest ``removed`` pairs that the greedy needs to make ``tr`` tight again: ranked by
    their violation of tr's last solution, 1, 2, 4, … at a time (all of them: the tightened set, tight on tr)."""
    chosen, remaining, r = list(current), list(removed), 0
    while remaining:
        last = tr.last.sdp if tr.last is not None else None
        if last is not None and last.X is not None and last.usable:
            remaining.sort(key=lambda p: -tr.violation(last.X, p))
            add, remaining = remaining[: 2 ** r], remaining[2 ** r:]
            r += 1
        else:
            add, remaining = remaining, []
        chosen += add
        known = tr.known(frozenset(chosen))
        if known or (known is None and run.solve(tr, chosen, "reduce")):
            break
    return chosen


@single_blas_thread
def discover_range(problem: Problem | str, params: Mapping[str, Any] | None, over: Mapping[str, Sequence[Any]],
                   seed: int = 0, *, n_train: int = 2, train_params: Mapping[str, Any] | None = None,
                   learn_params: Mapping[str, Any] | None = None,
                   n_heldout: int = 10, groups: Any = None, learn_options: LearnOptions = LearnOptions(),
                   criteria: Criteria = Criteria(), solver: Any = None, n_random: int = 2,
                   n_validate: int = 0, validate_params: Mapping[str, Any] | None = None, max_rounds: int = 3,
                   min_violation: float = 1e-7, compare: bool = True,
                   progress: Callable[[str, str], None] | None = None) -> RangeDiscoveryResult:
    """Learn, tighten and reduce one set over every point of ``over`` (see the module docstring).

    An empty ``over`` is the single point ``params``: the set is then reduced over ``n_train``
    instances of it (what ``discover`` does for a problem whose ``DEFAULT_TRAIN`` exceeds 1).

    learn_params (e.g. ``{"K": 5}``): learn the candidates once, on one instance at the first point's
    parameters overridden by these, with their templates; the training instances (at the points'
    parameters, e.g. K = 1000) get every candidate by evaluating the templates instead of learning on
    each.  The set is then saved with templates learned at ``learn_params`` (``DiscoveredSet.params``);
    where it was selected is in ``info["range"]``.

    n_validate: after the reduction, up to ``max_rounds`` times, learn ``n_validate`` more training
    instances per point that has a reached one; when the set is not tight on one of them, tighten
    from the set on them and reduce again over all training instances (0: no such rounds).

    validate_params (e.g. ``{"K": 100}``, with n_validate ≥ 1): the validation instances take these
    parameters: a set selected on K = 20 instances is checked, and tightened where it breaks, on
    K = 100 ones before it is saved.  Validation instance t at point i has the training seed
    ``training_seed(seed, i, t)``, t counting on from n_train.
    """
    prob = load(problem) if isinstance(problem, str) else problem
    groups = default_groups(prob, groups)
    if isinstance(n_train, bool) or not isinstance(n_train, (int, np.integer)) or n_train < 1:
        raise ParameterError(f"n_train must be an int ≥ 1, got {n_train!r}")
    for name, v in (("n_heldout", n_heldout), ("n_validate", n_validate), ("max_rounds", max_rounds)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ParameterError(f"{name} must be an int ≥ 0, got {v!r}")
    config = SolverConfig() if solver is None else solver
    say = progress or (lambda stage, text: None)
    over_ = parse_over(prob, over)
    tparams = dict(train_params or {})
    clash = [k for k in tparams if k in over_]
    if clash:
        raise ParameterError(f"parameter {clash[0]} is both varied and fixed for training")
    tparams, lparams = _parsed(prob, tparams), _parsed(prob, dict(learn_params or {}))
    vparams = _parsed(prob, dict(validate_params or {}))
    clash = [k for k in vparams if k in over_]
    if clash:
        raise ParameterError(f"parameter {clash[0]} is both varied and fixed for validation")
    if vparams and not n_validate:
        raise ParameterError("validate_params needs n_validate ≥ 1 (--validate N)")
    points = points_of(prob, params, over_)
    fixed = {k: v for k, v in points[0][0].items() if k not in over_}
    t0 = time.perf_counter()
    tm = {"learn_s": 0.0, "tighten_s": 0.0, "reduce_s": 0.0}

    def timed(key: str, f: Callable, *a: Any, **k: Any) -> Any:
        t = time.perf_counter()
        out = f(*a, **k)
        tm[key] += time.perf_counter() - t
        return out

    source = None
    if lparams:
        source = timed("learn_s", _learned_source, prob, points[0][0] | tparams | lparams, int(seed), groups,
                       learn_options, say, {k: v for k, v in over_.items() if k not in lparams})
    common = (int(seed), groups, learn_options, n_random, say, source)
    trainers = timed("learn_s", _learn_trainers, prob, points, range(len(points)), tparams, range(int(n_train)),
                     *common)
    candidates, not_everywhere = _candidates(trainers, tparams)
    run = _Run(prob, config, criteria)
    greedy = timed("tighten_s", _tighten, run, trainers, candidates, min_violation, say)
    reached = [tr for tr in trainers if tr.reached]
    pairs, dropped = timed("reduce_s", _reduce, run, reached, greedy, say) if reached and greedy else ([], [])
    rounds: list[dict[str, int]] = []
    next_t = int(n_train)
    while n_validate and reached and len(rounds) < max_rounds:
        which = sorted({tr.point for tr in reached})
        new = timed("learn_s", _learn_trainers, prob, points, which, tparams | vparams,
                    range(next_t, next_t + n_validate), *common)
        next_t += n_validate
        trainers += new
        candidates, not_everywhere = _candidates(trainers, tparams | vparams)
        more = timed("tighten_s", _tighten, run, new, candidates, min_violation, say, pairs, "validate")
        loose = sum(frozenset(pairs) in tr.loose_sets for tr in new)
        rounds.append({"new_instances": len(new), "not_tight": loose, "pairs_added": len(more) - len(pairs)})
        if len(more) == len(pairs):
            break  # tight on every new instance (or none of the loose ones could be reached)
        reached = [tr for tr in trainers if tr.reached]
        pairs, d2 = timed("reduce_s", _reduce, run, reached, more, say)
        dropped += d2
    rpoints = [RangePoint(i, varied, full, [tr.seed for tr in trainers if tr.point == i],
                          [tr.reached for tr in trainers if tr.point == i],
                          [tr.message for tr in trainers if tr.point == i]) for i, (full, varied) in enumerate(points)]
    info = {"range": {"over": over_, "train_params": tparams, "learn_params": lparams,
                      "selected_at": dict(points[0][0]) if source is not None else None,
                      "n_train": int(n_train), "validation": rounds, "validate_params": vparams,
                      "training_seeds": "SeedSequence((seed, point, t, 1))",
                      "reached": {str(p.varied): p.reached for p in rpoints}},
            "criteria": asdict(criteria), "tight": bool(reached), "message": "discovered over a range"}
    ds = DiscoveredSet(prob.name, dict(points[0][0]), int(seed), list(pairs), asdict(learn_options), info,
                       groups if isinstance(groups, str) else [list(g) for g in groups])
    if source is not None:  # the identities were learned at learn_params: so are the saved templates
        ds.params = dict(source.params)
        ds.templates = source.template_set(prob).restricted(pairs)
    t = time.perf_counter()
    if n_heldout:
        sets: dict[str, Any] = {"range": ConstraintSet(ds)}
        model0 = prob.build(prob.generate(points[0][0], 0))
        if compare and model0.paper:
            sets["paper"] = "paper"
        held, n_held = solve_points(prob, sets, points, int(n_heldout), int(seed), criteria=criteria, solver=config)
        run.by_stage["heldout"] = n_held
        run.n_solves += n_held
        n_prim = {i: len(prob.build(prob.generate(full, 0)).primary()) for i, (full, _) in enumerate(points)}
        for i, rp in enumerate(rpoints):
            rp.heldout = held["range"][i]
            rp.n_learned = _n_added(rp.heldout, n_prim[i])
            if "paper" in held:
                rp.paper = held["paper"][i]
                rp.n_paper = _n_added(rp.paper, n_prim[i])
    t_held = time.perf_counter() - t
    ex = None
    if reached:
        tr = reached[0]
        ex = (tr.model, [c for p in pairs for c in tr.pairs[p]])
    times = tm | {"heldout_s": t_held, "sdp_training_s": run.sdp_s, "total_s": time.perf_counter() - t0}
    say("done", "")
    return RangeDiscoveryResult(prob.name, fixed, over_, tparams, int(n_train), int(seed), rpoints, candidates,
                                not_everywhere, greedy, list(pairs), bool(reached), dropped,
                                ds, run.n_solves, dict(run.by_stage), times, run.log, ex, rounds, lparams,
                                vparams)


def add_range_args(p: argparse.ArgumentParser) -> None:
    """``discover``'s range options: --sigmas, --range, --train, --train-param."""
    from ..check_cmd import add_range_args as points_args

    points_args(p)
    p.add_argument("--train", type=int, default=None,
                   help="training instances per point (default 2 with --sigmas/--range; without them the "
                        "problem's DEFAULT_TRAIN, else 1: more than 1 reduces the set over that many instances)")
    p.add_argument("--train-param", action="append", default=[], metavar="NAME=VALUE",
                   help="with --sigmas/--range: a parameter of the training instances only, e.g. K=5 (repeatable)")
    p.add_argument("--learn-param", action="append", default=[], metavar="NAME=VALUE",
                   help="learn the candidates once on an instance with this parameter (e.g. K=5, repeatable) and "
                        "carry them to the training instances by their templates: select at -p K=1000 what was "
                        "learned at K=5")
    p.add_argument("--validate-param", action="append", default=[], metavar="NAME=VALUE",
                   help="with --validate: a parameter of the validation instances only, e.g. K=100: check the set "
                        "on longer chains than it was selected on, and tighten it where it breaks (repeatable)")
    p.add_argument("--validate", type=int, default=0, metavar="N",
                   help="with --sigmas/--range: up to 3 rounds of N more training instances per point, tightening "
                        "again where the set is not tight on one (default 0)")


def cmd_discover_range(args: argparse.Namespace, groups: Any, n_train: int, config: SolverConfig,
                       plan: CarryPlan | None = None) -> int:
    """``autotight discover PROBLEM --sigmas …`` (or ``--range NAME=…``, or ``--train N`` > 1 at one point, or
    the problem module's carry-over ``plan``): the range table, JSON, --out."""
    from ..check_cmd import parse_range

    from .cli import progress_bar

    prob = load(args.problem)
    if plan is not None:
        params, over, options = plan.params, plan.over, plan.range_options()
        if not args.json:
            print(plan.describe(), flush=True)
    else:
        params, over = parse_assignments(args.param), parse_range(args.sigmas, args.range)
        options = {"learn_params": parse_assignments(args.learn_param), "n_validate": args.validate,
                   "validate_params": parse_assignments(args.validate_param)}
    with progress_bar(args) as progress:
        res = discover_range(prob, params, over, args.seed,
                             n_train=n_train, train_params=parse_assignments(args.train_param),
                             n_heldout=args.heldout, groups=groups,
                             learn_options=LearnOptions(min_gap_decades=args.min_gap),
                             criteria=Criteria(gap_tol=args.gap_tol, accept=args.accept), progress=progress,
                             solver=config, **options)
    if plan is not None:
        plan.mark(res)
    if args.out:
        res.save(args.out)
    if args.json:
        print(json.dumps(jsonable(res.summary()), ensure_ascii=False))
    else:
        print(res.table())
        if args.out:
            print(f"\nsaved to {args.out}")
    from ..closed_form.cli import closed_form_output

    closed_form_output(prob, res.discovered, args)
    return 0
