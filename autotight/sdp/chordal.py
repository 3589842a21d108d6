"""Checks that a clique cover gives an exact decomposition of X ⪰ 0.

For cliques C_1 … C_p of a chordal pattern, X ⪰ 0 completable ⟺ X[C_k, C_k] ⪰ 0 for all k
(Grone et al. 1984).  The cliques must form a clique tree: they satisfy the running
intersection property iff a maximum-weight spanning tree of the clique-intersection graph
has weight Σ|C_k| − |∪C_k|.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import minimum_spanning_tree


def has_running_intersection(cliques: Sequence[np.ndarray]) -> bool:
    sets = [set(np.asarray(c).tolist()) for c in cliques]
    p = len(sets)
    if p <= 1:
        return True
    big = sum(len(s) for s in sets) + 1
    rows, cols, w = [], [], []
    for i in range(p):
        for j in range(i + 1, p):
            k = len(sets[i] & sets[j])
            if k:
                rows.append(i); cols.append(j); w.append(big - k)  # minimum of big − k = maximum of k
    if not rows:
        return False
    G = sp.csr_array((w, (rows, cols)), shape=(p, p))
    T = minimum_spanning_tree(G).tocoo()
    if T.nnz != p - 1:
        return False  # the cliques are not connected
    weight = sum(big - v for v in T.data)
    union = set().union(*sets)
    return int(round(weight)) == sum(len(s) for s in sets) - len(union)


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
    adj: list[set[int]] = [set() for _ in range(N)]
    for A in matrices:
        U = sp.coo_array(A)
        for i, j in zip(U.row.tolist(), U.col.tolist()):
            if i != j and i not in fixed and j not in fixed:
                adj[i].add(j)
                adj[j].add(i)
    alive = [i not in fixed for i in range(N)]

    def fill(v: int) -> int:
        nb = list(adj[v])
        return sum(1 for i, a in enumerate(nb) for b in nb[i + 1:] if b not in adj[a])

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
    keep = [c for c in cliques if not any(c < d for d in cliques if len(d) > len(c))]
    uniq = list(dict.fromkeys(keep))
    head = sorted(fixed)
    return [np.array(head + sorted(c), dtype=np.int64) for c in uniq]
