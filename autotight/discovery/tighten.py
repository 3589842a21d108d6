"""Greedy tightening: add the pairs the current SDP solution violates most until it is tight.

Rule: every valid constraint vanishes at rank-1 feasible points, so a pair that the current X
violates cuts X off.  Round t adds the 2^t most violated pairs (relative violation
|⟨A,X⟩|/(‖A‖_F‖X‖_F) above ``min_violation``), so the number of solves is logarithmic in the
number of pairs.  When no pair is violated and the SDP is still not tight, adding the rest
cannot change the solution: the problem is "not tightenable with this lifting".
"""

from __future__ import annotations

from dataclasses import dataclass

from ..sdp.result import SDPResult
from ..tightness import Verdict
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


def tighten(oracle: Oracle, min_violation: float = 1e-7, progress=None) -> TightenResult:
    v0, res = oracle.solve([], stage="primary")
    if v0.tight:
        return TightenResult([], True, v0, res, v0, "tight with the primary constraints alone")
    chosen: list[Pair] = []
    remaining = list(oracle.pairs)
    v, t = v0, 0
    while True:
        if res.X is None:
            return TightenResult(chosen, False, v, res, v0, f"solver failed ({res.status}); cannot rank candidates")
        scores = {p: oracle.violation(res.X, p) for p in remaining}
        ranked = sorted((p for p in remaining if scores[p] > min_violation), key=lambda p: -scores[p])
        if not ranked:
            return TightenResult(chosen, False, v, res, v0,
                                 "not tightenable with this lifting: no remaining candidate cuts the SDP solution")
        add = ranked[: 2 ** t]
        chosen += add
        remaining = [p for p in remaining if p not in set(add)]
        t += 1
        v, res = oracle.solve(chosen, stage="tighten")
        if progress is not None:
            progress(f"{len(chosen)} pairs, log SVR {res.log_svr:.1f}")
        if v.tight:
            return TightenResult(chosen, True, v, res, v0, f"tight after {t} rounds")
