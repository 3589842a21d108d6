"""Minimum-norm least squares, min ‖x‖ over argmin ‖G x − r‖, for sparse G with chain-like sparsity.

LSQR needs iterations in proportion to G's condition, which grows with the length of a trajectory:
polishing the dual of discrete K = 300 took 26 000 LSQR iterations (6.5 s), K = 1000 most of a minute.
Here one sparse LDLᵀ (``ldl.SymmetricLDL``) does it (linear in K on a chain): proximal-point steps

    x ← x + e,  e = argmin ‖G e − (r − G x)‖² + μ‖e‖² = Gᵀ(GGᵀ + μI)⁻¹(r − G x),

each a solve with the quasi-definite matrix [[I, Gᵀ], [G, −μI]] (e = −Gᵀλ from its second block, so every
x stays in range(Gᵀ), as the minimum-norm solution does).  The steps converge to that solution: a
component along a singular value σ of G shrinks by μ/(σ² + μ) per step, so one step settles every σ² ≫ μ.
μ = ``MU_REL``·‖G‖_F²/rows (a relative size with that meaning: the mean squared row norm).  Measured
against a dense ``numpy.linalg.lstsq`` (discrete K = 30, pose averaging M = 30, continuous time): 3e-9
relative after a few steps; against LSQR at discrete K = 300: 3e-8 relative in 0.07 s instead of 5 s.
Below ``LSQR_MAX_COLUMNS`` columns LSQR is kept: it converges there in a few hundred iterations and to
roundoff (discrete K = 30: 183 iterations, 1e-13 against the dense solve), and every committed report's
instances are that small, so their numbers do not move.  If the factorisation fails, LSQR does the work.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .ldl import SymmetricLDL

LSQR_MAX_COLUMNS = 4000  # LSQR up to this many columns (module docstring)
MU_REL = 1e-8  # μ relative to ‖G‖_F²/rows (module docstring)
MAX_STEPS = 30  # proximal steps at most
STEP_RTOL = 1e-14  # stop once a step changes x by less than this, relative to ‖x‖ …
CONTRACTION = 0.5  # … or is more than this fraction of the step before it


def min_norm_lstsq(G: sp.sparray, r: np.ndarray, *, atol: float = 1e-14) -> np.ndarray:
    """The minimum-norm least-squares solution of G x = r (G: rows × m sparse, r: (rows,)), x: (m,).

    ``atol``: LSQR's atol and btol when it is the fallback (module docstring)."""
    G = sp.csr_array(G)
    r = np.asarray(r, dtype=float)
    n, m = G.shape
    if n == 0 or m == 0 or G.nnz == 0:
        return np.zeros(m)
    if m <= LSQR_MAX_COLUMNS:
        return _lsqr(G, r, atol)
    mu = MU_REL * float(np.sum(G.data ** 2)) / n
    try:
        kkt = sp.bmat([[sp.identity(m, format="csc"), G.T], [G, -mu * sp.identity(n, format="csc")]],
                      format="csc")
        lu = SymmetricLDL(kkt)  # quasi-definite: an LDLᵀ exists under any symmetric ordering
    except RuntimeError:  # exactly singular factor: LSQR as before
        return _lsqr(G, r, atol)
    x = np.zeros(m)
    rhs = np.zeros(m + n)
    last = np.inf
    for _ in range(MAX_STEPS):
        rhs[m:] = r - G @ x
        sol = lu.solve(rhs)
        sol += lu.solve(rhs - kkt @ sol)  # one refinement step: the LDLᵀ does not pivot
        step = -(G.T @ sol[m:])
        if not np.all(np.isfinite(step)):
            return _lsqr(G, r, atol)
        x += step
        size = float(np.linalg.norm(step))
        # converged, or no longer contracting: at roundoff, or only components with σ² ≲ μ left
        if size <= STEP_RTOL * np.linalg.norm(x) or size > CONTRACTION * last:
            break
        last = size
    return x


def equilibrated_lstsq(G: sp.sparray, r: np.ndarray, *, atol: float = 1e-14) -> np.ndarray:
    """A least-squares solution of G x = r: ``min_norm_lstsq`` in the variables z = C x, C = diag(G's column
    norms) (a zero column keeps weight 1), so x has the least ‖C x‖ among the least-squares solutions.
    Where G's columns differ in norm by orders (multipliers of constraints on entries of very different
    size), the steps of ``min_norm_lstsq`` leave the components of small singular value unsettled in
    the plain metric; equilibrated columns bring those singular values up to the rest."""
    G = sp.csr_array(G)
    norms = np.sqrt(np.asarray(G.multiply(G).sum(axis=0)).ravel())
    norms[norms == 0] = 1.0
    return min_norm_lstsq(sp.csr_array(G @ sp.diags_array(1.0 / norms)), r, atol=atol) / norms


def _lsqr(G: sp.csr_array, r: np.ndarray, atol: float) -> np.ndarray:
    return spla.lsqr(G, r, atol=atol, btol=atol, iter_lim=10 * G.shape[1])[0]
