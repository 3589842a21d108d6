"""Comparing a problem's model with a reference build of it: the same layout, cost and constraint spans."""

from __future__ import annotations

import numpy as np


def assert_same_layout(new, old) -> None:
    """Same lifted vector (block names, sizes, order), factors (types, blocks, roles; the names after the first),
    cost matrix to rounding and cost offset."""
    assert [(b, new.variables.sizes[b]) for b in new.variables.names] == \
        [(b, old.variables.sizes[b]) for b in old.variables.names]
    assert [(f.type, f.blocks, f.roles) for f in new.factors] == [(f.type, f.blocks, f.roles) for f in old.factors]
    assert [f.name for f in new.factors[1:]] == [f.name for f in old.factors[1:]]
    assert abs(new.Q - old.Q).max() <= 1e-14 * abs(old.Q).max()
    assert new.cost_offset == old.cost_offset


def assert_same_span(new, old) -> None:
    """Two lists of constraints spanning the same space (the rank of each = the rank of both stacked = their
    count)."""
    A = np.array([c.A.toarray().ravel() for c in new])
    B = np.array([c.A.toarray().ravel() for c in old])
    assert len(A) == len(B) and np.linalg.matrix_rank(A) == np.linalg.matrix_rank(B) == \
        np.linalg.matrix_rank(np.vstack([A, B])) == len(B)
