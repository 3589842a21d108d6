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

from ..svec import stored_entries


def incidence(cliques: Sequence[np.ndarray], N: int | None = None) -> sp.csr_array:
    """(p × N) 0/1 clique-column incidence matrix."""
    sizes = [len(c) for c in cliques]
    cols = np.concatenate([np.asarray(c, np.int64) for c in cliques])
    N = int(cols.max()) + 1 if N is None else N
    return sp.csr_array((np.ones(cols.size), (np.repeat(np.arange(len(cliques)), sizes), cols)),
                        shape=(len(cliques), N))


def _overlaps(B: sp.csr_array) -> tuple[sp.csr_array, np.ndarray, np.ndarray]:
    """(O, every, count) of the p × N incidence B of cliques without repeated columns: O (p × p) the number of
    columns each pair of cliques shares outside the columns in every clique (``every``; h: a constant overlap of
    every pair, left out), count the cliques holding each column.  O is sparse: memory ∝ the pairs sharing such a
    column, not p²."""
    p = B.shape[0]
    count = np.asarray(B.sum(axis=0)).ravel()
    every = count == p
    Bs = B[:, np.flatnonzero(~every)] if every.any() else B
    return sp.csr_array(Bs @ Bs.T), every, count


def _tree(cliques: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, bool]:
    """(parent, order, running intersection) of a maximum-overlap spanning tree rooted at clique 0.

    parent[k] = −1 for the root; ``order`` lists every parent before its children.  The tree is a
    clique tree iff its weight (Σ overlaps) is Σ|C_k| − |∪C_k|, i.e. the running intersection property.
    """
    p = len(cliques)
    parent = np.full(p, -1, dtype=np.int64)
    if p <= 1:
        return parent, np.arange(p), True
    B = sp.csr_array(incidence(cliques))
    O, every, count = _overlaps(B)
    n_every = int(every.sum())
    W = sp.triu(O, k=1).tocoo()  # the overlap graph
    big = float(W.data.max()) + 1 if W.nnz else 1.0
    # max overlap; among equal overlaps the nearest clique index (penalty |i − j|/p² < 1/p per edge): cliques
    # sharing only one separator (pose averaging's {h, C, r}) form a chain, not a star whose root block every
    # transfer couples to (a dense Schur complement in the IPM: 21 GB at M = 300)
    i, j, w = W.row, W.col, W.data.astype(float)
    ci, cj = np.arange(p - 1), np.arange(1, p)  # neighbours by index: the common columns only (weight 0)
    i, j = np.concatenate([i, ci]), np.concatenate([j, cj])
    w = np.concatenate([w, np.zeros(p - 1)])
    cost = big + 1 - w + np.abs(i - j) / p ** 2
    T = minimum_spanning_tree(_min_duplicates(i, j, cost, p)).tocoo()
    if T.nnz != p - 1 or (n_every == 0 and not _connected_by_overlap(W, p)):
        raise ValueError("the cliques are not connected: no clique tree")
    order, pred = breadth_first_order(sp.csr_array((np.ones(T.nnz), (T.row, T.col)), shape=(p, p)), 0,
                                      directed=False)
    parent[1:] = pred[1:]
    overlap = np.rint(big + 1 - T.data + 0.0).astype(np.int64)  # w of each tree edge (penalty < 1 rounds away)
    weight = int(overlap.sum()) + n_every * (p - 1)
    union = int((count > 0).sum())
    return parent, order, weight == B.nnz - union


