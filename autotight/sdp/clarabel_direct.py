"""Clarabel called directly with sparse data.

Dense cone (one PSD block), dual form:
    max bᵀy  s.t.  s = Q − Σ yᵢ Aᵢ ∈ PSD,
i.e. Clarabel's  min −bᵀy  s.t.  [svec A₁ … svec A_m] y + s = svec Q,  s ∈ PSDTriangleConeT(N).
The cone's dual variable z is svec(X) of the primal  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

Clique form (cliques C_1 … C_p of a chordal pattern that contains Q and every Aᵢ, with a clique tree):
by Agler's theorem, S = Q − Σ yᵢ Aᵢ ⪰ 0 on that pattern iff S = Σ_k E_kᵀ S_k E_k with S_k ⪰ 0, so
    max bᵀy  s.t.  S_k = [k owns (i,j)]·(Q − Σ yᵢAᵢ)_ij − t_{k,ij} + Σ_{children c} t_{c,ij} ∈ PSD,
where each entry belongs to the highest clique holding it ("owns") and the free transfer t_{k,ij}
moves the share of an entry from clique k to its tree parent.  Each transfer touches two cone rows,
so the overlaps stay sparse.  The cones' dual variables are the clique blocks X[C_k, C_k]; their
agreement on overlaps is the optimality condition for t.  Same optimal value as the dense SDP.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Sequence

import clarabel
import numpy as np
import scipy.sparse as sp

from ..svec import SQRT2, position_to_ij, smat, svec_columns, svec_dim, triu_indices
from .chordal import clique_tree, incidence, maximal
from .result import SDPResult, SolverOptions, finish


def _settings(opts: SolverOptions) -> "clarabel.DefaultSettings":
    s = clarabel.DefaultSettings()
    s.verbose = opts.verbose
    s.max_iter = opts.max_iter
    s.time_limit = opts.time_limit
    s.tol_gap_abs = opts.tol * 1e-3  # the scaled cost can be ≪ 1: keep the relative gap in charge
    s.tol_gap_rel = opts.tol
    s.tol_feas = opts.tol
    s.tol_ktratio = max(opts.tol, 1e-8)
    if opts.threads:
        s.max_threads = opts.threads
    if opts.regularization == "small":
        # Tight relaxations have rank-deficient PSD blocks; the default static regularisation (1e-8)
        # then limits accuracy (AlmostSolved, costs ~1e-5 off).  A smaller one solves them to tol.
        s.static_regularization_constant = 1e-10
        s.static_regularization_proportional = 1e-16
        s.dynamic_regularization_enable = False
    elif opts.regularization != "default":
        raise ValueError(f"unknown regularization {opts.regularization!r}; use 'small' or 'default'")
    # Clarabel decomposes by default; "dense" must mean dense, so it is on only when asked for
    s.chordal_decomposition_enable = opts.clarabel_chordal
    if opts.clarabel_chordal:
        s.chordal_decomposition_complete_dual = True
        s.chordal_decomposition_merge_method = opts.chordal_merge
    return s


def _sdp_status(clarabel_status: object) -> str:
    """Clarabel solved the SDP's dual: its "primal infeasible" is our dual infeasible and vice versa."""
    s = str(clarabel_status)
    for a, b in (("PrimalInfeasible", "DualInfeasible"), ("DualInfeasible", "PrimalInfeasible")):
        if s.endswith(a):
            return s[: -len(a)] + b
    return s


def _scale(Q: sp.csr_array) -> float:
    m = abs(Q).max() if Q.nnz else 1.0
    return 1.0 / m if m > 0 else 1.0


