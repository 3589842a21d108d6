"""Affine vector expressions in the blocks of a vector lifting, for writing constraints as in the paper.

``Affine`` is u = Σ_b M_b x_b with h among the blocks, so a constant v is ``const(v)`` = v·h.
``quad(V, u, w, L)`` gives the sparse symmetric A with xᵀAx = uᵀ L w.  For example the Cayley
relation  c − c̃ − ½ φ × (c + c̃) = 0  becomes three quadratic forms (``cross_rows``).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np
import scipy.sparse as sp

from .model import HOMOGENISING, QuadForm, Variables

# LEVI[k] is the 3×3 matrix L_k with (a × b)_k = aᵀ L_k b
LEVI = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    LEVI[_k, _i, _j], LEVI[_k, _j, _i] = 1.0, -1.0


class Affine:
    """u = Σ_b M_b x_b, an r-vector affine in the lifted blocks (h carries constants)."""

    __array_ufunc__ = None  # let numpy defer L @ u and s * u to us

    def __init__(self, terms: dict[str, np.ndarray] | None = None, rows: int | None = None):
        self.terms: dict[str, np.ndarray] = {}
        self.rows = rows
        for b, M in (terms or {}).items():
            self._add(b, np.atleast_2d(np.asarray(M, float)))

    def _add(self, b: str, M: np.ndarray) -> None:
        if self.rows is None:
            self.rows = M.shape[0]
        if M.shape[0] != self.rows:
            raise ValueError(f"affine rows {M.shape[0]} ≠ {self.rows}")
        self.terms[b] = self.terms[b] + M if b in self.terms else M.copy()

    def __add__(self, other: "Affine") -> "Affine":
        out = Affine(self.terms, self.rows)
        for b, M in other.terms.items():
            out._add(b, M)
        return out

    def __neg__(self) -> "Affine":
        return Affine({b: -M for b, M in self.terms.items()}, self.rows)

    def __sub__(self, other: "Affine") -> "Affine":
        return self + (-other)

    def __rmul__(self, s: float) -> "Affine":
        return Affine({b: s * M for b, M in self.terms.items()}, self.rows)

    def __rmatmul__(self, L: np.ndarray) -> "Affine":
        """L @ u for a constant matrix L."""
        L = np.atleast_2d(L)
        return Affine({b: L @ M for b, M in self.terms.items()}, L.shape[0])

    def row(self, k: int) -> "Affine":
        return Affine({b: M[k:k + 1] for b, M in self.terms.items()}, 1)


def var(block: str, M: np.ndarray | None = None, size: int = 3) -> Affine:
    """M x_block (M = I by default)."""
    return Affine({block: np.eye(size) if M is None else M})


def const(v: np.ndarray | float) -> Affine:
    """The constant vector v, as v·h."""
    return Affine({HOMOGENISING: np.asarray(v, float).reshape(-1, 1)})


H = const(1.0)


def quad(V: Variables, u: Affine, w: Affine, L: np.ndarray | None = None,
         into: QuadForm | None = None) -> QuadForm:
    """Add uᵀ L w (L = I by default) to ``into`` (a new QuadForm if None)."""
    qf = into or QuadForm(V)
    L = np.eye(u.rows or 1) if L is None else np.atleast_2d(L)
    for a, Ma in u.terms.items():
        for b, Mb in w.terms.items():
            qf.add(a, b, Ma.T @ L @ Mb)
    return qf


def linear(V: Variables, u: Affine) -> QuadForm:
    """A scalar affine u (1 row) as the quadratic form h·u."""
    return quad(V, H, u)


def cross_rows(V: Variables, phi: Affine, u: Affine) -> list[QuadForm]:
    """The three quadratic forms (φ × u)_k, k = 0, 1, 2."""
    return [quad(V, phi, u, LEVI[k]) for k in range(3)]


def cayley_rows(V: Variables, phi: str, a: Affine, b: Affine, rho: Affine | None = None,
                gate: Affine | None = None) -> list[sp.csr_array]:
    """a − b − ½ φ × (a + b) − ρ = 0, as three sparse symmetric matrices (one per component).

    gate: a scalar affine g (1 row); the rows are then multiplied by g, with the blocks ``phi`` and ρ
    standing for g·φ and g·ρ: g (a − b) − ½ (gφ) × (a + b) − gρ = 0 (still quadratic).
    """
    g = H if gate is None else gate
    out = []
    for k in range(3):
        qf = quad(V, g, (a - b).row(k))
        if rho is not None:
            quad(V, H, (-rho).row(k), into=qf)
        quad(V, var(phi), a + b, -0.5 * LEVI[k], into=qf)
        out.append(qf.matrix())
    return out


def sum_quads(V: Variables, parts: Iterable[tuple[Affine, Affine, np.ndarray | None]]) -> sp.csr_array:
    """Σ uᵀ L w over (u, w, L) triples, as one sparse matrix."""
    qf = QuadForm(V)
    for u, w, L in parts:
        quad(V, u, w, L, into=qf)
    return qf.matrix()
