"""The clique-decomposed Shor SDP as a block standard-form SDP (shared by every clique backend).

For cliques C_1 … C_p of a chordal pattern that contains Q and every Aᵢ, with a clique tree, by
Agler's theorem the dual  max bᵀy s.t. S = Q − Σ yᵢAᵢ ⪰ 0  is, on that pattern,

    max bᵀy  s.t.  S_k = [k owns (i,j)]·(Q − Σ yᵢAᵢ)_ij − t_{k,ij} + Σ_{children c} t_{c,ij} ⪰ 0,

where each entry belongs to the highest clique holding it ("owns") and the free transfer t_{k,ij}
moves the share of an entry from clique k to its tree parent.  Written on the stacked svec of the
blocks, s = c − F [y; t], this is the dual of the block primal

    min cᵀz  s.t.  Fᵀz = g = [b; 0],  z = (svec X_1, …, svec X_p),  X_k ⪰ 0,

whose rows for t say that neighbouring blocks agree on their overlap.  Both have the optimal value
of the dense SDP.  svec is column-major upper triangle with off-diagonal entries scaled by √2, so
svec(A)·svec(X) = ⟨A, X⟩.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..svec import SQRT2, position_to_ij, prepended_entries, svec_columns, triu_indices
from .chordal import clique_tree, home_cliques, maximal, support_matrix
from ..svec import smat
from .result import DENSE_X_MAX, log_svr, rank_d_factor


@dataclass
class CliqueProgram:
    """Block data of the decomposed SDP (shapes: R = Σ svec(|C_k|) rows, m constraints, T transfers).

    F: (R × (m + T)) sparse, the columns of the m constraints then of the T transfers.
    c: (R,) the scaled cost (Q · scale) split among the blocks.  g: (m + T,) = [b; 0].
    start[k]: the first row of block k.  pos: (R,) each row's position in svec of the N×N matrix.
    """

    cliques: list[np.ndarray]
    F: sp.csc_matrix
    c: np.ndarray
    g: np.ndarray
    start: list[int]
    pos: np.ndarray
    m: int
    N: int
    scale: float

    @property
    def sizes(self) -> list[int]:
        return [len(C) for C in self.cliques]

    def congruence(self, D: np.ndarray) -> "CliqueProgram":
        """The program of the data D Q D, D Aᵢ D (D: positive (N,), the diagonal of a congruence), on the
        same cliques: each row of F and c (the svec entry (i, j)) times D_i D_j, the cost rescaled to
        max|C_ij| = 1 again.  y and g are unchanged (⟨D A D, D⁻¹ X D⁻¹⟩ = ⟨A, X⟩); a transfer variable
        is that of the unscaled program times D_i D_j."""
        gi, gj = position_to_ij(self.pos)
        s = np.asarray(D, float)[gi] * np.asarray(D, float)[gj]
        cost = s * self.c / self.scale  # the unscaled cost D Q D, split as before
        top = float(np.max(np.abs(cost), initial=0.0))
        scale = 1.0 / top if top > 0 else 1.0
        F = sp.csc_matrix(sp.diags_array(s) @ self.F)
        return CliqueProgram(self.cliques, F, cost * scale, self.g, self.start, self.pos, self.m, self.N, scale)

    def pattern_matrix(self, z: np.ndarray) -> np.ndarray | None:
        """The N×N matrix with the blocks' svec entries z (R,) on the pattern, zero elsewhere
        (None if z is not a finite vector of the blocks' size)."""
        if z.size != self.pos.size or not np.all(np.isfinite(z)):
            return None
        gi, gj = position_to_ij(self.pos)
        v = np.where(gi == gj, z, z / SQRT2)
        Xp = np.zeros((self.N, self.N))
        Xp[gi, gj] = v
        Xp[gj, gi] = v
        return Xp

    def complete(self, z: np.ndarray, d: int) -> tuple[np.ndarray | None, list[float]]:
        """The blocks' svec z (R,) → (X completed off the pattern, per-block log SVR); (None, []) when
        z is unusable."""
        Xp = self.pattern_matrix(z)
        return (None, []) if Xp is None else complete_from_cliques(Xp, self.cliques, d)


def complete_sparse(prog: "CliqueProgram", z: np.ndarray, d: int
                    ) -> tuple[sp.csr_array | None, list[float], np.ndarray | None]:
    """``CliqueProgram.complete`` without N×N arrays: (X on the cliques' pattern as a symmetric csr_array,
    per-block log SVR, the completion factor Θ (d×N)); (None, [], None) when z is unusable."""
    if z.size != prog.pos.size or not np.all(np.isfinite(z)):
        return None, [], None
    N = prog.N
    upos, first = np.unique(prog.pos[::-1], return_index=True)  # the last block's value of a shared entry
    zv = z[::-1][first]
    gi, gj = position_to_ij(upos)
    v = np.where(gi == gj, zv, zv / SQRT2)
    off = gi != gj
    X = sp.csr_array((np.concatenate([v, v[off]]), (np.concatenate([gi, gj[off]]), np.concatenate([gj, gi[off]]))),
                     shape=(N, N))
    Theta = np.zeros((d, N))
    svrs = []
    for k, C in enumerate(prog.cliques):
        w, Th = rank_d_factor(smat(z[prog.start[k]:prog.start[k + 1]], len(C)), d)
        svrs.append(log_svr(w, d))
        Theta[:, C] = Th
    return X, svrs, Theta


def complete_auto(prog: "CliqueProgram", z: np.ndarray, d: int
                  ) -> tuple[np.ndarray | sp.csr_array | None, list[float], np.ndarray | None]:
    """Dense completion (``complete``) up to ``DENSE_X_MAX`` columns, else ``complete_sparse``."""
    if prog.N <= DENSE_X_MAX:
        X, svrs = prog.complete(z, d)
        return X, svrs, None
    return complete_sparse(prog, z, d)


def complete_from_cliques(Xp: np.ndarray, cliques: Sequence[np.ndarray], d: int) -> tuple[np.ndarray, list[float]]:
    """X known on the cliques' pattern → per-clique log SVR, and X with the entries off the pattern
    filled from the rank-d factors of the clique blocks (each clique contains h, which fixes
    their alignment; the completion is exact when every block has rank d)."""
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


def cost_scale(Q: sp.csr_array) -> float:
    """1 / max|Q_ij|: the solvers see a cost of magnitude 1."""
    m = abs(Q).max() if Q.nnz else 1.0
    return 1.0 / m if m > 0 else 1.0


def _find(sorted_values: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index, found) of each query in an increasing array."""
    at = np.searchsorted(sorted_values, queries)
    found = (at < sorted_values.size) & (sorted_values[np.minimum(at, max(sorted_values.size - 1, 0))] == queries)
    return at, found


def _home_rows(G: sp.coo_array, cliques: Sequence[np.ndarray], pos: np.ndarray, start: list[int],
               own: np.ndarray, N: int) -> np.ndarray:
    """The block row for every nonzero (svec entry e, constraint i) of G.

    Constraint i is placed in its home clique, the one holding most of its columns; an entry that
    the home clique lacks goes to the entry's top clique.  Any split of an entry among the cliques
    holding it is exact (the transfers balance it); this one keeps a constraint's coefficients in
    its own part of the clique tree instead of sending every shared entry (h², h·x) to the root.
    """
    gi, gj = position_to_ij(G.row)
    home = home_cliques(cliques, support_matrix(gi, gj, G.col, N, G.shape[1]))[G.col]
    # one search over every block at once: (block, position) keys increase along the rows (blocks in
    # order, each block's positions increasing), so a nonzero's row in its home block is a binary search
    span = int(max(pos.max(initial=0), G.row.max(initial=0))) + 1
    block = np.repeat(np.arange(len(cliques), dtype=np.int64), np.diff(start))
    at, hit = _find(block * span + pos, home * span + G.row)
    rows = np.where(hit, at, -1)
    miss = rows < 0
    order = np.argsort(pos[own])
    rows[miss] = own[order[np.searchsorted(pos[own][order], G.row[miss])]]
    return rows


def _block_positions(cliques: Sequence[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    """(pos, start): one row per (clique k, svec entry of its block), blocks in order; pos the entry's position
    in svec of N×N (increasing within a block, each clique being sorted), start[k] block k's first row."""
    sizes = np.array([len(C) for C in cliques], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(sizes * (sizes + 1) // 2)])
    pos = np.empty(int(start[-1]), dtype=np.int64)
    for n in np.unique(sizes).tolist():  # the cliques of one size at once
        ids = np.flatnonzero(sizes == n)
        C = np.stack([np.asarray(cliques[k], dtype=np.int64) for k in ids.tolist()])  # (B, n)
        i, j = triu_indices(n)
        pos[start[ids][:, None] + np.arange(i.size)[None, :]] = C[:, j] * (C[:, j] + 1) // 2 + C[:, i]
    return pos, start.tolist()


def clique_program(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray,
                   cliques: Sequence[np.ndarray]) -> CliqueProgram:
    """Decompose  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0  over ``cliques`` (see the module docstring).

    ValueError when the cliques have no clique tree or miss an entry of the data.
    """
    N = Q.shape[0]
    scale = cost_scale(Q)
    cliques = maximal(cliques)
    parent = clique_tree(cliques)  # ValueError unless the cliques form a clique tree
    m = len(As)
    pos, start = _block_positions(cliques)
    nrow = start[-1]
    # the row of the same entry in the parent's block (−1: the entry is not in the parent, k owns it): one search
    # of (block, position) keys, increasing along the rows
    block = np.repeat(np.arange(len(cliques), dtype=np.int64), np.diff(start))
    span = int(pos.max(initial=0)) + 1
    up = np.asarray(parent, dtype=np.int64)[block]
    child = np.flatnonzero(up >= 0)
    at, hit = _find(block * span + pos, up[child] * span + pos[child])
    par_row = np.full(nrow, -1, dtype=np.int64)
    par_row[child[hit]] = at[hit]
    own = np.flatnonzero(par_row < 0)  # the top clique's row of each entry (one per entry)
    moved = np.flatnonzero(par_row >= 0)
    t = m + np.arange(moved.size)  # transfer variables, one per entry shared with the parent
    # COO throughout: a CSR copy of the svec data would hold an index array of N(N+1)/2 + 1 entries
    # (2.3 GB at N = 24 000), the one quadratic array of the decomposition
    data = svec_columns([Q, *As], N, prepended_entries(Q, As)).tocoo()  # column 0: Q
    own_order = np.argsort(pos[own])
    known = pos[own][own_order]  # every entry of the pattern once, increasing
    inside = _find(known, data.row)[1]
    if not inside.all():
        outside = np.unique(data.row[~inside])
        raise ValueError(f"{outside.size} entries of the cost or constraints lie outside every clique")
    isq = data.col == 0
    G = sp.coo_array((data.data[~isq], (data.row[~isq], data.col[~isq] - 1)), shape=(data.shape[0], m))
    g_row = _home_rows(G, cliques, pos, start, own, N)
    F = sp.csc_matrix((np.concatenate([G.data, np.ones(moved.size), -np.ones(moved.size)]),
                       (np.concatenate([g_row, moved, par_row[moved]]), np.concatenate([G.col, t, t]))),
                      shape=(nrow, m + moved.size))
    c = np.zeros(nrow)
    at = np.searchsorted(known, data.row[isq])
    c[own[own_order[at]]] = data.data[isq] * scale
    g = np.concatenate([np.asarray(b, float), np.zeros(moved.size)])
    return CliqueProgram(cliques, F, c, g, start, pos, m, N, scale)
