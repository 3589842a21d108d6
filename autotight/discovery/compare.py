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
    cols = np.asarray(cols)
    order = np.argsort(cols)
    at = np.searchsorted(cols, U.row, sorter=order)
    at_c = np.searchsorted(cols, U.col, sorter=order)
    at, at_c = np.minimum(at, len(cols) - 1), np.minimum(at_c, len(cols) - 1)
    if not (np.all(cols[order[at]] == U.row) and np.all(cols[order[at_c]] == U.col)):
        return None
    loc = sp.coo_array((U.data, (order[at], order[at_c])), shape=(len(cols), len(cols)))
    return sym_to_poly(loc)


def _polys(cons: Sequence[Constraint], cols: np.ndarray) -> list[np.ndarray]:
    """The monomial coefficients on ``cols`` of the constraints of ``cons`` inside them."""
    return [p for p in (_local_poly(b, cols) for b in cons) if p is not None]


def _orthonormal(B: list[np.ndarray]) -> np.ndarray | None:
    """An orthonormal basis (columns) of the span of the vectors B (singular values below lstsq's default
    cutoff, ε·max(shape)·s_max, dropped); None when B is empty."""
    if not B:
        return None
    U, sv, _ = np.linalg.svd(np.array(B).T, full_matrices=False)
    return U[:, sv > np.finfo(float).eps * max(len(B), len(B[0])) * sv[0]]


def _span_basis(basis: Sequence[Constraint], cols: np.ndarray) -> np.ndarray | None:
    """``_orthonormal`` of the constraints of ``basis`` inside ``cols``."""
    return _orthonormal(_polys(basis, cols))


def span_residual(c: Constraint, basis: Sequence[Constraint] | np.ndarray | None, cols: np.ndarray) -> float:
    """‖v − proj_span(basis) v‖ / ‖v‖ in monomial coefficients on ``cols`` (inf if c leaves them).  ``basis``:
    constraints, or their ``_span_basis`` when it is shared by several calls."""
    v = _local_poly(c, cols)
    if v is None:
        return float("inf")
    U = basis if basis is None or isinstance(basis, np.ndarray) else _span_basis(basis, cols)
    if U is None:
        return 1.0
    return float(np.linalg.norm(v - U @ (U.T @ v)) / max(float(np.linalg.norm(v)), 1e-300))


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


def _primary_polys(model: Model, g, cache: dict) -> list[np.ndarray]:
    """The homogeneous primary constraints inside group ``g`` as monomial coefficients (cached per group)."""
    key = ("primary", g.group.name)
    if key not in cache:
        cache[key] = _polys(_homogeneous(model), g.columns)
    return cache[key]


def paper_in_span(cat: Catalog, cache: dict | None = None) -> dict[str, dict]:
    """Per paper family: count, and the largest relative residual of its constraints against the
    span of the primary constraints and every learned relation of the group that contains it.  ``cache``: a
    dict kept between calls on one catalog (here and in ``resemblance``)."""
    model = cat.model
    cache = {} if cache is None else cache
    out = {}
    for fam, cons in model.paper.items():
        worst = 0.0
        for c in cons:
            g = _group_for(c, cat)
            if g is None:
                worst = float("inf")
                continue
            key = ("learned", g.group.name)
            if key not in cache:
                cache[key] = _orthonormal(_primary_polys(model, g, cache) + _polys(cat.basic(g.group.name), g.columns))
            worst = max(worst, span_residual(c, cache[key], g.columns))
        out[fam] = {"count": len(cons), "max_residual": worst}
    return out


def resemblance(c: Constraint, cat: Catalog, tol: float = 1e-6, cache: dict | None = None) -> str:
    """Which paper family (with the primary constraints) spans a learned constraint: a family name,
    'paper (combined)', or 'new'.  ``cache``: a dict kept between calls on one catalog (the spans per group)."""
    model = cat.model
    g = _group_for(c, cat)
    if g is None:
        return "new"
    cache = {} if cache is None else cache

    def basis(fam: str | None, cons: list[Constraint]) -> np.ndarray | None:
        key = (fam, g.group.name)
        if key not in cache:
            cache[key] = _orthonormal(_primary_polys(model, g, cache) + _polys(cons, g.columns))
        return cache[key]

    for fam, cons in model.paper.items():
        if span_residual(c, basis(fam, list(cons)), g.columns) < tol:
            return fam
    if model.paper and span_residual(c, basis(None, model.paper_constraints()), g.columns) < tol:
        return "paper (combined)"
    return "new"
