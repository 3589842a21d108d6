"""Certify a local solution x̂ without solving the full SDP.

x̂ (lifted: Θ̂, d×N) is globally optimal for the relaxation iff some y gives H(y) = Q − Σ yᵢAᵢ ⪰ 0 with
H(y)Θ̂ᵀ = 0.  With redundant constraints such y are not unique, so finding one is a convex problem; ours:

1. Least squares.  y₀ = argmin ‖H(y)Θ̂ᵀ‖ (sparse LSQR on the N·d × m system Σ yᵢAᵢΘ̂ᵀ = QΘ̂ᵀ).  When every
   clique block of H(y₀) is PSD (a necessary test, dense and cheap) and the full certificate below holds,
   we are done.
2. A margin program on the clique tree.  By Agler's theorem every H ⪰ 0 with the chordal pattern is
   Σ_k E_kᵀ S_k E_k with S_k ⪰ 0, and Θ̂ H Θ̂ᵀ = 0 forces S_k Θ̂_kᵀ = 0 in every clique.  With Π_k the
   projector onto the complement of Θ̂_k's rows we solve

       max λ  s.t.  ‖(S_k(y, t) Θ̂_kᵀ)_k‖ ≤ ε,  S_k(y, t) ⪰ λ Π_k,  λ ≤ cap,

   over y, the clique program's transfers t (``sdp.clique_program``) and λ, with Clarabel.  ε (10× the
   least-squares residual of step 1) replaces "= 0": x̂ is stationary only to its local solver's
   accuracy, and the exact system is then inconsistent.  The program is strictly feasible whenever the
   relaxation is tight with a margin; no X is completed or factored.  It is as large as the full SDP's
   dual (same cones, plus one second-order cone), so it is not much cheaper to solve (see
   benchmarks/certify.py).
3. Polish and check.  y is moved onto {y : H(y)Θ̂ᵀ = 0} (LSQR on the residual) and the certificate of
   ``autotight.certificate`` (sparse λ_min(H), trace bound, suboptimality bound) decides.

A λ* clearly below 0 means no certificate exists for x̂ (it is not a global minimiser of a tight
relaxation); the returned Certificate then carries the bound that the best y found still proves.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .certificate import Certificate, certificate, stack
from .model import Constraint, Model
from .svec import SQRT2, triu_indices


def stationarity_system(Q: sp.sparray, As: Sequence[sp.sparray], Th: np.ndarray) -> tuple[sp.csr_array, np.ndarray]:
    """(G, g) with G y = g ⟺ H(y)Θ̂ᵀ = 0: column i of G is vec(AᵢΘ̂ᵀ) (N·d rows)."""
    cols = [sp.csc_array((A @ Th.T).reshape(-1, 1)) for A in As]
    return sp.hstack(cols, format="csr"), np.asarray(Q @ Th.T).ravel()


def _lsqr(G: sp.csr_array, r: np.ndarray) -> np.ndarray:
    from scipy.sparse.linalg import lsqr

    return lsqr(G, r, atol=1e-15, btol=1e-15, iter_lim=20 * G.shape[1])[0]


def _svec_to_vec(n: int) -> sp.csr_array:
    """D (n² × svec(n)) with vec(S) = D svec(S) (row-major vec of the symmetric S)."""
    i, j = triu_indices(n)
    p = np.arange(i.size)
    off = i != j
    rows = np.concatenate([i * n + j, (j * n + i)[off]])
    cols = np.concatenate([p, p[off]])
    vals = np.concatenate([np.where(off, 1 / SQRT2, 1.0), np.full(off.sum(), 1 / SQRT2)])
    return sp.csr_array((vals, (rows, cols)), shape=(n * n, i.size))


def _vec_to_svec(n: int) -> sp.csr_array:
    """svec(S) = E vec(S) for a symmetric S."""
    i, j = triu_indices(n)
    return sp.csr_array((np.where(i == j, 1.0, SQRT2), (np.arange(i.size), i * n + j)), shape=(i.size, n * n))


def clique_blocks_psd(H: sp.sparray, cliques: Sequence[np.ndarray], tol: float) -> bool:
    """Every principal clique block of H has λ_min ≥ −tol (necessary for H ⪰ 0)."""
    H = sp.csr_array(H)
    return all(np.linalg.eigvalsh(H[C][:, C].toarray())[0] >= -tol for C in cliques)


def _margin_program(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, Th: np.ndarray,
                    cliques: Sequence[np.ndarray], tol: float, max_iter: int, cap: float, eps: float
                    ) -> tuple[np.ndarray | None, float, str, int]:
    """Step 2 of the module docstring: (y or None, λ* (scaled by 1/max|Q|), Clarabel status, iterations)."""
    import clarabel

    from .sdp.clique_program import clique_program

    prog = clique_program(Q, As, b, cliques)
    F = sp.csr_array(prog.F)
    nx = F.shape[1] + 1  # [y; t; λ]
    zero_A, zero_b, margin, cones_psd = [], [], [], []
    for k, C in enumerate(prog.cliques):
        n = len(C)
        rows = slice(prog.start[k], prog.start[k + 1])
        Tk = Th[:, C]  # d × n
        Mk = sp.csr_array(sp.kron(sp.identity(n), sp.csr_array(Tk)) @ _svec_to_vec(n))  # svec(S) → vec(S Θ̂ᵀ)
        zero_A.append(Mk @ F[rows])
        zero_b.append(Mk @ prog.c[rows])
        U = np.linalg.svd(Tk.T, full_matrices=True)[0][:, np.linalg.matrix_rank(Tk):]
        margin.append(_vec_to_svec(n) @ (U @ U.T).ravel())  # svec of the projector onto Θ̂_k's complement
        cones_psd.append(clarabel.PSDTriangleConeT(n))
    # s = c − F[y; t] − λ·svec(Π_k) ∈ PSD per clique: S_k ⪰ λΠ_k, with S_kΘ̂_kᵀ = 0 ⟺ P_kᵀS_kP_k ⪰ λI
    psd_A = sp.hstack([F, sp.csr_array(np.concatenate(margin)[:, None])])
    psd_b = [prog.c]
    zero_A = [sp.hstack([sp.vstack(zero_A), sp.csr_array((sum(z.shape[0] for z in zero_b), 1))])]
    psd_A = [psd_A]
    cap_row = sp.csr_array(([1.0], ([0], [nx - 1])), shape=(1, nx))
    # ‖S_kΘ̂_kᵀ‖ ≤ eps (all k) rather than = 0: x̂ is stationary only to its local solver's accuracy
    Z = zero_A[0]
    A = sp.vstack([cap_row, sp.csr_array((1, nx)), Z] + psd_A, format="csc")
    bb = np.concatenate([[cap, eps * prog.scale]] + zero_b + psd_b)
    cones = [clarabel.NonnegativeConeT(1), clarabel.SecondOrderConeT(Z.shape[0] + 1)] + cones_psd
    q = np.zeros(nx)
    q[-1] = -1.0
    s = clarabel.DefaultSettings()
    s.verbose = False
    s.max_iter = max_iter
    s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = tol
    s.tol_ktratio = max(tol, 1e-8)
    s.max_threads = 1
    s.chordal_decomposition_enable = False
    sol = clarabel.DefaultSolver(sp.csc_matrix((nx, nx)), q, sp.csc_matrix(A), bb, cones, s).solve()
    x = np.asarray(sol.x, float)
    if x.size != nx or not np.all(np.isfinite(x)):
        return None, -np.inf, str(sol.status), int(sol.iterations)
    return x[:prog.m] / prog.scale, float(x[-1]), str(sol.status), int(sol.iterations)


def default_cliques(Q: sp.sparray, As: Sequence[sp.sparray], d: int) -> list[np.ndarray]:
    """A chordal clique cover of the data's pattern (h in every clique), as the SDP layer builds it."""
    from .sdp.chordal import column_cliques, merge_small

    return merge_small(column_cliques(Q.shape[0], [Q, *As], always=range(d)), 20)


