"""Compiled (numba) kernels of the IPM's per-iteration block work: the Schur complement's assembly
(``BlockProducts``), the step length to the cone's boundary (``max_step``), and the band's scaling and
full storage for LAPACK (``scaled_band``, ``full_band``).  ``schur_ipm`` uses them from
``COMPILED_MIN_BLOCKS`` blocks on; its numpy code is the reference they are tested against, and they do
its floating-point operations in its order (the same iterates).

Conventions: the blocks of one size group are a C-contiguous (B, n, n) float64 array; block k's
constraint data G_k is a CSR matrix (m_k × s_k) over its support entries (a_u, b_u), a_u ≤ b_u, in half
form with the weights 1/o_u (``schur_ipm.block_data``).  numba compiles the kernels on first use and
caches them (``cache=True``: in ``__pycache__`` beside this file, or under ``NUMBA_CACHE_DIR``): the
first call of a fresh install pays the compilation (~2–3 s), later processes load it (~0.2 s).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

#: below this many blocks ``schur_ipm`` keeps its numpy code, so that no problem gets slower even in the
#: first process of an installation, which compiles the kernels (~2–3 s; later processes load them in
#: ~0.3 s, and numba adds ~100 MB resident).  ``autotight solve discrete_trajectory`` (one block per
#: pose), wall s, base / kernels with an empty cache / with a filled one: K = 50: 2.6 / 4.4 / 2.3;
#: K = 100: 6.0 / 7.8 / 5.3; K = 200: 13.3 / 12.3 / 9.1
COMPILED_MIN_BLOCKS = 150


def _kernels() -> Any:
    """The numba module of the kernels (imported on first use: numba's import costs ~0.15 s)."""
    from . import _schur_numba

    return _schur_numba


class BlockProducts:
    """The per-block data of S = Σ_k G_kᵀ (P_k ⊗ Q_k) G_k, concatenated over blocks for the compiled
    kernel: G_k's CSR arrays, the support (a_u, b_u) of each block, and the output positions of each
    block's m_k × m_k product (``targets``: all blocks' positions, block after block: row-major over the
    m_k² entries, or with ``lower`` over the lower triangle i ≥ l only, packed row-major, when the output
    needs one triangle).

    ``accumulate(out, P, Q)`` adds every block's product G_k K_k G_kᵀ (K_k the kernel of
    ``schur_ipm._Schur.assemble``, from the groups' P, Q) into ``out`` at its targets."""

    def __init__(self, per_block: list[sp.csr_array], support: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                 targets: np.ndarray, groups: list[tuple[int, np.ndarray, np.ndarray]], lower: bool = False):
        p = len(per_block)
        m = np.array([G.shape[0] for G in per_block], np.int64)
        s = np.array([G.shape[1] for G in per_block], np.int64)
        nnz = np.array([G.nnz for G in per_block], np.int64)
        self.row_off = np.concatenate([[0], np.cumsum(m + 1)])  # block k's indptr: indptr[row_off[k]:…]
        self.nz_off = np.concatenate([[0], np.cumsum(nnz)])
        self.sup_off = np.concatenate([[0], np.cumsum(s)])
        self.lower = lower
        self.tgt_off = np.concatenate([[0], np.cumsum(m * (m + 1) // 2 if lower else m * m)])
        self.indptr = np.concatenate([G.indptr.astype(np.int64) for G in per_block]) if p else np.zeros(0, np.int64)
        self.indices = np.concatenate([G.indices.astype(np.int64) for G in per_block]) if p else np.zeros(0, np.int64)
        self.data = np.concatenate([G.data.astype(np.float64) for G in per_block]) if p else np.zeros(0)
        self.a = np.concatenate([sup[0].astype(np.int64) for sup in support]) if p else np.zeros(0, np.int64)
        self.b = np.concatenate([sup[1].astype(np.int64) for sup in support]) if p else np.zeros(0, np.int64)
        self.targets = targets if targets.dtype in (np.int32, np.int64) else targets.astype(np.int64)
        self.groups = [ids.astype(np.int64) for _, ids, _ in groups]
        self.m_max, self.s_max = int(m.max(initial=0)), int(s.max(initial=0))

    def accumulate(self, out: np.ndarray, P: list[np.ndarray], Q: list[np.ndarray]) -> None:
        """out[targets[k]] += vec(G_k K_k G_kᵀ) for every block k; P, Q per size group (B, n, n),
        symmetric blocks; ``P is Q`` (NT) uses the folded kernel 2(P_ac P_bd + P_ad P_bc)."""
        kern = _kernels()
        same = P is Q
        for ids, Pg, Qg in zip(self.groups, P, Q):
            Pc = np.ascontiguousarray(Pg, dtype=np.float64)
            Qc = Pc if same else np.ascontiguousarray(Qg, dtype=np.float64)
            kern.accumulate_group(out, ids, Pc, Qc, same, self.lower, self.row_off, self.nz_off, self.sup_off,
                                  self.tgt_off, self.indptr, self.indices, self.data, self.a, self.b, self.targets,
                                  self.m_max, self.s_max)


def max_step(Linv: list[np.ndarray], dX: list[np.ndarray], limit: float = np.inf) -> float:
    """min(limit, the largest α with X + α dX ⪰ 0 in every block) (∞ when no block ever leaves the
    cone and limit is ∞), from the inverse Cholesky factors L⁻¹ of X; the same value as
    ``schur_ipm._max_step`` (which ignores ``limit``) wherever that is below ``limit``.

    α = −1/λ with λ the smallest eigenvalue over the blocks of M_k = sym(L_k⁻¹ dX_k L_k⁻ᵀ).  Instead of
    every block's eigenvalues, the blocks are visited by their smallest diagonal entry (an upper bound of
    their λ_k); a Cholesky factorisation of M_k − λ·I (n³/6 flops) shows λ_k > λ for the running minimum λ
    (from −1/limit), and only a block where it fails has its eigenvalues computed (LAPACK, as
    ``_max_step``), lowering λ."""
    kern = _kernels()
    lam0 = -1.0 / limit if limit < np.inf else 0.0
    lam = lam0
    for Li, dXg in zip(Linv, dX):
        M = Li @ dXg @ np.swapaxes(Li, -1, -2)
        M = np.ascontiguousarray(0.5 * (M + np.swapaxes(M, -1, -2)))
        order = np.argsort(np.diagonal(M, axis1=1, axis2=2).min(axis=1), kind="stable")
        p = 0
        while (p := int(kern.first_not_above(M, order, lam, p))) < order.size:
            lam = min(lam, float(np.linalg.eigvalsh(M[order[p]])[0]))
            p += 1
    if lam >= lam0:  # no block leaves the cone before limit
        return limit
    return -1.0 / lam


def _buffer(out: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """``out`` when it is a Fortran-ordered float64 array of ``shape`` (a buffer reused across iterations:
    a fresh one of ~100 MB costs its page faults each time), else a new one."""
    if out is not None and out.shape == shape and out.dtype == np.float64 and out.flags.f_contiguous:
        return out
    return np.empty(shape, order="F")


def full_band(low: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """LAPACK's general band storage (kl = ku = b, b more rows for the LU's fill; Fortran order) of the
    symmetric M × M matrix whose lower band storage (b + 1, M) is ``low``: ab[2b + i − j, j] = A[i, j]
    (``schur_ipm._BandSchur._full_band``), column by column; written into ``out`` when it fits."""
    b = low.shape[0] - 1
    ab = _buffer(out, (3 * b + 1, low.shape[1]))
    _kernels().full_band(np.asfortranarray(low), ab)
    return ab


def scaled_band(ab: np.ndarray, dsc: np.ndarray, reg: float, out: np.ndarray | None = None) -> np.ndarray:
    """D S D + reg·I in lower band storage ((b + 1, M), Fortran order) from S's (``ab``) and D = diag(dsc):
    entry (t, j) is ab[t, j]·dsc[j]·dsc[j + t], multiplied in that order (``schur_ipm._BandSchur._scaled``);
    the unused corner (j + t ≥ M) is 0; written into ``out`` when it fits."""
    res = _buffer(out, ab.shape)
    _kernels().scaled_band(ab, dsc, reg, res)
    return res

