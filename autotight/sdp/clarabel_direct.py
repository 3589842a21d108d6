"""Clarabel called directly with sparse data.

Dense cone (one PSD block), dual form:
    max bᵀy  s.t.  s = Q − Σ yᵢ Aᵢ ∈ PSD,
i.e. Clarabel's  min −bᵀy  s.t.  [svec A₁ … svec A_m] y + s = svec Q,  s ∈ PSDTriangleConeT(N).
The cone's dual variable z is svec(X) of the primal  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

Clique form (chordal aggregate sparsity, cliques given): primal over the entries of X on the
pattern covered by the cliques,
    min ⟨Q,X⟩  s.t.  ⟨Aᵢ,X⟩ = bᵢ  (zero cone),  X[C_k, C_k] ∈ PSD  for every clique C_k.
When the cliques are those of a chordal pattern that contains every Q and Aᵢ, this has the
same optimal value as the dense SDP (Grone's completion theorem).
"""

from __future__ import annotations

import time
from typing import Sequence

import clarabel
import numpy as np
import scipy.sparse as sp

from ..svec import SQRT2, smat, svec_columns, svec_dim
from .chordal import has_running_intersection, maximal
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
    # Tight relaxations have rank-deficient PSD blocks; the default static regularisation (1e-8)
    # then limits accuracy (AlmostSolved, costs ~1e-5 off).  A smaller one solves them to tol.
    s.static_regularization_constant = 1e-10
    s.static_regularization_proportional = 1e-16
    s.dynamic_regularization_enable = False
    # Clarabel decomposes by default; "dense" must mean dense, so it is on only when asked for
    s.chordal_decomposition_enable = opts.clarabel_chordal
    if opts.clarabel_chordal:
        s.chordal_decomposition_complete_dual = True
        s.chordal_decomposition_merge_method = opts.chordal_merge
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
    # Clarabel solved the SDP's dual: its "primal infeasible" is our dual infeasible and vice versa
    status = {"PrimalInfeasible": "DualInfeasible", "DualInfeasible": "PrimalInfeasible",
              "AlmostPrimalInfeasible": "AlmostDualInfeasible",
              "AlmostDualInfeasible": "AlmostPrimalInfeasible"}.get(str(sol.status), str(sol.status))
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


def _pattern_index(N: int, cliques: Sequence[np.ndarray]) -> dict[tuple[int, int], int]:
    idx: dict[tuple[int, int], int] = {}
    for C in cliques:
        C = np.sort(C)
        for jj in range(len(C)):
            for ii in range(jj + 1):
                idx.setdefault((int(C[ii]), int(C[jj])), len(idx))
    return idx


def solve_cliques(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
                  cliques: Sequence[np.ndarray], opts: SolverOptions) -> SDPResult:
    """Clique-decomposed primal; X is assembled on the pattern and completed from clique factors."""
    t0 = time.perf_counter()
    N = Q.shape[0]
    c = _scale(Q)
    cliques = maximal(cliques)
    if not has_running_intersection(cliques):
        raise ValueError("the cliques do not form a clique tree (running intersection fails): "
                         "the decomposed SDP would be weaker than the dense one")
    idx = _pattern_index(N, cliques)
    nv = len(idx)

    def entry_row(A: sp.csr_array) -> tuple[np.ndarray, np.ndarray]:
        U = sp.triu(sp.coo_array(A)).tocoo()
        cols, vals = [], []
        for r, cc, v in zip(U.row, U.col, U.data):
            key = (int(r), int(cc))
            if key not in idx:
                raise ValueError(f"entry {key} of a constraint/cost lies outside every clique")
            cols.append(idx[key])
            vals.append(v if r == cc else 2.0 * v)
        return np.asarray(cols, np.int64), np.asarray(vals)

    qc, qv = entry_row(Q)
    q = np.zeros(nv)
    np.add.at(q, qc, qv * c)
    rows, cols, vals = [], [], []
    for i, A in enumerate(As):
        ac, av = entry_row(A)
        rows.append(np.full(ac.size, i)); cols.append(ac); vals.append(av)
    m = len(As)
    off = m
    cones: list = [clarabel.ZeroConeT(m)] if m else []
    for C in cliques:
        n = len(C)
        jj, ii = np.tril_indices(n)
        keys = [idx[(int(C[a]), int(C[bb]))] for a, bb in zip(ii, jj)]
        rows.append(off + np.arange(len(keys)))
        cols.append(np.asarray(keys, np.int64))
        vals.append(-np.where(ii == jj, 1.0, SQRT2))
        off += len(keys)
        cones.append(clarabel.PSDTriangleConeT(n))
    Acl = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(off, nv))
    bcl = np.zeros(off)
    bcl[:m] = b
    P = sp.csc_matrix((nv, nv))
    solver = clarabel.DefaultSolver(P, q, Acl, bcl, cones, _settings(opts))
    t1 = time.perf_counter()
    sol = solver.solve()
    t2 = time.perf_counter()
    xv = np.asarray(sol.x, float)
    y = -np.asarray(sol.z, float)[:m] / c
    status = str(sol.status)
    X, svrs = None, []
    if np.all(np.isfinite(xv)):
        Xp = np.zeros((N, N))
        for (i, j), k in idx.items():
            Xp[i, j] = Xp[j, i] = xv[k]
        X, svrs = complete_from_cliques(Xp, cliques, d)
    primal = float(np.dot(q, xv) / c) if np.all(np.isfinite(xv)) else float("nan")
    res = SDPResult(status=status, solver="clarabel-cliques", d=d, X=X, y=y, primal_cost=primal,
                    dual_cost=float(np.dot(b, y)), solve_time_s=t2 - t1, setup_time_s=t1 - t0,
                    iterations=int(sol.iterations), clique_log_svr=svrs or None)
    res = finish(res)
    if svrs:
        res.log_svr = float(np.min(svrs))
    return res
