"""Unbounded relaxations: which blocks of X nothing bounds, in one line.

An SDP min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0 is unbounded below when a ray X_r ⪰ 0 with ⟨Aᵢ,X_r⟩ = 0
and ⟨Q,X_r⟩ < 0 exists.  The solver then reports DualInfeasible (its dual, in y, is infeasible) and
returns X_r as the certificate: the blocks on which X_r has mass are the unbounded ones.  A solve that
ends "Solved" with a cost below a valid lower bound of the QCQP (e.g. negative for a cost that is a
sum of squares and non-negative terms) is unbounded in the same sense, stopped by the solver's limits:
its unbounded blocks are those whose diagonal exceeds ``HUGE`` times the feasible scale.

A bounded relaxation can still have an unbounded optimal set: a column on which neither the cost nor
any constraint has a diagonal entry (``certificate.recession_columns``) can grow at no cost, so no SDP
solution is rank 1 and an interior-point solver drifts along it.  ``rank_out_of_reach`` says so.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from .errors import SolverError
from .model import HOMOGENISING, Constraint, Model
from .sdp.result import SDPResult, Status, finite

#: statuses meaning "the SDP in X is unbounded below" (its dual is infeasible)
UNBOUNDED_STATUSES = (Status.DUAL_INFEASIBLE, Status.ALMOST_DUAL_INFEASIBLE)
#: a block is in a ray's support when its largest diagonal entry is above this fraction of the ray's largest
RAY_SUPPORT = 1e-6
#: a block of a finite solution is unbounded when its diagonal exceeds this multiple of the feasible scale
HUGE = 1e6


class UnboundedRelaxation(SolverError):
    """The relaxation is unbounded below; ``blocks`` names the blocks that nothing bounds."""

    def __init__(self, message: str, blocks: list[str]):
        super().__init__(message)
        self.blocks = blocks


def is_unbounded(res: SDPResult, lower_bound: float | None = None) -> bool:
    """DualInfeasible, or a finite cost below ``lower_bound`` (a valid bound of the QCQP, if known)."""
    if res.status in UNBOUNDED_STATUSES:
        return True
    return lower_bound is not None and np.isfinite(res.primal_cost) and res.primal_cost < lower_bound - 1e-6 * max(
        1.0, abs(lower_bound))


def unbounded_blocks(model: Model, res: SDPResult, scale: float | None = None) -> list[str]:
    """Blocks of X that nothing bounds, in model order.

    DualInfeasible: the blocks in the support of the returned ray (max diagonal ≥ RAY_SUPPORT × the
    ray's largest).  Otherwise: blocks whose max diagonal exceeds HUGE × ``scale`` (default: X_hh, the
    homogenising entry, i.e. 1); [] when X is missing or nothing is that large.
    """
    if res.X is None or not finite(res.X):
        return []
    d = np.abs(res.X.diagonal())  # dense or sparse X
    V = model.variables
    per = {n: float(d[V.slice(n)].max()) for n in V.names}
    if res.status in UNBOUNDED_STATUSES:
        top = max(per.values())
        return [n for n, v in per.items() if top > 0 and v >= RAY_SUPPORT * top and n != HOMOGENISING]
    ref = scale if scale is not None else max(per[HOMOGENISING], 1e-300)
    return [n for n, v in per.items() if v > HUGE * ref and n != HOMOGENISING]


def recession_blocks(model: Model, constraints: Sequence[Constraint]) -> list[str]:
    """Blocks holding a recession column of the relaxation with these constraints (module docstring)."""
    from .certificate import entries, recession_columns, stack

    J = recession_columns(model.Q, entries(stack(constraints)[0]))
    return list(OrderedDict.fromkeys(model.variables.block_of(int(j))[0] for j in J))


def rank_out_of_reach(model: Model, constraints: Sequence[Constraint]) -> str:
    """'' or one clause: rank d is out of reach because nothing bounds some blocks (module docstring)."""
    blocks = recession_blocks(model, constraints)
    if not blocks:
        return ""
    return (f"rank {model.d} is out of reach: nothing bounds block(s) {compress(blocks)} (no cost term and no "
            "constraint has a diagonal entry on them, so X can grow there at no cost)")


def compress(blocks: list[str]) -> str:
    """'r, rho_0, rho_1, phi_0' → 'r, rho_* (2), phi_0': names differing in a trailing number are merged."""
    groups: OrderedDict[str, list[str]] = OrderedDict()
    for b in blocks:
        m = re.fullmatch(r"(.*?)(\d+)", b)
        groups.setdefault(m.group(1) + "*" if m else b, []).append(b)
    return ", ".join(v[0] if len(v) == 1 else f"{k} ({len(v)})" for k, v in groups.items())


def unbounded_message(model: Model, res: SDPResult, blocks: list[str] | None = None) -> str:
    """One line: the relaxation is unbounded, which blocks, and that bounding constraints are needed."""
    blocks = unbounded_blocks(model, res) if blocks is None else blocks
    what = compress(blocks) if blocks else "(no block stands out)"
    return (f"the relaxation is unbounded ({res.status}, cost {res.primal_cost:.3g}): nothing bounds blocks {what}; "
            "constraints bounding them are needed (e.g. trace relations such as w² = h², zᵀz = ξᵀξ)")
