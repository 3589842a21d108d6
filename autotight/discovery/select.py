"""Select a set over training instances: tighten greedily, then reduce to an irreducible set.

**Tighten** (``tighten``).  Solve each training instance with the start set.  In round r, every
remaining pair is scored by its largest relative violation |⟨A,X⟩|/(‖A‖_F‖X‖_F) over the SDP
solutions of the training instances that are not yet tight; the 2^r best pairs are added and only the
instances not yet tight are solved again (adding valid constraints keeps a tight relaxation tight).
An unbounded SDP (its X is a ray, not a solution, or has blocks far beyond X_hh:
``unbounded.unbounded_blocks``) ranks only the pairs that can bound it: those with a constraint whose A has
diagonal entries on those blocks.  A training instance that is not tight
while no remaining pair cuts its solution cannot be made tight by the candidates: it is "not reached"
and left out of the rest.  A solve without a usable X ranks nothing (the best iterate of a solve whose
verdict was settled without finishing, ``SDPResult.settled``, counts as usable here): the instances with a usable X
rank the round, and the blind one is solved again with the larger set; only when every loose instance
is blind is every remaining pair added at once (the reduction removes those not needed).

``tighten_each`` runs it on one instance at a time (the held-out instances a set failed, taken in together).

**Reduce** (``reduce``).  Pairs ordered by their largest normalised dual importance Σ|yᵢ|‖Aᵢ‖_F on any
instance (least important first) are removed in blocks that double after a success and halve after a
failure.  A removal is tried on the *probe* instances only, at first the hardest one (the largest set
known not to be tight on it); the result is then solved on the others, and the first where it is not
tight joins the probe, gets back the fewest removed pairs that make it tight (ranked by their
violation of its solution), and the removal runs again.  Every result is cached per instance
(``trainers.Trainer.known``).  **Irreducible**: removing any remaining pair breaks tightness on at least
one training instance, checked by a solve on exactly that set, or proved by an open cost gap of a set that
contains it (``trainers`` module docstring); a pair whose removal turns out not to break it is dropped, the pass
goes on with the smaller set, and passes repeat until one drops nothing.

"Tight" is ``solve_instance``'s verdict under the discovery's ``Criteria`` (an "undecided" verdict
counts as not tight here: it never lets a pair go).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..unbounded import compress, is_unbounded, rank_out_of_reach, unbounded_blocks
from .catalog import Pair
from .trainers import Solves, Trainer

Say = Callable[[str, str], None]


def bounding_pairs(tr: Trainer, pairs: Sequence[Pair], blocks: Sequence[str]) -> list[Pair]:
    """The pairs with a constraint (on ``tr``) whose A has a diagonal entry on one of ``blocks``."""
    V = tr.model.variables
    cols = np.zeros(V.N, bool)
    for b in blocks:
        cols[V.slice(b)] = True
    return [p for p in pairs if any(np.any((c.A.diagonal() != 0) & cols) for c in tr.pairs[p])]


def _scores(tr: Trainer, remaining: list[Pair], min_violation: float, accept: str,
            chosen: list[Pair]) -> dict[Pair, float] | None:
    """The violation of ``tr``'s last X by each pair that can cut it, or None (and ``tr`` marked not reached)."""
    assert tr.last is not None, "scores need the trainer's last solve"
    res = tr.last.sdp
    unb = unbounded_blocks(tr.model, res)  # a ray's support, or blocks of X far beyond X_hh
    pool = bounding_pairs(tr, remaining, unb) if unb else remaining
    X = res.X
    v = {} if X is None else tr.violations(X, pool)
    v = {p: x for p, x in v.items() if x > min_violation}
    if v:
        return v
    vd = tr.last.verdict
    structural = bool(unb)
    if unb:
        why = f"the relaxation is unbounded in {compress(unb)} and no learned candidate bounds it"
    else:
        why = ("its SDP solution is rank 1 but the cost gap is not closed (solver accuracy?)" if vd.rank_tight
               else "no remaining candidate cuts its SDP solution")
        if not vd.rank_tight:
            cons = tr.model.all_constraints() + [c for p in chosen for c in tr.pairs[p]]
            out_of_reach = rank_out_of_reach(tr.model, cons)
            structural = bool(out_of_reach) and accept == "rank"
            why = "; ".join(w for w in (why, out_of_reach) if w)
        if vd.cost_tight and accept == "rank":
            why += f"; the relaxation is cost-tight (relative gap {vd.rel_gap:.1e}): use --accept cost"
    tr.reached, tr.structural = False, structural
    tr.message = f"not tight with {len(chosen)} pairs, log SVR {vd.log_svr:.2f}: {why}"
    return None