def solve_dense(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
                opts: SolverOptions) -> SDPResult:
    """One PSD cone of size N, dual form."""
    t0 = time.perf_counter()
    N = Q.shape[0]
    c = _scale(Q)
    Acl = svec_columns(As, N)
    bcl = (svec_columns([Q], N) * c).toarray().ravel()
    m = Acl.shape[1]
    P = sp.csc_matrix((m, m))
    solver = clarabel.DefaultSolver(P, -np.asarray(b, float), sp.csc_matrix(Acl), bcl,
                                    [clarabel.PSDTriangleConeT(N)], _settings(opts))
    t1 = time.perf_counter()
    sol = solver.solve()
    t2 = time.perf_counter()
    status = _sdp_status(sol.status)
    z = np.asarray(sol.z, float)
    X = smat(z, N) if z.size == svec_dim(N) and np.all(np.isfinite(z)) else None
    y = np.asarray(sol.x, float) / c
    primal = float((Q.multiply(X)).sum()) if X is not None else float("nan")
    dual = float(np.dot(b, y))
    svrs = None
    if opts.clarabel_chordal and X is not None:
        # Clarabel completes X off the pattern with some PSD completion, not the rank-d one:
        # judge rank on the clique blocks of the pattern and complete X from their factors.
        from .chordal import column_cliques

        X, svrs = complete_from_cliques(X, column_cliques(N, [Q, *As], always=range(d)), d)
    res = SDPResult(status=status, solver="clarabel-chordal" if opts.clarabel_chordal else "clarabel", d=d, X=X, y=y, primal_cost=primal, dual_cost=dual,
                    solve_time_s=t2 - t1, setup_time_s=t1 - t0, iterations=int(sol.iterations))
    res.clique_log_svr = svrs
    res = finish(res)
    if svrs:
        res.log_svr = float(np.min(svrs))
    return res


def complete_from_cliques(Xp: np.ndarray, cliques: Sequence[np.ndarray], d: int) -> tuple[np.ndarray, list[float]]:
    """X known on the cliques' pattern → per-clique log SVR, and X with the entries off the pattern
    filled from the rank-d factors of the clique blocks (each clique contains h, which fixes
    their alignment; the completion is exact when every block has rank d)."""
    from .result import log_svr, rank_d_factor

    N = Xp.shape[0]
    Theta = np.zeros((d, N))
    svrs = []
    on = np.zeros((N, N), bool)
    for C in cliques:
        w, Th = rank_d_factor(Xp[np.ix_(C, C)], d)
        svrs.append(log_svr(w, d))
        Theta[:, C] = Th
        on[np.ix_(C, C)] = True
    return np.where(on, Xp, Theta.T @ Theta), svrs


