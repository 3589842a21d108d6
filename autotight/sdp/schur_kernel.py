"""Compiled (numba) kernels of the IPM's per-iteration block work: the Schur complement's assembly
(``BlockProducts``), the step length to the cone's boundary (``max_step``), and the band's scaling, alone
or straight into LAPACK's general band storage (``scaled_band``, ``scaled_full_band``).  ``schur_ipm`` uses
them from ``COMPILED_MIN_BLOCKS`` blocks on; its numpy code is the reference they are tested against, and
they do its floating-point operations in its order (the same iterates).  The kernels release the GIL: with
``block_threads.BlockThreads`` the assembly and the band's scaling run in two threads, each on its own
range of the output (every entry is the same sum, in the same order).

Conventions: the blocks of one size group are a C-contiguous (B, n, n) float64 array; block k's
constraint data G_k is a CSR matrix (m_k × s_k) over its support entries (a_u, b_u), a_u ≤ b_u, in half
form with the weights 1/o_u (``schur_ipm.block_data``).  numba compiles the kernels on first use and
caches them (``cache=True``: in ``__pycache__`` beside this file, or under ``NUMBA_CACHE_DIR``): the
first call of a fresh install pays the compilation (~2–3 s), later processes load it (~0.2 s).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import scipy.sparse as sp

#: below this many blocks ``schur_ipm`` keeps its numpy code, so that no problem gets slower even in the
#: first process of an installation, which compiles the kernels (~2–3 s; later processes load them in
#: ~0.3 s, and numba adds ~100 MB resident).  ``autotight solve discrete_trajectory`` (one block per
#: pose), wall s, base / kernels with an empty cache / with a filled one: K = 50: 2.6 / 4.4 / 2.3;
#: K = 100: 6.0 / 7.8 / 5.3; K = 200: 13.3 / 12.3 / 9.1
COMPILED_MIN_BLOCKS = 150
#: the assembly runs in two threads only when the blocks that reach both halves of the output (computed
#: by both) are at most this share of the work
SPLIT_MAX_SHARED = 0.1

if TYPE_CHECKING:
    from .block_threads import BlockThreads


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
    ``schur_ipm._Schur.assemble``, from the groups' P, Q) into ``out`` at its targets.  With worker threads
    the output's positions are cut in two ranges, each thread adds the blocks that reach its range, in
    the sequential order, to its range only: every entry is the same sum, in the same order."""

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
        # per block: the range of its targets, and its work (the kernel s², Y = G K, S_k's rows)
        lens = np.diff(self.tgt_off)
        nonempty = lens > 0
        self.tmin = np.full(p, np.iinfo(np.int64).max, np.int64)
        self.tmax = np.full(p, -1, np.int64)
        if nonempty.any():
            starts = self.tgt_off[:-1][nonempty]
            self.tmin[nonempty] = np.minimum.reduceat(self.targets.astype(np.int64), starts)
            self.tmax[nonempty] = np.maximum.reduceat(self.targets.astype(np.int64), starts)
        self.work = (s * s + nnz * s + lens).astype(np.float64)
        self._cut: int | None = None

    def _plan(self) -> int | None:
        """The position that cuts the output in two ranges of about equal work, or None when the blocks
        that reach both ranges (computed twice) would cost more than ``SPLIT_MAX_SHARED`` of the work."""
        if self._cut is None:
            order = np.argsort(self.tmin, kind="stable")
            cum = np.cumsum(self.work[order])
            if cum.size == 0:
                self._cut = -1
                return None
            half = int(np.searchsorted(cum, cum[-1] / 2))
            cut = int(self.tmin[order[min(half + 1, order.size - 1)]])
            shared = self.work[(self.tmin < cut) & (self.tmax >= cut)].sum()
            self._cut = cut if shared <= SPLIT_MAX_SHARED * cum[-1] else -1
        return None if self._cut < 0 else self._cut

    def accumulate(self, out: np.ndarray, P: list[np.ndarray], Q: list[np.ndarray],
                   par: "BlockThreads | None" = None) -> None:
        """out[targets[k]] += vec(G_k K_k G_kᵀ) for every block k; P, Q per size group (B, n, n),
        symmetric blocks; ``P is Q`` (NT) uses the folded kernel 2(P_ac P_bd + P_ad P_bc).  With ``par``
        (two or more workers) in two threads, each on one range of ``out`` (the same sums)."""
        same = P is Q
        stacks = []  # per size group: P, Q (C-contiguous) and the block ids
        for ids, Pg, Qg in zip(self.groups, P, Q):
            Pc = np.ascontiguousarray(Pg, dtype=np.float64)
            stacks.append((Pc, Pc if same else np.ascontiguousarray(Qg, dtype=np.float64), ids))
        cut = self._plan() if par is not None and par.workers > 1 else None
        if cut is None:
            self._add(out, stacks, same, None, 0, np.iinfo(np.int64).max)
            return
        assert par is not None
        upper = par.submit(self._add, out, stacks, same, lambda ids: self.tmax[ids] >= cut, cut,
                           np.iinfo(np.int64).max)
        self._add(out, stacks, same, lambda ids: self.tmin[ids] < cut, 0, cut)
        upper.result()

    def _add(self, out: np.ndarray, stacks: list[tuple[np.ndarray, np.ndarray, np.ndarray]], same: bool,
             reach: Callable[[np.ndarray], np.ndarray] | None, lo: int, hi: int) -> None:
        """The blocks (of each group, in order; those where ``reach`` holds) added to out[lo:hi]."""
        kern = _kernels()
        for Pc, Qc, ids in stacks:
            sel = np.arange(ids.size) if reach is None else np.flatnonzero(reach(ids))
            kern.accumulate_group(out, ids, sel, lo, hi, Pc, Qc, same, self.lower, self.row_off, self.nz_off,
                                  self.sup_off, self.tgt_off, self.indptr, self.indices, self.data, self.a, self.b,
                                  self.targets, self.m_max, self.s_max)


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


