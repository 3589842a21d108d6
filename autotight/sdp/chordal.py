"""Clique covers for the decomposed SDP: a min-fill chordal cover of the data, clique trees,
merging of small cliques, and the check that a cover decomposes X ⪰ 0 exactly.

For cliques C_1 … C_p of a chordal pattern, X ⪰ 0 completable ⟺ X[C_k, C_k] ⪰ 0 for all k
(Grone et al. 1984).  The cliques must form a clique tree: they satisfy the running
intersection property iff a maximum-weight spanning tree of the clique-intersection graph
has weight Σ|C_k| − |∪C_k|.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree


def _overlaps(cliques: Sequence[np.ndarray]) -> np.ndarray:
    """(p × p) dense array of |C_i ∩ C_j| (diagonal zeroed), from the clique-column incidence matrix."""
    sizes = [len(c) for c in cliques]
    N = int(max(int(np.max(c)) for c in cliques)) + 1
    B = sp.csr_array((np.ones(sum(sizes)), (np.repeat(np.arange(len(cliques)), sizes),
                                              np.concatenate([np.asarray(c, np.int64) for c in cliques]))),
                     shape=(len(cliques), N))
    W = (B @ B.T).toarray()
    np.fill_diagonal(W, 0)
    return W


def _max_overlap_tree(cliques: Sequence[np.ndarray]) -> sp.coo_array:
    """A maximum-weight spanning forest of the clique-intersection graph (edge weight |C_i ∩ C_j|)."""
    W = _overlaps(cliques)
    big = W.max() + 1
    return minimum_spanning_tree(sp.csr_array(np.where(W > 0, big - W, 0))).tocoo()  # min of big − w = max of w


def has_running_intersection(cliques: Sequence[np.ndarray]) -> bool:
    p = len(cliques)
    if p <= 1:
        return True
    T = _max_overlap_tree(cliques)
    if T.nnz != p - 1:
        return False  # the cliques are not connected
    weight = int(round(_overlaps(cliques)[T.row, T.col].sum()))
    union = np.unique(np.concatenate([np.asarray(c) for c in cliques]))
    return weight == sum(len(c) for c in cliques) - union.size


def clique_tree(cliques: Sequence[np.ndarray]) -> np.ndarray:
    """parent[k] of every clique in a clique tree rooted at clique 0 (parent −1 for the root).

    The tree is a maximum-overlap spanning tree, which is a clique tree whenever the cliques have
    the running intersection property; then the cliques holding any one column form a subtree.
    """
    p = len(cliques)
    parent = np.full(p, -1, dtype=np.int64)
    if p <= 1:
        return parent
    T = _max_overlap_tree(cliques)
    if T.nnz != p - 1:
        raise ValueError("the cliques are not connected: no clique tree")
    _, pred = breadth_first_order(sp.csr_array((np.ones(T.nnz), (T.row, T.col)), shape=(p, p)), 0,
                                  directed=False)
    parent[1:] = pred[1:]
    return parent


def merge_small(cliques: Sequence[np.ndarray], max_size: int) -> list[np.ndarray]:
    """Merge every clique into its clique-tree parent while their union has at most ``max_size`` columns.

    Merging a clique into its tree neighbour keeps a clique tree.  Fewer, larger blocks trade the
    interior-point cost of the blocks (∝ Σ svec(|C|)³) against that of the overlaps between them;
    on the trajectory problems about 20 columns was the best cap.
    """
    cl = [set(np.asarray(c).tolist()) for c in cliques]
    parent = clique_tree(cliques)
    order = _depth_order(parent)
    alive = np.ones(len(cl), bool)
    for k in order[::-1]:  # leaves first
        p = int(parent[k])
        while p >= 0 and not alive[p]:
            p = int(parent[p])
        if p >= 0 and len(cl[k] | cl[p]) <= max_size:
            cl[p] |= cl[k]
            alive[k] = False
    return [np.array(sorted(cl[k]), dtype=np.int64) for k in range(len(cl)) if alive[k]]


def _depth_order(parent: np.ndarray) -> np.ndarray:
    """Clique indices ordered so that every parent comes before its children."""
    depth = np.zeros(len(parent), np.int64)
    for k in range(len(parent)):
        j, d = k, 0
        while parent[j] >= 0:
            j, d = parent[j], d + 1
        depth[k] = d
    return np.argsort(depth, kind="stable")


def maximal(cliques: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Drop cliques contained in another clique (keeps the first of equal ones)."""
    sets = [frozenset(np.asarray(c).tolist()) for c in cliques]
    out = []
    for i, s in enumerate(sets):
        if any((s < t) or (s == t and j < i) for j, t in enumerate(sets) if j != i):
            continue
        out.append(np.array(sorted(s), dtype=np.int64))
    return out


def column_cliques(N: int, matrices: Sequence[sp.sparray], always: Sequence[int] = (0,)) -> list[np.ndarray]:
    """Cliques (column indices) of a chordal extension of the aggregate sparsity of ``matrices``.

    Columns i ≠ j are adjacent when some matrix has a nonzero at (i, j).  The ``always``
    columns (h) touch everything; they are left out of the graph and added to every clique.
    Greedy minimum-fill elimination gives the chordal extension; its elimination cliques, kept
    maximal, form a clique tree.
    """
    import heapq

    fixed = set(int(a) for a in always)
    entries = [sp.coo_array(A) for A in matrices]
    rows = np.concatenate([E.row for E in entries]).astype(np.int64)
    cols = np.concatenate([E.col for E in entries]).astype(np.int64)
    free = np.ones(N, bool)
    free[list(fixed)] = False
    keep = (rows != cols) & free[rows] & free[cols]
    pairs = np.unique(np.concatenate([rows[keep] * N + cols[keep], cols[keep] * N + rows[keep]]))
    adj: list[set[int]] = [set() for _ in range(N)]
    for i, j in zip((pairs // N).tolist(), (pairs % N).tolist()):
        adj[i].add(j)
    alive = free.tolist()

    def fill(v: int) -> int:
        """Missing edges among the neighbours of v: pairs minus the edges already there."""
        nb = adj[v]
        present = sum(len(adj[a] & nb) for a in nb) // 2
        return len(nb) * (len(nb) - 1) // 2 - present

    key = {i: (fill(i), len(adj[i])) for i in range(N) if alive[i]}
    heap = [(k, i) for i, k in key.items()]
    heapq.heapify(heap)
    cliques: list[frozenset[int]] = []
    while heap:
        k, v = heapq.heappop(heap)
        if not alive[v] or key[v] != k:
            continue  # stale entry
        nb = list(adj[v])
        for i, a in enumerate(nb):
            adj[a].discard(v)
            for b in nb[i + 1:]:
                if b not in adj[a]:
                    adj[a].add(b)
                    adj[b].add(a)
        alive[v] = False
        cliques.append(frozenset([v, *nb]))
        touched = set(nb)
        for a in nb:
            touched |= adj[a]
        for u in touched:
            if alive[u]:
                key[u] = (fill(u), len(adj[u]))
                heapq.heappush(heap, (key[u], u))
    uniq = [np.array(sorted(c), dtype=np.int64) for c in dict.fromkeys(cliques)]
    uniq = [frozenset(c.tolist()) for c in maximal(uniq)]
    head = sorted(fixed)
    return [np.array(head + sorted(c), dtype=np.int64) for c in uniq]
