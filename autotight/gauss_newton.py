"""Gauss-Newton with Levenberg-Marquardt damping on a manifold, for the problems' local solvers.

The problem supplies ``linearize(state) -> (e, J, W)``: the stacked residual e (m,), its
Jacobian J (m×p, dense or scipy.sparse) with respect to a perturbation ε ∈ R^p, and the
weight W (m×m, dense or sparse), so that cost = eᵀWe; and ``retract(state, ε) -> state``.
Each step solves (JᵀWJ + λ diag(JᵀWJ)) ε = −JᵀWe; λ shrinks after a cost decrease and grows
after an increase, so the cost never goes up.  A step is rejected (and λ grown) when the system
is singular, the step is not finite, the new cost is not finite, or the step lands on a Cayley
singularity; any other exception from ``linearize`` or ``retract`` is a bug and propagates.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import block_diag, solveh_banded

from .lie import CayleySingularityError
from .problem import LocalResult


#: a sparse system whose half bandwidth b has (b + 1)·n ≤ this many band entries and b ≤ n / BAND_FRACTION is
#: solved by banded Cholesky (LAPACK pbsv: O(n b²)) instead of SuperLU; discrete trajectory K = 1000
#: (n = 6000, b = 11): the chain's block-tridiagonal normal equations
BAND_MAX_ENTRIES = 50_000_000
BAND_FRACTION = 8


def half_bandwidth(H: sp.sparray) -> int:
    """max |i − j| over the stored entries of a sparse matrix."""
    C = sp.coo_array(H)
    return int(np.abs(C.row.astype(np.int64) - C.col).max(initial=0))


def solve_banded_spd(H: sp.sparray, g: np.ndarray, b: int) -> np.ndarray:
    """H x = g for a symmetric positive definite sparse H of half bandwidth b, by banded Cholesky; raises
    np.linalg.LinAlgError when H is not positive definite."""
    C = sp.coo_array(H)
    low = C.row >= C.col
    ab = np.zeros((b + 1, H.shape[0]))
    np.add.at(ab, ((C.row[low] - C.col[low]), C.col[low]), C.data[low])
    return solveh_banded(ab, g, lower=True, check_finite=False)


def _solve(Hm: Any, g: np.ndarray, band: int | None = None) -> np.ndarray:
    """Hm ε = g; ``band``: Hm's half bandwidth when the banded Cholesky applies (``half_bandwidth``)."""
    if sp.issparse(Hm):
        if band is not None:
            return solve_banded_spd(Hm, g, band)
        return spla.spsolve(sp.csc_array(Hm), g)
    return np.linalg.solve(Hm, g)


def _band(Hm: Any) -> int | None:
    if not sp.issparse(Hm):
        return None
    n, b = Hm.shape[0], half_bandwidth(Hm)
    return b if (b + 1) * n <= BAND_MAX_ENTRIES and b * BAND_FRACTION <= n else None


def gauss_newton(linearize: Callable[[Any], tuple[np.ndarray, Any, Any]], retract: Callable[[Any, np.ndarray], Any],
                 state: Any, max_iter: int = 200, rel_tol: float = 1e-12, lam0: float = 0.0) -> LocalResult:
    """Minimise eᵀWe from ``state``.  Converged when the relative cost decrease is below rel_tol."""
    t0 = time.perf_counter()
    e, J, W = linearize(state)
    f = float(e @ (W @ e))
    lam, it, converged, msg = lam0, 0, False, "max_iter reached"
    for it in range(1, max_iter + 1):
        JW = J.T @ W
        Hm = JW @ J
        band = _band(Hm)
        g = JW @ e
        diag = Hm.diagonal() if sp.issparse(Hm) else np.diag(Hm)
        accepted = False
        for _ in range(40):
            Hd = Hm + sp.diags(lam * np.maximum(diag, 1e-12)) if sp.issparse(Hm) else \
                Hm + np.diag(lam * np.maximum(diag, 1e-12))
            f2 = np.inf
            try:
                eps = -_solve(Hd, g, band)
                if np.all(np.isfinite(eps)):
                    cand = retract(state, eps)
                    e2, J2, W2 = linearize(cand)
                    f2 = float(e2 @ (W2 @ e2))
            except (CayleySingularityError, np.linalg.LinAlgError):
                pass  # a singular system, or a step onto a Cayley singularity: damp more
            if np.isfinite(f2) and f2 <= f:
                accepted = True
                break
            lam = max(1e-6, lam * 10 if lam > 0 else 1e-4)
        if not accepted:
            converged, msg = True, "no decrease possible (stationary within precision)"
            break
        decrease = f - f2
        state, e, J, W, f = cand, e2, J2, W2, f2
        lam = lam / 10 if lam > 1e-9 else 0.0
        if decrease <= rel_tol * max(f, 1e-300) or np.linalg.norm(eps) < 1e-14:
            converged, msg = True, "converged"
            break
    return LocalResult(state, f, it, converged, time.perf_counter() - t0, msg)


#: up to this many rows the block-diagonal weight is dense (as it always was): the products are cheap
#: and the local solutions of the committed reports (pose averaging M = 10, robust M = 6) stay the
#: same to the last bit; above, sparse (M = 1000: a dense weight was 288 MB)
DENSE_WEIGHT_MAX = 600


def block_sparse(brow: np.ndarray, bcol: np.ndarray, blocks: np.ndarray, shape: tuple[int, int]) -> sp.csr_array:
    """The sparse matrix of ``shape`` holding the (d × e) ``blocks[k]`` at block row brow[k] and block
    column bcol[k] (entries at rows d·brow[k] + i, columns e·bcol[k] + j)."""
    _, d, e = blocks.shape
    i, j = np.meshgrid(np.arange(d), np.arange(e), indexing="ij")
    return sp.csr_array((blocks.ravel(), ((d * np.asarray(brow)[:, None, None] + i).ravel(),
                                          (e * np.asarray(bcol)[:, None, None] + j).ravel())), shape=shape)


def block_weight(blocks: np.ndarray, dense_max: int = DENSE_WEIGHT_MAX) -> np.ndarray | sp.csr_array:
    """The block-diagonal weight (Bd × Bd) of stacked residuals from their (B, d, d) blocks: dense up to
    ``dense_max`` rows, else sparse."""
    B, d, _ = blocks.shape
    if B * d <= dense_max:
        return block_diag(*blocks) if B else np.zeros((0, 0))
    return block_sparse(np.arange(B), np.arange(B), blocks, (B * d, B * d))