def scaled_band(ab: np.ndarray, dsc: np.ndarray, reg: float, out: np.ndarray | None = None,
                par: "BlockThreads | None" = None) -> np.ndarray:
    """D S D + reg·I in lower band storage ((b + 1, M), Fortran order) from S's (``ab``) and D = diag(dsc):
    entry (t, j) is ab[t, j]·dsc[j]·dsc[j + t], multiplied in that order (``schur_ipm._BandSchur._scaled``);
    the unused corner (j + t ≥ M) is 0; written into ``out`` when it fits; with ``par``, by column ranges
    in its threads."""
    res = _buffer(out, ab.shape)
    _by_columns(_kernels().scaled_band, ab.shape[1], par, ab, dsc, reg, res)
    return res


def scaled_full_band(ab: np.ndarray, dsc: np.ndarray, reg: float, out: np.ndarray | None = None,
                     par: "BlockThreads | None" = None) -> np.ndarray:
    """LAPACK's general band storage (kl = ku = b, b more rows for the LU's fill; Fortran order (3b + 1, M)) of
    ``scaled_band(ab, dsc, reg)``'s symmetric matrix, in one pass: the same entries as
    ``schur_ipm._BandSchur._full_band`` of it, A[i, j] at row 2b + i − j; written into ``out`` when it fits."""
    b = ab.shape[0] - 1
    res = _buffer(out, (3 * b + 1, ab.shape[1]))
    _by_columns(_kernels().scaled_full_band, ab.shape[1], par, ab, dsc, reg, res)
    return res


def _by_columns(kernel: Callable[..., None], M: int, par: "BlockThreads | None", *args: Any) -> None:
    """kernel(*args, j0, j1) over the columns 0 … M − 1: in one call, or in one range per thread of ``par``
    (each column is written by one call: the same entries)."""
    if par is None or par.workers < 2 or M < 2:
        kernel(*args, 0, M)
        return
    cuts = np.linspace(0, M, par.workers + 1).round().astype(np.int64)
    futures = [par.submit(kernel, *args, int(lo), int(hi)) for lo, hi in zip(cuts[1:-1], cuts[2:])]
    kernel(*args, int(cuts[0]), int(cuts[1]))
    for f in futures:
        f.result()

