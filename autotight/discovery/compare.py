"""Side-by-side comparison of the learned constraints with the paper's hand-derived families."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..model import Constraint, Model
from ..svec import sym_to_poly
from .catalog import Catalog


def _local_poly(c: Constraint, cols: np.ndarray) -> np.ndarray | None:
    """Monomial coefficients of c on the group's columns, or None if c reaches outside them."""
    U = sp.coo_array(c.A)
    pos = {int(k): q for q, k in enumerate(cols)}
    if not all(int(r) in pos for r in U.row):
        return None
    loc = sp.coo_array((U.data, ([pos[int(r)] for r in U.row], [pos[int(q)] for q in U.col])),
                       shape=(len(cols), len(cols)))
    return sym_to_poly(loc)


def span_residual(c: Constraint, basis: Sequence[Constraint], cols: np.ndarray) -> float:
    """‖v − proj_span(basis) v‖ / ‖v‖ in monomial coefficients on ``cols`` (inf if c leaves them)."""
    v = _local_poly(c, cols)
    if v is None:
        return float("inf")
    B = [p for p in (_local_poly(b, cols) for b in basis) if p is not None]
    if not B:
        return 1.0
    M = np.array(B).T
    coef, *_ = np.linalg.lstsq(M, v, rcond=None)
    return float(np.linalg.norm(v - M @ coef) / max(float(np.linalg.norm(v)), 1e-300))


def _group_for(c: Constraint, cat: Catalog):
    U = sp.coo_array(c.A)
    need = set(U.row.tolist())
    best = None
    for g in cat.groups:
        if need <= set(g.columns.tolist()) and (best is None or len(g.columns) < len(best.columns)):
            best = g
    return best


def _homogeneous(model: Model) -> list[Constraint]:
    return [c for c in model.primary() if c.b == 0]


def paper_in_span(cat: Catalog) -> dict[str, dict]:
    """Per paper family: count, and the largest relative residual of its constraints against the
    span of the primary constraints and every learned relation of the group that contains it."""
    model = cat.model
    out = {}
    for fam, cons in model.paper.items():
        worst = 0.0
        for c in cons:
            g = _group_for(c, cat)
            if g is None:
                worst = float("inf")
                continue
            basis = _homogeneous(model) + cat.basic(g.group.name)
            worst = max(worst, span_residual(c, basis, g.columns))
        out[fam] = {"count": len(cons), "max_residual": worst}
    return out


def resemblance(c: Constraint, cat: Catalog, tol: float = 1e-6) -> str:
    """Which paper family (with the primary constraints) spans a learned constraint: a family name,
    'paper (combined)', or 'new'."""
    model = cat.model
    g = _group_for(c, cat)
    if g is None:
        return "new"
    prim = _homogeneous(model)
    for fam, cons in model.paper.items():
        if span_residual(c, prim + list(cons), g.columns) < tol:
            return fam
    if model.paper and span_residual(c, prim + model.paper_constraints(), g.columns) < tol:
        return "paper (combined)"
    return "new"
