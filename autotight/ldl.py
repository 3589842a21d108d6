"""Sparse symmetric LDLᵀ without pivoting (qdldl, Apache-2.0: AMD ordering, then the numeric factorisation).

For matrices whose LDLᵀ exists under any symmetric ordering: quasi-definite ones ([[A, Bᵀ], [B, −C]] with
A, C positive definite) and, for an inertia count by Sylvester's law, symmetric ones whose factorisation
does not break down.  On chain-like patterns the AMD ordering keeps the fill linear in the chain's
length; SuperLU in symmetric mode (``MMD_AT_PLUS_A``) took 30× longer on the same matrices
(discrete trajectory K = 3000: the minimum-norm KKT matrix of 180 000 rows, 8.7 s against 0.27 s).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class SymmetricLDL:
    """P A Pᵀ = (I + L) D (I + L)ᵀ of a symmetric sparse A (only its upper triangle is read).

    ``solve(b)``: A⁻¹ b for b (n,).  ``pivots``: D (n,), whose signs are A's inertia.  Raises
    RuntimeError (qdldl's own) when a pivot is exactly zero or a diagonal entry is not stored: the
    factorisation breaks down."""

    def __init__(self, A: sp.sparray):
        import qdldl

        upper = sp.triu(sp.csc_matrix(A), format="csc")
        upper.sort_indices()
        self._solver = qdldl.Solver(upper, upper=True)
        self.shape = upper.shape

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._solver.solve(np.asarray(b, dtype=float))

    @property
    def pivots(self) -> np.ndarray:
        return np.asarray(self._solver.factors()[1])
