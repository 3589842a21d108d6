"""Which clique cover a decomposed solve runs on: candidate covers and the choice per cover policy.

A backend names its policy (``Backend.cover``): "clarabel" (Clarabel's dense KKT blocks, cost
Σ_k svec(|C_k|)³) or "ipm" (our Schur-complement IPM, cost ``schur_ipm.iteration_cost``).
"""

from __future__ import annotations

from functools import cached_property
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..svec import svec_dim
from .chordal import (block_cliques, block_incidence, clique_tree, entry_cliques, incidence, merged_covers,
                      nonzeros, support_matrix)

#: largest clique that small neighbouring cliques are merged into for Clarabel (see ``chordal.merge_small``)
MERGE_MAX_SIZE = 20
#: merging caps tried for our IPM, whose cost per block grows more slowly with the block size
IPM_MERGE_CAPS = (16, 20, 24, 28, 32, 40, 48)
#: the cover policies ``CliqueCovers.choose`` knows
POLICIES = ("clarabel", "ipm")


class CliqueCovers:
    """Candidate clique covers of one SDP (the first d columns, h, in every clique) and the choice
    per policy.

    Candidates: the min-fill chordal cover of Q and the constraints (``chordal.entry_cliques``),
    the min-fill cover of the graph of variable blocks (``chordal.block_cliques``, when the block
    sizes are known), each with small neighbours merged, and the model's own cover (``hint``) when
    it gives one.  For "clarabel" both covers merged up to ``MERGE_MAX_SIZE`` columns and the hint
    are compared by the interior-point cost estimate Σ_k svec(|C_k|)³; for "ipm" the block cover
    (the column cover when the block sizes are not known) and the model's cover, each unmerged and merged
    at every cap in ``IPM_MERGE_CAPS``, are the candidates, compared by ``schur_ipm.iteration_cost`` on
    the Schur complement each would give (``chordal.block_incidence``).
    The block cover keeps blocks whole, so its separators are unions of blocks: on continuous time
    (ϖ kept) {h, ξ_{k+1,k}, ϖ_{k+1}} rather than a whole pose.

    ValueError when the hint is not a clique tree holding every nonzero of the data.
    """

    def __init__(self, Q: sp.sparray, As: Sequence[sp.sparray], d: int = 1,
                 block_sizes: Sequence[int] | None = None, hint: Sequence[np.ndarray] | None = None):
        N = Q.shape[0]
        owner, rows, cols = nonzeros([Q, *As])  # one pass over the data
        caps = tuple(sorted({MERGE_MAX_SIZE, *IPM_MERGE_CAPS}))
        self._entries = (N, rows, cols, d, caps)  # for ``columns``, built on first use
        #: {cap: cover} for each base cover (cap 0: unmerged), on one clique tree per base
        self.blocks = merged_covers(block_cliques(block_sizes, rows, cols), (0,) + caps) if block_sizes else {}
        self.own: list[list[np.ndarray]] = []
        if hint is not None:
            own = [np.asarray(c, np.int64) for c in hint]
            _check_cover(own, N, rows, cols)
            self.own = [own]
        con = owner > 0  # (N × m) the columns of each constraint (owner 0 is Q)
        self.support = support_matrix(rows[con], cols[con], owner[con] - 1, N, len(As))

    @cached_property
    def columns(self) -> dict[int, list[np.ndarray]]:
        """{cap: cover} of the min-fill column cover, merged (cap 0 is not built).  Built on first use:
        the IPM does without it when the block sizes are known (discrete K = 1000: 6 s of min-fill)."""
        N, rows, cols, d, caps = self._entries
        return merged_covers(entry_cliques(N, rows, cols, always=range(d)), caps)

    @cached_property
    def own_merged(self) -> dict[int, list[np.ndarray]]:
        """{cap: cover} of the model's own cover, merged at every cap of ``IPM_MERGE_CAPS`` (cap 0: as given)."""
        return merged_covers(self.own[0], (0,) + IPM_MERGE_CAPS) if self.own else {}

    def choose(self, policy: str = "clarabel") -> list[np.ndarray]:
        from .schur_ipm import iteration_cost

        if policy == "clarabel":
            covers = [self.columns[MERGE_MAX_SIZE]] + ([self.blocks[MERGE_MAX_SIZE]] if self.blocks else []) + self.own
            return min(covers, key=lambda cl: sum(float(svec_dim(len(c))) ** 3 for c in cl))
        if policy != "ipm":
            raise ValueError(f"unknown cover policy {policy!r}; use one of {POLICIES}")
        # the block covers when the variable blocks are known: a column cover splits blocks, so most
        # constraints spill out of their home clique and couple blocks far apart in the tree
        # (pose averaging M = 200: 3197 of 3207 constraints at cap 16, estimated cheapest and 6× slower
        # per iteration than the block cover at cap 32; 268 spill from the block cover at cap 24)
        candidates = ([self.blocks[c] for c in (0,) + IPM_MERGE_CAPS] if self.blocks
                      else [self.columns[c] for c in IPM_MERGE_CAPS]) + list(self.own_merged.values())
        unique: dict[tuple, list[np.ndarray]] = {}  # equal covers (caps that merge nothing more) once
        seen: set[int] = set()  # caps below every merge share one list object (``chordal.merged_covers``)
        for cl in candidates:
            if id(cl) not in seen:
                seen.add(id(cl))
                unique.setdefault(tuple(tuple(c.tolist()) for c in cl), cl)
        return min(list(unique.values()),
                   key=lambda cl: iteration_cost([len(c) for c in cl], *block_incidence(cl, self.support)))


def _check_cover(cover: list[np.ndarray], N: int, rows: np.ndarray, cols: np.ndarray) -> None:
    """ValueError unless ``cover`` is a clique tree of columns in [0, N) holding every entry (rows, cols)."""
    if not cover or any(c.size == 0 or c.min() < 0 or c.max() >= N for c in cover):
        raise ValueError(f"the clique cover hint must be non-empty index arrays in [0, {N})")
    inc = incidence(cover, N).astype(bool)
    count = np.asarray(inc.sum(axis=0)).ravel()  # cliques holding each column
    # an entry with a column in every clique (h) is held iff its other column is in some clique; the rest by
    # the clique-incidence product (h's full column in that product was quadratic: 10 GB at K = 1000)
    every = (count[rows] == len(cover)) | (count[cols] == len(cover))
    held = np.where(every, (count[rows] > 0) & (count[cols] > 0), False)
    rest = np.flatnonzero(~every)
    if rest.size:
        held[rest] = np.asarray((inc[:, rows[rest]].multiply(inc[:, cols[rest]])).sum(axis=0)).ravel() > 0
    if not np.all(held):
        raise ValueError(f"the clique cover hint misses {int((~held).sum())} nonzero entries of the cost or "
                         "constraints")
    clique_tree(cover)  # ValueError unless the cliques form a clique tree
