"""Gauss-Newton with Levenberg-Marquardt damping on a manifold, for the problems' local solvers.

The problem supplies ``linearize(state) -> (e, J, W)``: the stacked residual e (m,), its
Jacobian J (m×p, dense, scipy.sparse, or a ``BlockJacobian`` whose normal equations are formed block by
block) with respect to a perturbation ε ∈ R^p, and the weight W (m×m, dense or sparse), so that
cost = eᵀWe; and ``retract(state, ε) -> state``.
Each step solves (JᵀWJ + λ diag(JᵀWJ)) ε = −JᵀWe; λ shrinks after a cost decrease and grows
after an increase, so the cost never goes up.  A step is rejected (and λ grown) when the system
is singular, the step is not finite, the new cost is not finite, or the step lands on a Cayley
singularity; any other exception from ``linearize`` or ``retract`` is a bug and propagates.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
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


def lower_band(H: sp.sparray, b: int) -> np.ndarray:
    """The lower band storage ab (b + 1, n) of a symmetric sparse H of half bandwidth b: ab[i − j, j] = H_ij."""
    C = sp.coo_array(H)
    low = C.row >= C.col
    ab = np.zeros((b + 1, H.shape[0]))
    np.add.at(ab, ((C.row[low] - C.col[low]), C.col[low]), C.data[low])
    return ab


def solve_banded_spd(H: sp.sparray, g: np.ndarray, b: int) -> np.ndarray:
    """H x = g for a symmetric positive definite sparse H of half bandwidth b, by banded Cholesky; raises
    np.linalg.LinAlgError when H is not positive definite."""
    return solveh_banded(lower_band(H, b), g, lower=True, check_finite=False)


def _solve(Hm: Any, g: np.ndarray) -> np.ndarray:
    """Hm ε = g (sparse by SuperLU, dense by LAPACK); a singular Hm raises np.linalg.LinAlgError either way
    (SuperLU's warning, which would reach the user's terminal, becomes the error)."""
    if sp.issparse(Hm):
        with warnings.catch_warnings():
            warnings.simplefilter("error", spla.MatrixRankWarning)
            try:
                return spla.spsolve(sp.csc_array(Hm), g)
            except spla.MatrixRankWarning as e:
                raise np.linalg.LinAlgError(str(e)) from None
    return np.linalg.solve(Hm, g)


def _band(Hm: Any) -> int | None:
    if not sp.issparse(Hm):
        return None
    n, b = Hm.shape[0], half_bandwidth(Hm)
    return b if (b + 1) * n <= BAND_MAX_ENTRIES and b * BAND_FRACTION <= n else None


class BlockPattern:
    """Where the (d × e) blocks of a block Jacobian sit (blocks[q] at block row brow[q], block column bcol[q];
    shape (R·d, C·e)) and, computed once, where each e × e product J_pᵀ W J_q of two blocks in one residual
    row goes in the normal equations: lower band storage (``lower_band``) when the half bandwidth is within
    ``BAND_MAX_ENTRIES`` and n / ``BAND_FRACTION``, else a sparse matrix."""

    def __init__(self, brow: np.ndarray, bcol: np.ndarray, d: int, e: int, shape: tuple[int, int]):
        self.brow, self.bcol = np.asarray(brow, np.int64), np.asarray(bcol, np.int64)
        self.d, self.e, self.shape = d, e, shape
        n = self.n = shape[1]
        order = np.argsort(self.brow, kind="stable")
        _, start, count = np.unique(self.brow[order], return_index=True, return_counts=True)
        pp, qq = [], []
        for c in np.unique(count):  # every ordered pair of blocks in one residual row
            st = start[count == c]
            pp.append(np.broadcast_to(st[:, None, None] + np.arange(c)[None, :, None], (st.size, c, c)).ravel())
            qq.append(np.broadcast_to(st[:, None, None] + np.arange(c)[None, None, :], (st.size, c, c)).ravel())
        self.p, self.q = order[np.concatenate(pp)], order[np.concatenate(qq)]
        shp = (self.p.size, e, e)
        r = np.broadcast_to((e * self.bcol[self.p])[:, None, None] + np.arange(e)[None, :, None], shp).ravel()
        c_ = np.broadcast_to((e * self.bcol[self.q])[:, None, None] + np.arange(e)[None, None, :], shp).ravel()
        self.g_index = ((e * self.bcol)[:, None] + np.arange(e)[None, :]).ravel()  # rows of Jᵀ(We) per block
        self.diag = np.flatnonzero(r == c_)
        self.diag_at = r[self.diag]
        self.b = int(e * np.abs(self.bcol[self.p] - self.bcol[self.q]).max(initial=0) + e - 1)
        self.banded = (self.b + 1) * n <= BAND_MAX_ENTRIES and self.b * BAND_FRACTION <= n
        if self.banded:
            self.low = np.flatnonzero(r >= c_)
            self.band_at = c_[self.low] * (self.b + 1) + (r[self.low] - c_[self.low])  # column-major (b + 1) × n
        else:
            self.rows, self.cols = r, c_


@dataclass(frozen=True)
class BlockJacobian:
    """A Jacobian of (d × e) blocks (nb, d, e) on a ``BlockPattern`` with a block-diagonal weight
    (weights[R] (R, d, d): the weight of residual block R), which ``gauss_newton`` turns into the normal
    equations by e × e products instead of sparse matrix products.  ``matrix()`` is the same Jacobian as a
    sparse array (``block_sparse``)."""

    pattern: BlockPattern
    blocks: np.ndarray
    weights: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    def matrix(self) -> sp.csr_array:
        P = self.pattern
        return block_sparse(P.brow, P.bcol, self.blocks, P.shape)

    def normal(self, e: np.ndarray) -> tuple[sp.csr_array | None, np.ndarray | None, np.ndarray, np.ndarray]:
        """(H, ab, g, diag): H = JᵀWJ as a sparse array, or None when the pattern is banded and its lower band
        storage ab is given instead; g = JᵀWe; diag = diag(H)."""
        P, Jb = self.pattern, self.blocks
        We = np.einsum("rij,rj->ri", self.weights, e.reshape(-1, P.d))
        WJ = self.weights[P.brow] @ Jb  # (nb, d, e)
        g = np.bincount(P.g_index, weights=np.einsum("qde,qd->qe", Jb, We[P.brow]).ravel(), minlength=P.n)
        vals = (np.swapaxes(Jb[P.p], 1, 2) @ WJ[P.q]).ravel()  # J_pᵀ W J_q, (pairs · e²)
        diag = np.bincount(P.diag_at, weights=vals[P.diag], minlength=P.n)
        if P.banded:
            flat = np.bincount(P.band_at, weights=vals[P.low], minlength=(P.b + 1) * P.n)
            return None, flat.reshape(P.n, P.b + 1).T.copy(), g, diag
        H = sp.csr_array((vals, (P.rows, P.cols)), shape=(P.n, P.n))
        H.sum_duplicates()
        return H, None, g, diag


def gauss_newton(linearize: Callable[[Any], tuple[np.ndarray, Any, Any]], retract: Callable[[Any, np.ndarray], Any],
                 state: Any, max_iter: int = 200, rel_tol: float = 1e-12, lam0: float = 0.0) -> LocalResult:
    """Minimise eᵀWe from ``state``.  Converged when the relative cost decrease is below rel_tol."""
    t0 = time.perf_counter()
    e, J, W = linearize(state)
    f = float(e @ (W @ e))
    lam, it, converged, msg = lam0, 0, False, "max_iter reached"
    for it in range(1, max_iter + 1):
        if isinstance(J, BlockJacobian):
            Hm, ab, g, diag = J.normal(e)
        else:
            JW = J.T @ W
            Hm = JW @ J
            band = _band(Hm)
            ab = lower_band(Hm, band) if band is not None else None  # once per linearisation, damped per try
            g = JW @ e
            diag = Hm.diagonal() if sp.issparse(Hm) else np.diag(Hm)
        accepted = False
        for _ in range(40):
            f2 = np.inf
            try:
                if ab is not None:
                    abd = ab.copy()
                    abd[0] += lam * np.maximum(diag, 1e-12)
                    eps = -solveh_banded(abd, g, lower=True, check_finite=False)
                else:
                    Hd = Hm + sp.diags(lam * np.maximum(diag, 1e-12)) if sp.issparse(Hm) else \
                        Hm + np.diag(lam * np.maximum(diag, 1e-12))
                    eps = -_solve(Hd, g)
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
    column bcol[k] (entries at rows d·brow[k] + i, columns e·bcol[k] + j; blocks at the same place add).
    Built in CSR order directly (no COO → CSR conversion) when no two blocks share a place."""
    nb, d, e = blocks.shape
    brow, bcol = np.asarray(brow, np.int64), np.asarray(bcol, np.int64)
    order = np.lexsort((bcol, brow))
    br, bc = brow[order], bcol[order]
    if nb and (shape[0] % d or np.any((br[1:] == br[:-1]) & (bc[1:] == bc[:-1]))):
        i, j = np.meshgrid(np.arange(d), np.arange(e), indexing="ij")
        return sp.csr_array((blocks.ravel(), ((d * brow[:, None, None] + i).ravel(),
                                              (e * bcol[:, None, None] + j).ravel())), shape=shape)
    nbr = shape[0] // d
    count = np.bincount(br, minlength=nbr)  # blocks per block row
    first = np.concatenate([[0], np.cumsum(count)])  # each block row's first block (sorted order)
    row_nnz = np.repeat(count * e, d)  # every scalar row of block row R holds count[R]·e entries
    indptr = np.concatenate([[0], np.cumsum(row_nnz)])
    # entry (q, i, j) of sorted block q sits in scalar row d·br[q] + i at its rank in the block row
    rank = np.arange(nb) - first[br]
    start = indptr[d * br][:, None] + np.arange(d)[None, :] * (count[br] * e)[:, None] + (rank * e)[:, None]  # (nb, d)
    pos = (start[:, :, None] + np.arange(e)[None, None, :]).ravel()
    data = np.empty(nb * d * e)
    indices = np.empty(nb * d * e, np.int64)
    data[pos] = blocks[order].ravel()
    indices[pos] = np.broadcast_to((e * bc)[:, None, None] + np.arange(e)[None, None, :], (nb, d, e)).ravel()
    return sp.csr_array((data, indices, indptr), shape=shape)


def block_weight(blocks: np.ndarray, dense_max: int = DENSE_WEIGHT_MAX) -> np.ndarray | sp.csr_array:
    """The block-diagonal weight (Bd × Bd) of stacked residuals from their (B, d, d) blocks: dense up to
    ``dense_max`` rows, else sparse."""
    B, d, _ = blocks.shape
    if B * d <= dense_max:
        return block_diag(*blocks) if B else np.zeros((0, 0))
    return block_sparse(np.arange(B), np.arange(B), blocks, (B * d, B * d))
