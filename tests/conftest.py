"""Shared fixtures for the foundation tests (svec/model, SDP, rotation averaging, CLI).

Every random quantity in these tests comes from an explicit ``numpy.random.Generator`` created
in the test with a stated seed; nothing here touches the global NumPy RNG.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import norm as sparse_norm

from autotight.problem import Problem, load


@pytest.fixture(scope="session")
def ra() -> Problem:
    """The rotation-averaging problem module (paper §3.1)."""
    return load("rotation_averaging")


@pytest.fixture(scope="session")
def relative_violation():
    """|⟨A, X⟩ − b| / (‖A‖_F ‖X‖_F): a constraint's residual relative to what could cancel in it.

    By Cauchy-Schwarz |⟨A, X⟩| ≤ ‖A‖_F ‖X‖_F, so this is the residual measured against the
    largest value the inner product could take on this X; rounding alone gives ~1e-16.
    """

    def f(A: sp.sparray, b: float, X: np.ndarray) -> float:
        A = sp.csr_array(A)
        val = float(A.multiply(X).sum())
        return abs(val - b) / (sparse_norm(A) * np.linalg.norm(X))

    return f


@pytest.fixture(scope="session")
def lifted_violations():
    """|xᵀAx − b| / (‖A‖_F ‖xxᵀ‖_F) of each constraint at lifted points: x (N,) → (m,); a stack of
    samples (S, N) → (S, m) (one sparse product per constraint for the whole stack).  The same
    Cauchy-Schwarz scale as ``relative_violation``: rounding alone gives ~1e-16."""

    def f(constraints, x: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(x, dtype=float))
        sq = np.einsum("sn,sn->s", X, X)
        out = np.array([np.abs(np.einsum("sn,sn->s", X, (c.A @ X.T).T) - c.b) / (sparse_norm(c.A) * sq)
                        for c in constraints]).T
        return out.reshape(np.shape(x)[:-1] + (len(constraints),))

    return f


@pytest.fixture(scope="session")
def factor_cliques():
    """Clique index sets of a model: one per factor, the factor's own blocks (each starts with h).

    Factors whose blocks are contained in another factor's are dropped (their entries are
    covered).  For rotation averaging these are {h, c1, c2, c3, phi_m}, m = 1..M.
    """

    def f(model) -> list[np.ndarray]:
        sets = [tuple(fa.blocks) for fa in model.factors]
        keep = [s for s in sets if not any(set(s) < set(t) for t in sets)]
        uniq = list(dict.fromkeys(keep))
        return [model.variables.index(s) for s in uniq]

    return f