def _min_duplicates(i: np.ndarray, j: np.ndarray, cost: np.ndarray, p: int) -> sp.csr_array:
    """The p×p graph with the smallest cost of each (i, j) pair (COO→CSR would sum duplicates)."""
    key = i * p + j
    order = np.lexsort((cost, key))
    key, cost = key[order], cost[order]
    first = np.concatenate([[True], key[1:] != key[:-1]])
    return sp.csr_array((cost[first], (key[first] // p, key[first] % p)), shape=(p, p))


def _connected_by_overlap(W: sp.coo_array, p: int) -> bool:
    from scipy.sparse.csgraph import connected_components

    return connected_components(sp.csr_array((np.ones(W.nnz), (W.row, W.col)), shape=(p, p)), directed=False)[0] == 1


def has_running_intersection(cliques: Sequence[np.ndarray]) -> bool:
    try:
        return _tree(cliques)[2]
    except ValueError:
        return False  # not connected


def clique_tree(cliques: Sequence[np.ndarray]) -> np.ndarray:
    """parent[k] of every clique in a clique tree rooted at clique 0 (parent −1 for the root), so that
    the cliques holding any one column form a subtree.  ValueError when the cliques have no clique
    tree (not connected, or the running intersection property fails)."""
    parent, _, ok = _tree(cliques)
    if not ok:
        raise ValueError("the cliques do not form a clique tree (running intersection fails): "
                         "the decomposed SDP would be weaker than the dense one")
    return parent


def merge_small(cliques: Sequence[np.ndarray], max_size: int,
                tree: tuple[np.ndarray, np.ndarray, bool] | None = None) -> list[np.ndarray]:
    """Merge every clique into its clique-tree parent while their union has at most ``max_size`` columns.

    Merging a clique into its tree neighbour keeps a clique tree.  Fewer, larger blocks trade the
    interior-point cost of the blocks against that of the overlaps between them (see
    ``run.CliqueCovers`` for how the cap is chosen).  ``tree``: ``_tree(cliques)`` when known.
    """
    cl = [set(np.asarray(c).tolist()) for c in cliques]
    parent, bfs, _ = tree if tree is not None else _tree(cliques)
    depth = np.zeros(len(cl), np.int64)
    for k in bfs[1:]:
        depth[k] = depth[parent[k]] + 1
    alive = np.ones(len(cl), bool)
    for k in np.argsort(depth, kind="stable")[::-1]:  # deepest first: a clique's parent is still alive
        p = int(parent[k])
        if p >= 0 and len(cl[k] | cl[p]) <= max_size:
            cl[p] |= cl[k]
            alive[k] = False
    return [np.array(sorted(cl[k]), dtype=np.int64) for k in range(len(cl)) if alive[k]]


def merged_covers(cliques: Sequence[np.ndarray], caps: Sequence[int]) -> dict[int, list[np.ndarray]]:
    """{cap: ``merge_small(cliques, cap)``} for every cap, on one clique tree (cap 0: unmerged).

    A cap below every clique's union with its tree parent merges nothing: a clique and its parent only grow
    as others merge into them, so such a pair never merges later.  Those caps get ``cliques`` itself (one
    list object, unmerged), without the merging pass."""
    tree = _tree(cliques)
    parent = tree[0]
    child = np.flatnonzero(parent >= 0)
    smallest = np.inf
    if child.size:
        B = sp.csr_array(incidence(cliques))
        size = np.diff(B.indptr)
        overlap = np.asarray(B[child].multiply(B[parent[child]]).sum(axis=1)).ravel()
        smallest = float(np.min(size[child] + size[parent[child]] - overlap))
    unmerged = [np.array(sorted(set(np.asarray(c).tolist())), dtype=np.int64) for c in cliques]
    return {cap: unmerged if cap < smallest else merge_small(cliques, cap, tree) for cap in caps}


def maximal(cliques: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Drop cliques contained in another clique (keeps the first of equal ones), each kept one sorted
    without repeats (int64).

    Clique i lies in clique j exactly when they share |C_i| columns.  Columns in every clique add the same to
    each pair, so the shared counts are ``_overlaps`` (the other columns) plus those; a clique of such common
    columns only lies in every other clique."""
    p = len(cliques)
    if not p:
        return []
    owner = np.repeat(np.arange(p, dtype=np.int64), [np.size(c) for c in cliques])
    cols = np.concatenate([np.asarray(c, dtype=np.int64).ravel() for c in cliques])
    width = int(cols.max(initial=0)) + 1
    key = np.unique(owner * width + cols)  # each clique's distinct columns, sorted, clique by clique
    owner, cols = key // width, key % width
    size = np.bincount(owner, minlength=p)
    sets = np.split(cols, np.cumsum(size)[:-1])
    if p <= 1 or not size.any():
        return sets if p <= 1 else []  # an empty clique is contained in any other
    overlaps, every, _ = _overlaps(incidence(sets, width))
    rest = size - int(every.sum())
    O = sp.coo_array(overlaps)
    i, j = O.row, O.col
    inside = (i != j) & (O.data == rest[i]) & ((size[j] > size[i]) | ((size[j] == size[i]) & (j < i)))
    drop = np.zeros(p, dtype=bool)
    drop[i[inside]] = True
    common = np.flatnonzero(rest == 0)  # the smallest cliques possible: inside a larger one, or the first of equals
    drop[common if size.max() > size.min() else common[1:]] = True
    return [s for s, d in zip(sets, drop.tolist()) if not d]


def column_cliques(N: int, matrices: Sequence[sp.sparray], always: Sequence[int] = (0,)) -> list[np.ndarray]:
    """Cliques (column indices) of a chordal extension of the aggregate sparsity of ``matrices``
    (``entry_cliques`` of their ``nonzeros``)."""
    _, rows, cols = nonzeros(matrices)
    return entry_cliques(N, rows, cols, always)


def entry_cliques(N: int, rows: np.ndarray, cols: np.ndarray, always: Sequence[int] = (0,)) -> list[np.ndarray]:
    """Cliques (column indices) of a chordal extension of the pattern with entries (rows, cols).

    Columns i ≠ j are adjacent when some entry is at (i, j) or (j, i).  The ``always`` columns (h)
    touch everything; they are left out of the graph and added to every clique.  Greedy
    minimum-fill elimination gives the chordal extension; its elimination cliques, kept maximal,
    form a clique tree.
    """
    import heapq

    fixed = set(int(a) for a in always)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    free = np.ones(N, bool)
    free[list(fixed)] = False
    keep = (rows != cols) & free[rows] & free[cols]
    edges = np.unique(np.minimum(rows[keep], cols[keep]) * N + np.maximum(rows[keep], cols[keep]))  # i < j
    pairs = np.unique(np.concatenate([edges, (edges % N) * N + edges // N]))  # both orientations, sorted
    starts = np.searchsorted(pairs, np.arange(N + 1) * N).tolist()  # each vertex's neighbours, increasing
    nbrs = (pairs % N).tolist()
    adj: list[set[int]] = [set(nbrs[starts[i]:starts[i + 1]]) for i in range(N)]
    alive = free.tolist()

    def fill(v: int) -> int:
        """Missing edges among the neighbours of v: pairs minus the edges already there."""
        nb = adj[v]
        present = sum(len(adj[a] & nb) for a in nb) // 2
        return len(nb) * (len(nb) - 1) // 2 - present

    key = {i: (fill(i), len(adj[i])) for i in range(N) if alive[i]}
    heap = [(k, i) for i, k in key.items()]
    heapq.heapify(heap)
    cliques: list[tuple[int, list[int]]] = []  # (v, its neighbours when eliminated), in elimination order
    while heap:
        k, v = heapq.heappop(heap)
        if not alive[v] or key[v] != k:
            continue  # stale entry
        nb = list(adj[v])
        if k[0] == 0:  # simplicial: nb is a clique, no edge to add
            _eliminate_simplicial(v, nb, adj, key, heap)
            alive[v] = False
            cliques.append((v, nb))
            continue
        added = []
        for i, a in enumerate(nb):
            adj[a].discard(v)
            for b in nb[i + 1:]:
                if b not in adj[a]:
                    adj[a].add(b)
                    adj[b].add(a)
                    added.append((a, b))
        alive[v] = False
        cliques.append((v, nb))
        # fill changes for v's neighbours (they lost v) and for the common neighbours of the
        # endpoints of each added edge (that pair is no longer missing); nobody else's
        touched = set(nb)
        for a, b in added:
            touched |= adj[a] & adj[b]
        for u in touched:
            if alive[u]:
                key[u] = (fill(u), len(adj[u]))
                heapq.heappush(heap, (key[u], u))
    head = sorted(fixed)
    return [np.array(head + sorted([v, *nb]), dtype=np.int64) for v, nb in elimination_maximal(cliques)]


def _eliminate_simplicial(v: int, nb: list[int], adj: list[set[int]], key: dict[int, tuple[int, int]],
                          heap: list[tuple[tuple[int, int], int]]) -> None:
    """Remove v, whose neighbours ``nb`` form a clique, from the graph ``adj``, and push the new (fill, degree)
    key of each neighbour u.  Its missing pairs lose those with v, one per neighbour of u outside nb ∪ {v}
    (nb ∖ {u} ⊆ adj[u]): fill − (deg(u) − |nb|), without recounting."""
    import heapq

    for u in nb:
        adj[u].discard(v)
        key[u] = (key[u][0] - (len(adj[u]) + 1 - len(nb)), len(adj[u]))
        heapq.heappush(heap, (key[u], u))


def elimination_maximal(cliques: Sequence[tuple[int, list[int]]]) -> list[tuple[int, list[int]]]:
    """The maximal ones of the elimination cliques {v} ∪ N⁺(v) of a perfect elimination ordering (given in
    that order, N⁺(v) the neighbours of v eliminated after it), in the same order.

    Such a clique is contained in another exactly when some u has v as its parent (the first of N⁺(u) to be
    eliminated) and |N⁺(u)| = |N⁺(v)| + 1: then N⁺(u) = {v} ∪ N⁺(v) (N⁺(u) ∖ {v} ⊆ N⁺(v) by the perfect
    ordering).  Linear in the cliques' sizes, where the pairwise test of ``maximal`` is not."""
    order = {v: k for k, (v, _) in enumerate(cliques)}
    size = {v: len(nb) for v, nb in cliques}
    inside: set[int] = set()
    for _, nb in cliques:
        if nb:
            parent = min(nb, key=order.__getitem__)
            if len(nb) == size[parent] + 1:
                inside.add(parent)
    return [(v, nb) for v, nb in cliques if v not in inside]


def block_cliques(sizes: Sequence[int], rows: np.ndarray, cols: np.ndarray) -> list[np.ndarray]:
    """``entry_cliques`` on the graph of variable blocks, expanded to columns.

    ``sizes`` (nb,): the block sizes in column order; block 0 (h) is in every clique.  Two blocks
    are adjacent when an entry (rows, cols) couples a column of one with a column of the other.
    Eliminating whole blocks keeps a block's columns together, so separators are unions of blocks
    (continuous time: {h, ξ_{k+1,k}, ϖ_{k+1}}), and the graph is about 30× smaller than the
    columns' graph."""
    edges = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    block = np.repeat(np.arange(len(sizes), dtype=np.int64), sizes)  # column → its block: a gather, not a search
    br, bc = block[np.asarray(rows, np.int64)], block[np.asarray(cols, np.int64)]
    cliques = entry_cliques(len(sizes), br, bc, always=(0,))
    if not cliques:
        return []
    blocks = np.concatenate(cliques)  # every clique's blocks in turn, each block expanded to its columns at once
    width = edges[blocks + 1] - edges[blocks]
    first = np.cumsum(width) - width  # each block's first position in the expansion
    columns = np.arange(int(width.sum()), dtype=np.int64) + np.repeat(edges[blocks] - first, width)
    count = np.array([len(cl) for cl in cliques])
    per_clique = np.add.reduceat(width, np.cumsum(count) - count)  # each clique's columns
    return [c.copy() for c in np.split(columns, np.cumsum(per_clique)[:-1])]


def nonzeros(matrices: Sequence[sp.sparray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(matrix index, row, column) of the stored upper-triangle entries (row ≤ column) of a list of
    symmetric sparse matrices."""
    if not len(matrices):
        return (np.zeros(0, np.int64),) * 3
    rows, cols, _, owner = stored_entries(matrices)  # one pass, no per-matrix arrays but the stored ones
    keep = rows <= cols
    return owner[keep].astype(np.int64), rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def support_matrix(rows: np.ndarray, cols: np.ndarray, owner: np.ndarray, N: int, m: int) -> sp.csr_array:
    """(N × m) 0/1: column j appears in constraint i, from the entries (rows, cols) of constraint ``owner``."""
    S = sp.csr_array((np.ones(2 * owner.size), (np.concatenate([rows, cols]), np.concatenate([owner, owner]))),
                     shape=(N, m))
    S.data[:] = 1.0  # duplicates summed: back to 0/1
    return S


def column_support(matrices: Sequence[sp.sparray], N: int) -> sp.csr_array:
    """``support_matrix`` of a list of symmetric sparse matrices."""
    owner, rows, cols = nonzeros(matrices)
    return support_matrix(rows, cols, owner, N, len(matrices))


#: the most hub counts (patterns × constraints) ``home_cliques`` holds; beyond, hub columns go through the sparse
#: product like the others
HUB_COUNTS_MAX = 50_000_000


def home_cliques(cliques: Sequence[np.ndarray], support: sp.csr_array) -> np.ndarray:
    """(m,) each constraint's home clique: the one holding most of its columns (the lowest index on
    ties), from ``support`` (see ``support_matrix``).

    count_k(i) = |cols(i) ∩ C_k| splits over three kinds of column.  Columns in every clique (h) add the same to
    every k: left out.  Hub columns (in at least half of the cliques: the pose of pose averaging) add
    |cols(i) ∩ H ∩ C_k|, which depends on k only through its hub pattern C_k ∩ H, of which there are few.  The
    rest give a sparse p × m product R.  So the maximum over k is the larger of the best clique with R_ki > 0
    (R + the hub count of its pattern, by segmented reductions over R's columns) and, per pattern, the hub count
    at its lowest clique (a clique of the pattern with R_ki > 0 counts more, so one without can only win when
    the lowest has none).  Memory and time ∝ nnz(R) + patterns × m, where the
    full product is nearly dense with a hub (p × m: 24 GB at pose averaging M = 10 000)."""
    m = support.shape[1]
    if m == 0:
        return np.zeros(0, np.int64)
    p = len(cliques)
    B = sp.csc_array(incidence(cliques, support.shape[0]))
    held = np.diff(B.indptr)  # cliques holding each column
    hub = (2 * held >= p) & (held < p)
    pattern_of, hub_count = np.zeros(p, np.int64), np.zeros((1, m), np.int64)
    if hub.any():
        patterns, inverse = np.unique(B[:, np.flatnonzero(hub)].toarray() > 0, axis=0, return_inverse=True)
        if len(patterns) * m <= HUB_COUNTS_MAX:
            pattern_of = inverse.ravel()
            hub_count = np.asarray((sp.csr_array(patterns.astype(np.float64))
                                    @ sp.csr_array(support[np.flatnonzero(hub)])).toarray(), np.int64)
        else:  # too many patterns to hold their counts: every column through the sparse product
            hub[:] = False
    rest = (held > 0) & ~hub & (held < p)
    R = sp.csc_array(sp.csr_array(B[:, np.flatnonzero(rest)]) @ support[np.flatnonzero(rest)])
    R.sum_duplicates()
    R.sort_indices()
    counts = np.diff(R.indptr)
    col = np.repeat(np.arange(m), counts)
    value = R.data.astype(np.int64) + hub_count[pattern_of[R.indices], col]
    best = np.full(m, -1, np.int64)
    home = np.zeros(m, np.int64)
    filled = np.flatnonzero(counts > 0)
    if filled.size:
        starts = R.indptr[filled]
        best[filled] = np.maximum.reduceat(value, starts)
        at_best = np.where(value == np.repeat(best[filled], counts[filled]), R.indices, np.iinfo(np.int64).max)
        home[filled] = np.minimum.reduceat(at_best, starts)
    # per pattern: its lowest clique at the pattern's hub count.  When that clique has rest columns of i, its
    # count is higher and it is among the filled ones already, which then beat every clique of the pattern
    first = np.full(hub_count.shape[0], p, np.int64)
    np.minimum.at(first, pattern_of, np.arange(p))
    for q in range(hub_count.shape[0]):
        v, k = hub_count[q], first[q]
        better = (v > best) | ((v == best) & (k < home))
        best[better], home[better] = v[better], k
    return home


def block_incidence(cliques: Sequence[np.ndarray], support: sp.csr_array) -> tuple[list[np.ndarray], int]:
    """(inc, M): the constraints of the decomposed SDP that touch each clique block, estimated, and their
    number.  Constraint i (a column of ``support``) touches its ``home_cliques`` block and the top clique
    (the one nearest the tree's root) of each of its columns that the home block lacks: where
    ``clique_program`` places such entries, so that a constraint that spills couples its blocks in the
    Schur complement.  Each clique-tree edge adds svec(|C_k ∩ C_parent|) transfer constraints, ids from m
    on, touching both of its ends.  Columns in every clique (h) are left out."""
    p, m = len(cliques), support.shape[1]
    B = sp.csr_array(incidence(cliques, support.shape[0]))
    home = home_cliques(cliques, support)
    parent, order, ok = _tree(cliques)
    if not ok:
        clique_tree(cliques)  # raises: no clique tree
    pairs = [np.arange(m) * p + home]
    if p > 1:
        pairs.append(_spills(B, order, home, support))
    child = np.flatnonzero(parent >= 0)
    overlap = np.asarray(B[child].multiply(B[parent[child]]).sum(axis=1)).ravel().astype(np.int64)
    count = overlap * (overlap + 1) // 2
    ids = m + np.arange(int(count.sum()))
    edge = np.repeat(np.arange(child.size), count)
    pairs += [ids * p + child[edge], ids * p + parent[child][edge]]
    # no pair twice: a spill goes to a clique other than the home one, transfers are new ids
    key = np.concatenate(pairs)
    total = m + int(count.sum())
    by_block = sp.csr_array((np.ones(key.size, np.int8), (key % p, key // p)), shape=(p, total))  # grouped in C
    return np.split(by_block.indices.astype(np.int64), by_block.indptr[1:-1]), total


def _spills(B: sp.csr_array, order: np.ndarray, home: np.ndarray, support: sp.csr_array) -> np.ndarray:
    """Keys i·p + k: constraint i spills into block k, the top clique of a column of i outside its home
    clique (columns in every clique excluded)."""
    p, N = B.shape
    rank = np.empty(p, np.int64)
    rank[order] = np.arange(p)  # BFS rank: a parent before its children
    Bc = sp.csc_array(B)
    top = np.full(N, -1, np.int64)
    held = np.flatnonzero(np.diff(Bc.indptr))
    best = np.minimum.reduceat(rank[Bc.indices], Bc.indptr[held])
    top[held] = order[best]
    every = np.diff(Bc.indptr) == p
    coo = sp.coo_array(support)  # (column c, constraint i)
    c, i = coo.row, coo.col
    out = (np.asarray(B[home[i], c]).ravel() == 0) & ~every[c]
    return np.unique(i[out] * p + top[c[out]])
