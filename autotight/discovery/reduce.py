"""Reduction of a tight set of pairs to an irreducible one, and AutoTight's prefix rule for comparison.

``reduce_pairs``: pairs are ordered by their dual importance Σ|yᵢ|‖Aᵢ‖_F in the tight solve
(least important first) and removed in blocks: a block whose removal keeps the SDP tight goes
at once (the block size then doubles); otherwise it is halved, and a single pair whose removal
breaks tightness is necessary.  Tightness is monotone in the constraint set, so a pair found
necessary stays necessary as others are removed; the final check re-solves only for pairs whose
test was made on a larger set than the final one.  The set is reported irreducible only after
that check: removing any one remaining pair breaks tightness.  "Tight" is the oracle's acceptance
(rank, or cost only).  Solver calls (retries included) are counted by the oracle.  Clarabel has no
warm start, so every solve starts cold; what is reused is the order (dual importance) and the
monotonicity, and the verification re-solves only pairs not yet tested on the final set.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..sdp.result import SDPResult
from .catalog import Pair
from .oracle import Oracle


@dataclass
class ReduceResult:
    pairs: list[Pair]
    irreducible: bool
    n_solves: int
    n_verify_solves: int
    message: str
    dropped_in_verification: list[Pair] = field(default_factory=list)


def reduce_pairs(oracle: Oracle, chosen: list[Pair], tight_res: SDPResult, verify: bool = True,
                 progress=None) -> ReduceResult:
    start = oracle.n_solves
    imp = oracle.importance(tight_res, chosen)
    pending = sorted(chosen, key=lambda p: imp[p])
    current = list(chosen)
    tested_on: dict[Pair, frozenset] = {}
    chunk = max(1, len(pending) // 2)
    while pending:
        c = min(chunk, len(pending))
        block = set(pending[:c])
        trial = [p for p in current if p not in block]
        v, _ = oracle.solve(trial, stage="reduce")
        if progress is not None:
            progress(f"{len(current)} pairs")
        if oracle.ok(v):
            current, pending, chunk = trial, pending[c:], 2 * c
        elif c == 1:
            tested_on[pending[0]] = frozenset(current)
            pending = pending[1:]
        else:
            chunk = c // 2
    n_reduce = oracle.n_solves - start
    dropped: list[Pair] = []
    if not verify:
        return ReduceResult(current, False, n_reduce, 0, "not verified")
    final = frozenset(current)
    changed = True
    while changed:
        changed = False
        for p in list(current):
            if tested_on.get(p) == final:
                continue  # tested on exactly this set already
            v, _ = oracle.solve([q for q in current if q != p], stage="verify")
            tested_on[p] = final
            if oracle.ok(v):  # numerically non-monotone: drop it and verify again
                current.remove(p)
                dropped.append(p)
                final = frozenset(current)
                changed = True
                break
    n_verify = oracle.n_solves - start - n_reduce
    return ReduceResult(current, True, n_reduce, n_verify,
                        f"irreducible: removing any one of the {len(current)} pairs breaks tightness", dropped)


def shortest_tight_prefix(oracle: Oracle, chosen: list[Pair], tight_res: SDPResult) -> tuple[list[Pair], int]:
    """AutoTight's rule: sort by dual importance (largest first), keep the shortest tight prefix
    (found by adding one pair at a time).  Returns the prefix and the number of solves."""
    start = oracle.n_solves
    imp = oracle.importance(tight_res, chosen)
    order = sorted(chosen, key=lambda p: -imp[p])
    for k in range(0, len(order) + 1):
        v, _ = oracle.solve(order[:k], stage="prefix")
        if oracle.ok(v):
            return order[:k], oracle.n_solves - start
    return order, oracle.n_solves - start
