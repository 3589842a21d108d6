"""Greedy tightening: add the pairs the current SDP solution violates most until it is tight.

Rule: every valid constraint vanishes at rank-1 feasible points, so a pair that the current X
violates cuts X off.  Round t adds the 2^t most violated pairs (relative violation
|⟨A,X⟩|/(‖A‖_F‖X‖_F) above ``min_violation``), so the number of solves is logarithmic in the
number of pairs.  When no pair is violated and the SDP is still not tight, adding the rest
cannot change the solution: the problem is "not tightenable with this lifting".

Unbounded SDP (DualInfeasible: X is a ray, not a solution): the violation of a meaningless X does not
rank candidates.  The pairs that bound the unbounded blocks come first: those with a constraint whose
A has diagonal entries on those blocks (trace-bounding relations such as w² = h², zᵀz = ξᵀξ) and that
the ray violates (a pair the ray satisfies cannot cut it), most violated first, 2^t per round.  With
no such pair the result says which blocks nothing bounds (``unbounded_blocks``).

What counts as tight is the oracle's acceptance (``Oracle.ok``: rank, or cost only).

``start="all"`` (a problem module's ``DEFAULT_TIGHTEN``): once the relaxation is bounded, solve with
every candidate first.  Tightness is monotone in the constraint set, so that one solve decides
whether any subset can be tight (if all candidates are not, "not tightenable with this lifting"),
and its multipliers order the reduction (AutoTight's start).  Worth it when the violation ranking
is not selective (robust pose averaging: the greedy rounds end up adding every pair, one solve
per doubling).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..sdp.result import SDPResult
from ..tightness import Verdict
from ..unbounded import compress, is_unbounded, unbounded_blocks, unbounded_message
from .catalog import Pair
from .oracle import Oracle


@dataclass
class TightenResult:
    chosen: list[Pair]
    tight: bool
    verdict: Verdict
    sdp: SDPResult
    primary_verdict: Verdict
    message: str
    unbounded: list[str] = field(default_factory=list)  # blocks still unbounded at the end ([] if bounded)
    primary_unbounded: list[str] = field(default_factory=list)  # blocks unbounded with the primary constraints


def bounding_pairs(oracle: Oracle, pairs: list[Pair], blocks: list[str]) -> list[Pair]:
    """The pairs with a constraint whose A has a diagonal entry on one of ``blocks``."""
    V = oracle.model.variables
    cols = np.zeros(V.N, bool)
    for b in blocks:
        cols[V.slice(b)] = True
    out = []
    for p in pairs:
        for c in oracle.pairs[p]:
            dg = c.A.diagonal()
            if np.any((dg != 0) & cols):
                out.append(p)
                break
    return out


def tighten(oracle: Oracle, min_violation: float = 1e-7, progress=None, max_rounds: int | None = None,
            start: str = "greedy") -> TightenResult:
    """Greedy rounds until tight (``oracle.ok``), no candidate cuts X, or ``max_rounds`` rounds;
    ``start="all"``: every candidate in one solve once bounded (see the module docstring)."""
    if start not in ("greedy", "all"):
        raise ValueError(f"start must be 'greedy' or 'all', got {start!r}")
    v0, res = oracle.solve([], stage="primary")
    prim_unb = unbounded_blocks(oracle.model, res) if is_unbounded(res) else []
    if oracle.ok(v0):
        return TightenResult([], True, v0, res, v0, "tight with the primary constraints alone")
    chosen: list[Pair] = []
    remaining = list(oracle.pairs)
    v, t = v0, 0
    while True:
        if start == "all" and res.X is not None and not is_unbounded(res) and remaining:
            chosen, remaining = chosen + remaining, []
            t += 1
            v, res = oracle.solve(chosen, stage="tighten")
            if progress is not None:
                progress(f"{len(chosen)} pairs (all), log SVR {res.log_svr:.1f}")
            if oracle.ok(v):
                return TightenResult(chosen, True, v, res, v0, f"tight ({oracle.accept}) with every candidate "
                                     f"(after {t} rounds)", [], prim_unb)
            unb = unbounded_blocks(oracle.model, res) if is_unbounded(res) else []
            if not res.usable or getattr(v, "undecided", False):
                why = (f"undecided with every learned candidate ({res.status}; relative gap {v.rel_gap:.1e}): "
                       "the solver's accuracy does not decide the bracket")
            else:
                why = "not tightenable with this lifting: not tight with every learned candidate"
            return TightenResult(chosen, False, v, res, v0, why, unb, prim_unb)
        if res.X is None:
            return TightenResult(chosen, False, v, res, v0, f"solver failed ({res.status}); cannot rank candidates",
                                 primary_unbounded=prim_unb)
        unb = unbounded_blocks(oracle.model, res) if is_unbounded(res) else []
        pool = bounding_pairs(oracle, remaining, unb) if unb else remaining
        scores = {p: oracle.violation(res.X, p) for p in pool}
        ranked = sorted((p for p in pool if scores[p] > min_violation), key=lambda p: -scores[p])
        if not ranked:
            if unb:
                return TightenResult(chosen, False, v, res, v0,
                                     unbounded_message(oracle.model, res, unb) + "; no learned candidate bounds them",
                                     unb, prim_unb)
            return TightenResult(chosen, False, v, res, v0,
                                 "not tightenable with this lifting: no remaining candidate cuts the SDP solution",
                                 [], prim_unb)
        add = ranked[: 2 ** t]
        chosen += add
        remaining = [p for p in remaining if p not in set(add)]
        t += 1
        v, res = oracle.solve(chosen, stage="tighten")
        if progress is not None:
            state = f"unbounded ({compress(unb)})" if unb else f"log SVR {res.log_svr:.1f}"
            progress(f"{len(chosen)} pairs, {state}")
        if oracle.ok(v):
            return TightenResult(chosen, True, v, res, v0, f"tight ({oracle.accept}) after {t} rounds", [], prim_unb)
        if max_rounds is not None and t >= max_rounds:
            unb = unbounded_blocks(oracle.model, res) if is_unbounded(res) else []
            return TightenResult(chosen, False, v, res, v0, f"stopped after {t} rounds (max_rounds)", unb, prim_unb)
