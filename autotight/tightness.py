"""When a relaxation counts as tight.

Rank: log SVR = log10(λ_d/λ_{d+1}) of X above ``min_log_svr`` (5, as in the paper).
Cost: |f_local − f_SDP| ≤ gap_tol·max(|f_local|, cost_floor) + solver_accuracy·Σ|Q_ij X_ij|, where
f_local is the best local solution found.  The second term is what an interior-point solver can
resolve: the cost is a sum of terms of total magnitude Σ|Q_ij X_ij| that may cancel to a much
smaller value, and the solver is accurate relative to the terms, not to their sum.
The reported ``rel_gap`` is (f_local − f_SDP)/max(|f_local|, cost_floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sdp.result import SDPResult


@dataclass(frozen=True)
class Criteria:
    """Tightness thresholds.  gap_tol is relative to the local cost (floored at cost_floor);
    solver_accuracy (10× the default solver tolerance) is relative to the cost's term magnitude."""

    min_log_svr: float = 5.0
    gap_tol: float = 1e-5
    cost_floor: float = 1e-9
    solver_accuracy: float = 1e-8
    accept: str = "rank"  # what counts as tight: "rank" | "cost" | "certified" (see discovery.oracle.accepted)


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
    slack = criteria.gap_tol * max(abs(best_local), criteria.cost_floor) + criteria.solver_accuracy * res.cost_scale
    cost_tight = bool(abs(best_local - res.primal_cost) <= slack)
    reasons = []
    if not rank_tight:
        reasons.append(f"log SVR {res.log_svr:.2f} ≤ {criteria.min_log_svr}")
    if not cost_tight:
        reasons.append(f"relative cost gap {gap:.2e} exceeds {criteria.gap_tol:g} (+ solver accuracy)")
    if res.status != "Solved":
        reasons.append(f"status {res.status}")
    return Verdict(rank_tight and cost_tight, rank_tight, cost_tight, res.log_svr, gap,
                   "; ".join(reasons) or "tight")
