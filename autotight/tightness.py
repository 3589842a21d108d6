"""When a relaxation counts as tight.

Rank: log SVR = log10(λ_d/λ_{d+1}) of X above ``min_log_svr`` (5, as in the paper).
Cost: the relative gap  (f_local − f_SDP) / max(|f_local|, cost_floor)  below ``gap_tol``, where
f_local is the best local solution found.  The SDP cost is a lower bound, so a gap well below
−gap_tol signals an inaccurate solve and is reported as not tight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sdp.result import SDPResult


@dataclass(frozen=True)
class Criteria:
    """Tightness thresholds.  gap_tol is relative to the local cost (floored at cost_floor)."""

    min_log_svr: float = 5.0
    gap_tol: float = 1e-5
    cost_floor: float = 1e-9


def relative_gap(sdp_cost: float, local_cost: float, floor: float = 1e-9) -> float:
    """(f_local − f_SDP) / max(|f_local|, floor)."""
    return float((local_cost - sdp_cost) / max(abs(local_cost), floor))


@dataclass
class Verdict:
    tight: bool
    rank_tight: bool
    cost_tight: bool
    log_svr: float
    rel_gap: float
    reason: str


def judge(res: SDPResult, best_local: float, criteria: Criteria = Criteria()) -> Verdict:
    """Tightness of one SDP solution against the best local cost."""
    if not res.usable:
        return Verdict(False, False, False, res.log_svr, float("nan"), f"solver status {res.status}")
    gap = relative_gap(res.primal_cost, best_local, criteria.cost_floor)
    rank_tight = bool(np.isfinite(res.log_svr) and res.log_svr > criteria.min_log_svr) or res.log_svr == np.inf
    cost_tight = bool(abs(gap) <= criteria.gap_tol)
    reasons = []
    if not rank_tight:
        reasons.append(f"log SVR {res.log_svr:.2f} ≤ {criteria.min_log_svr}")
    if not cost_tight:
        reasons.append(f"relative cost gap {gap:.2e} exceeds {criteria.gap_tol:g}")
    if res.status != "Solved":
        reasons.append(f"status {res.status}")
    return Verdict(rank_tight and cost_tight, rank_tight, cost_tight, res.log_svr, gap,
                   "; ".join(reasons) or "tight")
