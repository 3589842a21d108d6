"""Factors of one type on fresh instances: their data, the primary constraints on their columns and the
paper's families there, as local coefficient vectors (monomials θ_iᵀθ_j of the factor's columns, h first, in
svec order without √2: ``autotight.svec``).

The normal form of a relation v modulo the primary constraints G (rows spanning the homogeneous primary
constraints that live on the factor's columns) is

    NF(v) = v − v[P] (G_P)⁻¹ G,

P the pivot monomials: the first monomials, in the order "h·x first, then the other products, h² last"
(svec order within each), on which G has full rank.  NF(v) is 0 on P, depends only on the span of G,
and NF(v) = NF(w) exactly when v − w is a combination of primary constraints.  The pivots are chosen on
the first factor and kept for all (a factor where G_P is near singular is left out).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import AutotightError
from ..model import Constraint, Model
from ..problem import Problem
from ..discovery.transport import Layout
from ..svec import stored_entries, triu_indices

#: the data of the instances are drawn at this noise level (when the problem has a ``sigma`` parameter),
#: so that the measurements of every factor type vary over their whole range
DATA_SIGMA = 1.0
#: most instances generated to collect the factors
MAX_INSTANCES = 400
#: G_P with a condition number above this: the factor is left out (its pivots are not generic)
MAX_PIVOT_COND = 1e8


def factor_cols(model: Model, f) -> np.ndarray:
    V = model.variables
    return np.concatenate([np.arange(V.offsets[b], V.offsets[b] + V.sizes[b]) for b in f.blocks]).astype(np.int64)


def local_poly(c: Constraint, cols: np.ndarray) -> np.ndarray | None:
    """Coefficients of c (A symmetric) on the monomials of ``cols`` (None when c reaches outside them)."""
    U = sp.coo_array(c.A)
    pos = np.full(max(int(cols.max()), int(U.row.max(initial=0)), int(U.col.max(initial=0))) + 1, -1,
                  dtype=np.int64)
    pos[cols] = np.arange(len(cols))
    r, q = pos[U.row], pos[U.col]
    if np.any(r < 0) or np.any(q < 0):
        return None
    up = r <= q
    n = len(cols)
    out = np.zeros(n * (n + 1) // 2)
    np.add.at(out, q[up] * (q[up] + 1) // 2 + r[up], np.where(r[up] == q[up], 1.0, 2.0) * U.data[up])
    return out


def local_polys(rows: np.ndarray, cols_: np.ndarray, vals: np.ndarray, owner: np.ndarray, m: int, cols: np.ndarray,
                N: int) -> np.ndarray:
    """``local_poly`` of every matrix that lies on ``cols``, from the stored entries (rows, cols_, vals, owner) of m
    symmetric N × N matrices (``svec.stored_entries``) → (number of those matrices, |cols|(|cols| + 1)/2), in
    the matrices' order; the matrices that reach outside ``cols`` are left out."""
    pos = np.full(N, -1, dtype=np.int64)
    pos[cols] = np.arange(len(cols))
    r, q = pos[rows], pos[cols_]
    outside = np.bincount(owner, weights=(r < 0) | (q < 0), minlength=m)
    on = np.flatnonzero(outside == 0)
    rank = np.full(m, -1, dtype=np.int64)
    rank[on] = np.arange(on.size)
    keep = (rank[owner] >= 0) & (r <= q)
    r, q, k = r[keep], q[keep], rank[owner[keep]]
    n = len(cols)
    out = np.zeros((on.size, n * (n + 1) // 2))
    np.add.at(out, (k, q * (q + 1) // 2 + r), np.where(r == q, 1.0, 2.0) * vals[keep])
    return out


def pivot_order(n_h: int, n: int) -> np.ndarray:
    """Monomial positions in pivot preference: h·x (x not h), then x·y, then h·h' (n_h columns of h)."""
    ii, jj = triu_indices(n)
    hh = (ii < n_h) & (jj < n_h)
    hx = (ii < n_h) & (jj >= n_h)
    pos = np.arange(len(ii))
    return np.concatenate([pos[hx], pos[~hh & ~hx], pos[hh]])


def choose_pivots(G: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The first monomials of ``order`` on which the rows of G are independent (as many as rank G)."""
    if G.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    U, s, Vt = np.linalg.svd(G, full_matrices=False)
    rank = int(np.sum(s > 1e-10 * s[0]))
    B = Vt[:rank]  # orthonormal row basis
    piv: list[int] = []
    Q = np.zeros((rank, 0))
    for mono in order:
        col = B[:, mono].copy()
        col -= Q @ (Q.T @ col)
        n = np.linalg.norm(col)
        if n > 1e-8:
            Q = np.column_stack([Q, col / n])
            piv.append(int(mono))
            if len(piv) == rank:
                break
    return np.array(piv, dtype=np.int64)


@dataclass
class FactorSamples(Layout):
    """S factors of one type: data D (S, p); ``reducers`` (S, r, m): (G_P)⁻¹ G per factor, so that
    NF(v) = v − v[pivots] · reducer; ``paper``: family → (S, k, m) local coefficient vectors of its k rows."""

    factor_type: str
    roles: list[str]
    block_sizes: list[int]
    d: int
    D: np.ndarray
    pivots: np.ndarray
    reducers: np.ndarray
    paper: dict[str, np.ndarray] = field(default_factory=dict)
    paper_rows: dict[str, list[str]] = field(default_factory=dict)
    instances: list[tuple[Any, Model, list]] = field(default_factory=list)

    def normal_form(self, V: np.ndarray) -> np.ndarray:
        """NF of relations V (S, …, m), one factor per leading index."""
        V = np.asarray(V, dtype=float)
        if self.pivots.size == 0:  # no relation of the factor's own to reduce by: every v is its normal form
            return V
        lead = V[..., self.pivots]  # (S, …, r)
        shape = V.shape
        Vf = V.reshape(shape[0], -1, shape[-1])
        Lf = lead.reshape(shape[0], -1, len(self.pivots))
        return (Vf - Lf @ self.reducers).reshape(shape)


def data_params(problem: Problem, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` with σ = ``DATA_SIGMA`` (when the problem has a ``sigma`` parameter, within its bounds)."""
    p = dict(params)
    if "sigma" in problem.params:
        hi = problem.params["sigma"].high
        p["sigma"] = DATA_SIGMA if hi is None else min(DATA_SIGMA, hi)
    return p


def collect(problem: Problem, params: dict[str, Any], factor_type: str, n: int, seed: int,
            keep_instances: int = 0, wide: bool = True) -> FactorSamples:
    """At least n factors of ``factor_type`` from instances with seeds (seed, 7000 + i) at ``params``, their
    data drawn at σ = ``DATA_SIGMA`` when ``wide`` (see ``FactorSamples``).  ``keep_instances``: keep the
    first instances (with their models and factors) for checks on feasible states.  AutotightError when the
    type has no factor."""
    pars = problem.parse_params(data_params(problem, params) if wide else params)
    D: list[np.ndarray] = []
    Gs: list[np.ndarray] = []
    papers: dict[str, list[np.ndarray]] = {}
    rows: dict[str, list[str]] = {}
    kept: list = []
    layout = None
    order: np.ndarray | None = None
    pivots: np.ndarray | None = None
    d = 1
    for i in range(MAX_INSTANCES):
        if len(D) >= n:
            break
        inst = problem.generate(pars, np.random.default_rng([seed, 7000 + i]))
        model = problem.build(inst)
        d = model.d
        fs = [f for f in model.factors if f.type == factor_type]
        if not fs:
            raise AutotightError(f"factor type {factor_type!r} has no factor on an instance with params {pars}")
        prim = [c.A for c in model.primary() if c.b == 0]
        pr, pc, pv, owner = stored_entries(prim)  # a constraint lies on a factor when all its rows do
        paper_of: dict[str, list[Constraint]] = {}
        for cons in model.paper.values():
            for c in cons:
                paper_of.setdefault(c.factor or "", []).append(c)
        if len(kept) < keep_instances:
            kept.append((inst, model, fs))
        V = model.variables
        for f in fs:
            cols = factor_cols(model, f)
            sizes = [V.sizes[b] for b in f.blocks]
            if layout is None:
                layout = (list(f.roles or f.blocks), sizes)
                order = pivot_order(model.d, len(cols))
            elif sizes != layout[1]:
                raise AutotightError(f"factors of type {factor_type!r} have different block sizes")
            G = local_polys(pr, pc, pv, owner, len(prim), cols, V.N)
            if pivots is None:
                assert order is not None
                pivots = choose_pivots(G, order)
            GP = G[:, pivots]
            try:
                # rows of (G_P)⁻¹ G from any row basis of G: least squares on the pivot columns
                X, *_ = np.linalg.lstsq(GP.T, np.eye(len(pivots)), rcond=None)
                R = X.T @ G
            except np.linalg.LinAlgError:
                continue
            if len(pivots) and (np.linalg.cond(R[:, pivots]) > MAX_PIVOT_COND
                                or not np.allclose(R[:, pivots], np.eye(len(pivots)), atol=1e-8)):
                continue
            fam_rows: dict[str, list[tuple[str, np.ndarray]]] = {}
            for c in paper_of.get(f.name, []):
                pl = local_poly(c, cols)
                if pl is not None:
                    fam_rows.setdefault(c.family or "paper", []).append((c.name.rsplit(":", 1)[-1], pl))
            if D and sorted(fam_rows) != sorted(papers):
                continue
            for fam, rs in fam_rows.items():
                papers.setdefault(fam, []).append(np.array([p for _, p in rs]))
                rows[fam] = [r for r, _ in rs]
            D.append(np.zeros(0) if f.data is None else np.asarray(f.data, dtype=float).ravel())
            Gs.append(R)
    if layout is None or not D or pivots is None:
        raise AutotightError(f"no factor of type {factor_type!r} found")
    return FactorSamples(factor_type, layout[0], layout[1], d, np.array(D).reshape(len(D), -1), pivots,
                         np.array(Gs), {k: np.array(v) for k, v in papers.items()}, rows, kept)