def _find(sorted_values: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index, found) of each query in an increasing array."""
    at = np.searchsorted(sorted_values, queries)
    found = (at < sorted_values.size) & (sorted_values[np.minimum(at, max(sorted_values.size - 1, 0))] == queries)
    return at, found


def _home_rows(G: sp.coo_array, cliques: Sequence[np.ndarray], pos: np.ndarray, start: list[int],
               own: np.ndarray, N: int) -> np.ndarray:
    """The cone row for every nonzero (svec entry e, constraint i) of G.

    Constraint i is placed in its home clique, the one holding most of its columns; an entry that
    the home clique lacks goes to the entry's top clique.  Any split of an entry among the cliques
    holding it is exact (the transfers balance it); this one keeps a constraint's coefficients in
    its own part of the clique tree instead of sending every shared entry (h², h·x) to the root.
    """
    gi, gj = position_to_ij(G.row)
    m = G.shape[1]
    B = incidence(cliques, N)
    cols = sp.csr_array((np.ones(2 * G.nnz), (np.r_[gi, gj], np.r_[G.col, G.col])), shape=(N, m))
    cols.data[:] = 1.0  # summed duplicates → indicator
    home = np.asarray((B @ cols).argmax(axis=0)).ravel()[G.col] if m else np.zeros(0, np.int64)
    rows = np.full(G.nnz, -1, dtype=np.int64)
    for k in np.unique(home):
        sel = np.flatnonzero(home == k)
        at, hit = _find(pos[start[k]:start[k + 1]], G.row[sel])
        rows[sel[hit]] = start[k] + at[hit]
    miss = rows < 0
    order = np.argsort(pos[own])
    rows[miss] = own[order[np.searchsorted(pos[own][order], G.row[miss])]]
    return rows


def solve_cliques(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
                  cliques: Sequence[np.ndarray], opts: SolverOptions) -> SDPResult:
    """Clique-decomposed dual (see the module docstring); X is read on the pattern from the cones'
    dual variables and completed from the clique blocks' rank-d factors."""
    t0 = time.perf_counter()
    N = Q.shape[0]
    c = _scale(Q)
    cliques = maximal(cliques)
    parent = clique_tree(cliques)  # ValueError unless the cliques form a clique tree
    m = len(As)
    # one row per (clique k, svec entry of its block); pos = the entry's position in svec of N×N
    pos, start = [], [0]
    for C in cliques:
        i, j = triu_indices(len(C))
        pos.append(C[j] * (C[j] + 1) // 2 + C[i])  # increasing, since C is sorted
        start.append(start[-1] + i.size)
    nrow = start[-1]
    # the row of the same entry in the parent's block (−1: the entry is not in the parent, k owns it)
    par_row = np.full(nrow, -1, dtype=np.int64)
    for k, pk in enumerate(parent):
        if pk >= 0:
            at, hit = _find(pos[pk], pos[k])
            par_row[start[k]:start[k + 1]][hit] = start[pk] + at[hit]
    pos = np.concatenate(pos)
    own = np.flatnonzero(par_row < 0)  # the top clique's row of each entry (one per entry)
    moved = np.flatnonzero(par_row >= 0)
    t = m + np.arange(moved.size)  # transfer variables, one per entry shared with the parent
    data = svec_columns([Q, *As], N).tocsr()  # column 0: Q
    outside = np.setdiff1d(np.unique(data.nonzero()[0]), pos)
    if outside.size:
        raise ValueError(f"{outside.size} entries of the cost or constraints lie outside every clique")
    G = sp.coo_array(data[:, 1:])
    g_row = _home_rows(G, cliques, pos, start, own, N)
    A = sp.csc_matrix((np.concatenate([G.data, np.ones(moved.size), -np.ones(moved.size)]),
                       (np.concatenate([g_row, moved, par_row[moved]]), np.concatenate([G.col, t, t]))),
                      shape=(nrow, m + moved.size))
    bcl = np.zeros(nrow)
    bcl[own] = data[pos[own]][:, [0]].toarray().ravel() * c
    obj = np.concatenate([-np.asarray(b, float), np.zeros(moved.size)])
    cones = [clarabel.PSDTriangleConeT(len(C)) for C in cliques]
    # the cones are the cliques already: Clarabel's own decomposition stays off
    solver = clarabel.DefaultSolver(sp.csc_matrix((obj.size, obj.size)), obj, A, bcl, cones,
                                    _settings(replace(opts, clarabel_chordal=False)))
    t1 = time.perf_counter()
    sol = solver.solve()
    t2 = time.perf_counter()
    z = np.asarray(sol.z, float)
    y = np.asarray(sol.x, float)[:m] / c
    X, svrs = None, []
    if z.size == nrow and np.all(np.isfinite(z)):
        gi, gj = position_to_ij(pos)
        v = np.where(gi == gj, z, z / SQRT2)
        Xp = np.zeros((N, N))
        Xp[gi, gj] = v
        Xp[gj, gi] = v
        X, svrs = complete_from_cliques(Xp, cliques, d)
    primal = float(Q.multiply(X).sum()) if X is not None else float("nan")
    status = _sdp_status(sol.status)
    res = SDPResult(status=status, solver="clarabel-cliques", d=d, X=X, y=y, primal_cost=primal,
                    dual_cost=float(np.dot(b, y)), solve_time_s=t2 - t1, setup_time_s=t1 - t0,
                    iterations=int(sol.iterations), clique_log_svr=svrs or None)
    res = finish(res)
    if svrs:
        res.log_svr = float(np.min(svrs))
    return res
