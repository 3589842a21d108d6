"""numba kernels of ``schur_kernel`` (imported only when they are used: importing numba costs time).
The arrays' meanings are those of ``schur_kernel.BlockProducts``."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def accumulate_group(out, ids, sel, lo, hi, P, Q, same, lower, row_off, nz_off, sup_off, tgt_off, indptr, indices, data,
                     a, b, targets, m_max, s_max):  # pragma: no cover - compiled
    """For each block ids[j], j in sel (data P[j], Q[j]): K = the kernel on its support, Y = G K, and
    S_il = (G Yᵀ)_il added to out at its target when lo ≤ target < hi, for i ≥ l (lower: targets packed
    row-major over i ≥ l) or for every (i, l) (targets row-major over all m² entries)."""
    K = np.empty((s_max, s_max))
    Y = np.empty((m_max, s_max))
    Yt = np.empty((s_max, m_max))
    row = np.empty(m_max)
    for jj in range(sel.size):
        j = sel[jj]
        k = ids[j]
        Pk = P[j]
        Qk = Q[j]
        s0 = sup_off[k]
        s = sup_off[k + 1] - s0
        r0 = row_off[k]
        m = row_off[k + 1] - r0 - 1
        z0 = nz_off[k]
        # K_uw: 2(P_ac P_bd + P_ad P_bc) when P is Q (symmetric: the lower half, mirrored), else the
        # four-term orbit sum at every (u, w), in the numpy code's order
        aa = a[s0:s0 + s]
        bb = b[s0:s0 + s]
        for u in range(s):
            pa = Pk[aa[u]]
            pb = Pk[bb[u]]
            qa = Qk[aa[u]]
            qb = Qk[bb[u]]
            if same:
                for w in range(u + 1):
                    aw = aa[w]
                    bw = bb[w]
                    v = 2.0 * (pa[aw] * pb[bw] + pa[bw] * pb[aw])
                    K[u, w] = v
                    K[w, u] = v
            else:
                for w in range(s):
                    aw = aa[w]
                    bw = bb[w]
                    K[u, w] = pa[aw] * qb[bw] + pa[bw] * qb[aw] + pb[aw] * qa[bw] + pb[bw] * qa[aw]
        # Y = G K (rows of G are sparse: a sum of rows of K)
        for i in range(m):
            for w in range(s):
                Y[i, w] = 0.0
            for p in range(indptr[r0 + i], indptr[r0 + i + 1]):
                g = data[z0 + p]
                u = indices[z0 + p]
                for w in range(s):
                    Y[i, w] += g * K[u, w]
        # S_k = G Yᵀ (= Y Gᵀ), or its lower triangle, into out: row i of S_k = Σ_p g_p (column u_p of Y),
        # contiguous in Yt = Yᵀ
        for w in range(s):
            for i in range(m):
                Yt[w, i] = Y[i, w]
        t0 = tgt_off[k]
        for i in range(m):
            n_l = i + 1 if lower else m  # the lower triangle, or the whole row
            for l in range(n_l):
                row[l] = 0.0
            for p in range(indptr[r0 + i], indptr[r0 + i + 1]):
                g = data[z0 + p]
                u = indices[z0 + p]
                for l in range(n_l):
                    row[l] += g * Yt[u, l]
            t = t0 + (i * (i + 1) // 2 if lower else i * m)
            for l in range(n_l):
                tg = targets[t + l]
                if lo <= tg < hi:
                    out[tg] += row[l]


@njit(cache=True, nogil=True)
def first_not_above(M, order, lam, start):  # pragma: no cover - compiled
    """The first position p ≥ start of ``order`` whose block M[order[p]] − lam·I is not positive definite
    (its Cholesky factorisation meets a pivot ≤ 0), or order.size when there is none."""
    n = M.shape[1]
    L = np.empty((n, n))
    for p in range(start, order.size):
        k = order[p]
        for j in range(n):
            d = M[k, j, j] - lam
            for t in range(j):
                d -= L[j, t] * L[j, t]
            if not d > 0.0:  # also catches NaN
                return p
            d = np.sqrt(d)
            L[j, j] = d
            for i in range(j + 1, n):
                v = M[k, i, j]
                for t in range(j):
                    v -= L[i, t] * L[j, t]
                L[i, j] = v / d
    return order.size


@njit(cache=True, nogil=True)
def scaled_band(ab, dsc, reg, out, j0, j1):  # pragma: no cover - compiled
    """out[t, j] = ab[t, j]·dsc[j]·dsc[j + t] (0 where j + t ≥ M), plus reg on t = 0, for columns j0 ≤ j < j1."""
    bp1, M = ab.shape
    for j in range(j0, j1):
        for t in range(bp1):
            out[t, j] = ab[t, j] * dsc[j] * dsc[j + t] if j + t < M else 0.0
        out[0, j] += reg


@njit(cache=True, nogil=True)
def scaled_full_band(ab, dsc, reg, out, j0, j1):  # pragma: no cover - compiled
    """The general band storage of ``scaled_band``'s output in one pass, for columns j0 ≤ j < j1: rows 0 … b − 1 zero,
    out[2b + t, j] = the scaled entry (t, j), out[2b − t, j] = the scaled entry (t, j − t) (0 for j < t)."""
    bp1, M = ab.shape
    b = bp1 - 1
    for j in range(j0, j1):
        for r in range(b):
            out[r, j] = 0.0
        for t in range(b, 0, -1):
            c = j - t
            out[2 * b - t, j] = ab[t, c] * dsc[c] * dsc[c + t] if c >= 0 else 0.0
        for t in range(bp1):
            out[2 * b + t, j] = ab[t, j] * dsc[j] * dsc[j + t] if j + t < M else 0.0
        out[2 * b, j] += reg
