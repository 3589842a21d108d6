"""Reduction of a tight set of pairs to an irreducible one, and AutoTight's prefix rule for comparison.

``reduce_pairs`` (group testing on a monotone property):

- Order: the pairs' dual importance Σ|yᵢ|‖Aᵢ‖_F (least important first), recomputed from the
  multipliers of every tight solve of the reduction (no extra solve), so the order follows the set
  as it shrinks.
- Blocks: the first block is every pair whose importance is negligible (below ``NEGLIGIBLE`` of the
  largest; at least half the set when there are none); a block whose removal keeps the SDP tight
  goes at once and the next block doubles, otherwise the block is halved; a single pair whose
  removal breaks tightness is necessary.
- Early stop: tightness is monotone in the constraint set (fewer constraints, lower bound no
  higher), so a pair found necessary on a set S is necessary on every subset of S, in particular
  on the final set.  When every remaining pair has been found necessary the irreducibility proof is
  complete and no verification solve is needed.  ``verify=True`` re-solves, for every final pair
  tested on a larger set, the final set without it (a guard against numerical non-monotonicity:
  a pair whose removal keeps the SDP tight is then dropped and the check repeats).

"Tight" is the oracle's acceptance (rank, cost, or certified).  Solver calls (retries and fallbacks
included) are counted by the oracle.  Clarabel has no warm start, so every solve starts cold; what
is reused is the order (dual importance) and monotonicity.

``shortest_tight_prefix``: AutoTight's rule (largest importance first, the shortest tight prefix by
adding one pair at a time), for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..sdp.result import SDPResult
from .catalog import Pair
from .oracle import Oracle

#: importance below this fraction of the largest counts as negligible (the first block removed)
NEGLIGIBLE = 1e-4


@dataclass
class ReduceResult:
    pairs: list[Pair]
    irreducible: bool
    n_solves: int
    n_verify_solves: int
    message: str
    dropped_in_verification: list[Pair] = field(default_factory=list)
    proof: str = "monotonicity"  # "monotonicity" (every pair failed on a superset) or "verified" (on the final set)


def _order(oracle: Oracle, res: SDPResult, current: list[Pair], pending: list[Pair]) -> list[Pair]:
    """``pending`` by the importance from ``res`` (a solve with exactly ``current``), least first."""
    if res.y is None:
        return pending
    imp = oracle.importance(res, current)
    return sorted(pending, key=lambda p: imp[p])


def reduce_pairs(oracle: Oracle, chosen: list[Pair], tight_res: SDPResult, verify: bool = False,
                 progress=None) -> ReduceResult:
    start = oracle.n_solves
    current = list(chosen)
    imp = oracle.importance(tight_res, chosen)
    pending = sorted(chosen, key=lambda p: imp[p])
    top = max(imp.values(), default=0.0)
    negligible = sum(1 for p in pending if imp[p] <= NEGLIGIBLE * top) if top > 0 else 0
    chunk = negligible if negligible else max(1, len(pending) // 2)
    tested_on: dict[Pair, frozenset] = {}  # pair → the set on which removing it broke tightness
    while pending:
        c = min(chunk, len(pending))
        block = set(pending[:c])
        trial = [p for p in current if p not in block]
        v, res = oracle.solve(trial, stage="reduce")
        if progress is not None:
            progress(f"{len(current)} pairs, {len(pending)} untested")
        if oracle.ok(v):
            current = trial
            pending = _order(oracle, res, current, pending[c:])
            chunk = 2 * c
        elif c == 1:
            tested_on[pending[0]] = frozenset(current)
            pending = pending[1:]
        else:
            chunk = c // 2
    n_reduce = oracle.n_solves - start
    if not verify:
        return ReduceResult(current, True, n_reduce, 0,
                            f"irreducible: removing any one of the {len(current)} pairs breaks tightness "
                            "(each tested on a superset of this set; tightness is monotone)")
    dropped: list[Pair] = []
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
                        f"irreducible: removing any one of the {len(current)} pairs breaks tightness (verified "
                        "on this set)", dropped, "verified")


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


def shortest_tight_prefix_bisect(oracle: Oracle, chosen: list[Pair], tight_res: SDPResult) -> tuple[list[Pair], int]:
    """The same prefix as ``shortest_tight_prefix`` (tightness is monotone in the prefix length), found
    by bisection on the length: about log2(len(chosen)) solves instead of one per prefix.  Returns the
    prefix and the number of solves."""
    start = oracle.n_solves
    imp = oracle.importance(tight_res, chosen)
    order = sorted(chosen, key=lambda p: -imp[p])
    lo, hi = 0, len(order)  # prefix hi is tight (the whole set); lo − 1 … : not known
    v, _ = oracle.solve([], stage="prefix")
    if oracle.ok(v):
        return [], oracle.n_solves - start
    while hi - lo > 1:  # invariant: prefix lo is not tight, prefix hi is tight
        mid = (lo + hi) // 2
        v, _ = oracle.solve(order[:mid], stage="prefix")
        if oracle.ok(v):
            hi = mid
        else:
            lo = mid
    return order[:hi], oracle.n_solves - start