def certify(Q: sp.sparray, constraints: Sequence[Constraint], theta_hat: np.ndarray, *, d: int = 1,
            cliques: Sequence[np.ndarray] | None = None, tol: float = 1e-5, solver_tol: float = 1e-8,
            max_iter: int = 100, trace: float | None = None) -> Certificate:
    """Certify x̂ (Θ̂ = ``theta_hat``) for min ⟨Q,X⟩ s.t. ``constraints``, X ⪰ 0 (module docstring).

    certified: the certified suboptimality bound f(x̂) − p* is ≤ tol relative to f(x̂)
    (``certificate.certificate``; the default is ``Criteria.gap_tol``, so that certify and the bracket
    test of a full SDP decide with the same relative gap).  cliques: a chordal cover containing the pattern of Q and every Aᵢ,
    each with the h columns (default: ``default_cliques``).  solver_tol: Clarabel's tolerance for the
    margin program (its y is polished and checked exactly afterwards, so it need not be tight).
    trace: a known bound on tr(X) (default: derived from the constraints).
    """
    t0 = time.perf_counter()
    Q = sp.csr_array(Q)
    As, b = stack(constraints)
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    G, g = stationarity_system(Q, As, Th)
    y0 = _lsqr(G, g)
    if cliques is None:
        cliques = default_cliques(Q, As, d)
    cliques = [np.asarray(C) for C in cliques]
    from .certificate import dual_matrix

    qscale = float(abs(Q).max()) if Q.nnz else 1.0
    if clique_blocks_psd(dual_matrix(Q, As, y0), cliques, 1e-12 * qscale):
        cert = certificate(Q, constraints, y0, Th, d=d, tol=tol, trace=trace, method="least squares")
        if cert.certified:
            return replace(cert, time_s=time.perf_counter() - t0)
    y, lam, status, iters = _margin_program(Q, As, b, Th, cliques, solver_tol, max_iter, cap=1e-3,
                                             eps=10 * float(np.linalg.norm(G @ y0 - g)) + 1e-9 * qscale * float(np.linalg.norm(Th)))
    if y is None:
        y = y0
    y = y + _lsqr(G, g - G @ y)  # onto H(y)Θ̂ᵀ = 0
    cert = certificate(Q, constraints, y, Th, d=d, tol=tol, trace=trace,
                       method=f"clique margin program (Clarabel {status}, {iters} it, margin {lam:.2e})")
    return replace(cert, time_s=time.perf_counter() - t0)


def certify_model(model: Model, constraints: Sequence[Constraint], theta_hat: np.ndarray, *,
                  cliques: Sequence[np.ndarray] | None = None, **kw) -> Certificate:
    """``certify`` on a model's cost, with the clique cover the SDP layer would choose for Clarabel."""
    if cliques is None:
        from .sdp import model_cover

        cliques = model_cover(model, constraints, "clarabel")
    return certify(model.Q, constraints, theta_hat, d=model.d, cliques=cliques, **kw)
