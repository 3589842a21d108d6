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