def tighten(run: Solves, trainers: list[Trainer], candidates: list[Pair], say: Say, start: Sequence[Pair] = (),
            stage: str = "primary", min_violation: float = 1e-7) -> list[Pair]:
    """Greedy over ``trainers`` from the set ``start`` (module docstring); marks the ones not reached."""
    loose = [tr for tr in trainers if not run.solve(tr, start, stage)]
    chosen: list[Pair] = list(start)
    r = 0
    while loose:
        remaining = [p for p in candidates if p not in set(chosen)]
        score: dict[Pair, float] = {}
        blind = False  # a loose trainer whose solve returned no usable X: nothing ranks the candidates
        for tr in loose:
            res = tr.last.sdp if tr.last is not None else None
            if res is None or res.X is None or not (res.usable or res.settled or is_unbounded(res)):
                if remaining:
                    blind = True
                else:
                    tr.reached = False
                    tr.message = f"solver status {res.status if res else '?'} with every candidate added"
                continue
            v = _scores(tr, remaining, min_violation, run.criteria.accept, chosen)
            for p, x in (v or {}).items():
                score[p] = max(score.get(p, 0.0), x)
        loose = [tr for tr in loose if tr.reached]
        ranked = sorted(score, key=lambda p: -score[p])
        if not loose or not (ranked or blind):
            break
        if ranked:  # the instances with a usable X rank; a blind one is solved again with the larger set
            chosen += ranked[: 2 ** r]
            r += 1
        else:  # only blind instances left: every remaining candidate; the reduction removes those not needed
            chosen += remaining
        loose = [tr for tr in loose if not run.solve(tr, chosen, "tighten")]
        say("tighten", f"{len(chosen)} pairs, {len(loose)} not tight")
    return chosen


def tighten_each(run: Solves, trainers: list[Trainer], candidates: list[Pair], say: Say, start: Sequence[Pair] = (),
                 stage: str = "validate") -> list[Pair]:
    """``tighten`` on one trainer at a time, in order, each from the set the ones before it left: for instances
    that the set failed together (a held-out batch), where the pairs that fix the first usually fix the others,
    so each of those costs one solve instead of one per greedy round."""
    chosen = list(start)
    for tr in trainers:
        chosen = tighten(run, [tr], candidates, say, chosen, stage)
    return chosen


def reduce(run: Solves, trainers: list[Trainer], chosen: list[Pair], say: Say,
           keep: Sequence[Pair] = ()) -> tuple[list[Pair], list[Pair]]:
    """A subset of ``chosen`` tight on every trainer from which no pair outside ``keep`` can be removed, and the
    pairs dropped by the final check (module docstring).  ``keep``: pairs that stay (a validated set that the
    closed loop grows: removing its pairs to fit the new instances would lose what the earlier ones showed)."""
    kept = set(keep)
    imp: dict[Pair, float] = {p: 0.0 for p in chosen}
    for tr in trainers:
        for p, v in tr.importance().items():
            imp[p] = max(imp.get(p, 0.0), v)
    probe = [_hardest(trainers)]
    current = list(chosen)
    pending = sorted((p for p in chosen if p not in kept), key=lambda p: imp[p])
    breaker: dict[Pair, Trainer] = {}
    while True:
        current = _remove_blocks(run, probe, current, pending, breaker, say)
        ok, bad = run.tight_on_all([tr for tr in trainers if tr not in probe], current, "reduce")
        if ok or bad is None:
            break
        probe.append(bad)
        current = _restore(run, bad, current, [p for p in chosen if p not in current])
        pending = sorted((p for p in current if p not in kept), key=lambda p: imp[p])
    order = probe + [tr for tr in trainers if tr not in probe]
    dropped: list[Pair] = []
    changed = True
    while changed:  # passes until one drops nothing: then every check of it was made on the final set
        changed = False
        for p in [q for q in current if q not in kept]:
            rest = [q for q in current if q != p]
            _to_front(order, breaker.get(p))
            ok, bad = run.tight_on_all(order, rest, "verify", exact=True)
            _to_front(order, bad)
            if ok:  # numerically non-monotone: p is not needed after all
                current.remove(p)
                dropped.append(p)
                changed = True
            elif bad is not None:
                breaker[p] = bad
    return current, dropped


def _to_front(order: list[Trainer], tr: Trainer | None) -> None:
    """Move ``tr`` (if any) to the front of ``order``: the instance that broke the last trial is solved first."""
    if tr is not None:
        order.remove(tr)
        order.insert(0, tr)


def _hardest(trainers: list[Trainer]) -> Trainer:
    """The trainer with the largest set known not to be tight on it (the first one when none is known)."""
    return max(trainers, key=lambda tr: max((len(s) for s in tr.loose_sets), default=-1))


def _remove_blocks(run: Solves, probe: list[Trainer], current: list[Pair], pending: list[Pair],
                   breaker: dict[Pair, Trainer], say: Say) -> list[Pair]:
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
            if bad is not None:
                breaker[pending[0]] = bad
            pending = pending[1:]
        else:
            chunk = c // 2
    return current


def _restore(run: Solves, tr: Trainer, current: list[Pair], removed: list[Pair]) -> list[Pair]:
    """``current`` plus the fewest ``removed`` pairs that the greedy needs to make ``tr`` tight again: ranked by
    their violation of tr's last solution, 1, 2, 4, … at a time (all of them: the tightened set, tight on tr)."""
    chosen, remaining, r = list(current), list(removed), 0
    while remaining:
        last = tr.last.sdp if tr.last is not None else None
        X = None if last is None or not (last.usable or last.settled) else last.X
        if X is not None:
            v = tr.violations(X, remaining)
            remaining.sort(key=lambda p: -v[p])
            add, remaining = remaining[: 2 ** r], remaining[2 ** r:]
            r += 1
        else:
            add, remaining = remaining, []
        chosen += add
        known = tr.known(frozenset(chosen))
        if known or (known is None and run.solve(tr, chosen, "reduce", with_ray=False)):
            break
    return chosen
