"""The manifolds a factor-graph variable lives on, with their embedding in the lifted vector.

A manifold fixes, for one variable value x:

- ``shape``: the shape of x as the state holds it; ``size``: the length of its embedding v = embed(x), the
  variable's main block of the lifting (a linear map of x's ambient entries);
- ``embed(x) -> v`` and ``unembed(v) -> ambient array`` (linear, inverse to each other; ``unembed`` of a
  vector off the manifold is still an array of ``shape``), ``project(ambient) -> x`` (the nearest point);
- ``dof`` and ``retract(x, ε) -> x'`` (ε of length ``dof``), ``tangent(x)``: ∂ embed(retract(x, ε))/∂ε at
  ε = 0, (size, dof);
- ``constraints()``: the quadratic equations of the embedding, each an (1 + size) × (1 + size) symmetric
  matrix M with [h; v]ᵀ M [h; v] = 0 on the manifold (h the homogenising entry), with a name.

``Euclidean(n)``: x ∈ Rⁿ (shape (n,)), v = x, x ← x + ε, no equations.
``Rotation(d)``: C ∈ SO(d), d ∈ {2, 3} (shape (d, d)), v = vec C (columns stacked), C ← exp(ε^∧) C (left
perturbation; ε has 1 entry in 2-D, 3 in 3-D), equations c_iᵀc_j = δ_ij h² (i ≤ j; the determinant is
dropped, as in the problems of the paper: O(d), and ``project`` returns det +1).
``Binary()``: a label w ∈ {−1, +1} (shape ()), v = [w], equation w² = h² (named "w²"); discrete: no
retraction (dof 0: the local solver and the sampler leave it where it is), ``project`` its sign (0 → +1).
``Binary(equation=False)``: the same label without an equation, for a factor that declares w² = h² among its own
constraints (e.g. a measurement's, in the order its saved sets know).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..errors import ProblemDefinitionError
from ..lie import exp_so3, hat


class Manifold(Protocol):
    """What the factor-graph layer needs of a variable's manifold (see the module docstring)."""

    shape: tuple[int, ...]
    size: int
    dof: int

    def embed(self, x: np.ndarray) -> np.ndarray: ...

    def unembed(self, v: np.ndarray) -> np.ndarray: ...

    def project(self, a: np.ndarray) -> np.ndarray: ...

    def retract(self, x: np.ndarray, eps: np.ndarray) -> np.ndarray: ...

    def tangent(self, x: np.ndarray) -> np.ndarray: ...

    def constraints(self) -> list[tuple[str, np.ndarray]]: ...


class Euclidean:
    """Rⁿ: the value itself is the main block."""

    def __init__(self, n: int):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ProblemDefinitionError(f"Euclidean(n) needs a positive integer n, got {n!r}")
        self.shape, self.size, self.dof = (int(n),), int(n), int(n)

    def __repr__(self) -> str:
        return f"Euclidean({self.size})"

    def embed(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float).reshape(self.size)

    def unembed(self, v: np.ndarray) -> np.ndarray:
        return np.asarray(v, float).reshape(self.shape)

    def project(self, a: np.ndarray) -> np.ndarray:
        return self.unembed(a)

    def retract(self, x: np.ndarray, eps: np.ndarray) -> np.ndarray:
        return np.asarray(x, float) + np.asarray(eps, float).reshape(self.shape)

    def tangent(self, x: np.ndarray) -> np.ndarray:
        return np.eye(self.size)

    def constraints(self) -> list[tuple[str, np.ndarray]]:
        return []


def _generators(d: int) -> np.ndarray:
    """(dof, d, d): the generators G_k of so(d), exp(ε^∧) = exp(Σ ε_k G_k)."""
    if d == 2:
        return np.array([[[0.0, -1.0], [1.0, 0.0]]])
    return np.array([hat(e) for e in np.eye(3)])


class Rotation:
    """SO(d), d ∈ {2, 3}, embedded as vec C (columns stacked)."""

    def __init__(self, d: int):
        if d not in (2, 3):
            raise ProblemDefinitionError(f"Rotation(d) needs d = 2 or 3, got {d!r}")
        self.d = int(d)
        self.shape, self.size, self.dof = (self.d, self.d), self.d * self.d, 1 if d == 2 else 3
        self._G = _generators(self.d)

    def __repr__(self) -> str:
        return f"Rotation({self.d})"

    def embed(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float).reshape(self.shape).ravel(order="F")

    def unembed(self, v: np.ndarray) -> np.ndarray:
        return np.asarray(v, float).reshape(self.shape, order="F")

    def project(self, a: np.ndarray) -> np.ndarray:
        U, _, Vt = np.linalg.svd(np.asarray(a, float).reshape(self.shape))
        D = np.ones(self.d)
        D[-1] = np.sign(np.linalg.det(U @ Vt)) or 1.0
        return (U * D) @ Vt

    def exp(self, eps: np.ndarray) -> np.ndarray:
        """exp(ε^∧), (d, d)."""
        eps = np.asarray(eps, float).reshape(self.dof)
        if self.d == 2:
            c, s = np.cos(eps[0]), np.sin(eps[0])
            return np.array([[c, -s], [s, c]])
        return exp_so3(eps)

    def retract(self, x: np.ndarray, eps: np.ndarray) -> np.ndarray:
        return self.exp(eps) @ np.asarray(x, float).reshape(self.shape)

    def tangent(self, x: np.ndarray) -> np.ndarray:
        C = np.asarray(x, float).reshape(self.shape)
        return np.stack([(G @ C).ravel(order="F") for G in self._G], axis=1)

    def constraints(self) -> list[tuple[str, np.ndarray]]:
        d, out = self.d, []
        for i in range(d):
            for j in range(i, d):
                M = np.zeros((1 + self.size, 1 + self.size))
                for k in range(d):  # c_i[k] c_j[k], symmetrised
                    a, b = 1 + i * d + k, 1 + j * d + k
                    M[a, b] += 0.5
                    M[b, a] += 0.5
                if i == j:
                    M[0, 0] = -1.0
                out.append((f"orth({i},{j})", M))
        return out


class Binary:
    """{−1, +1}: a label w, embedded as itself; its only equation w² = h² ("w²").  A discrete variable has no
    tangent directions (dof 0): ``retract`` returns it unchanged, so the layer's local solver optimises the
    other variables at fixed labels and its sampler keeps the nominal's (a module draws labels itself).
    ``equation=False``: no equation, so no model factor of the variable's own: a factor on it declares w² = h²."""

    shape: tuple[int, ...] = ()
    size, dof = 1, 0

    def __init__(self, equation: bool = True):
        #: whether w² = h² is the manifold's equation (False: a factor on the variable declares it)
        self.equation = bool(equation)

    def __repr__(self) -> str:
        return "Binary()" if self.equation else "Binary(equation=False)"

    def embed(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float).reshape(1)

    def unembed(self, v: np.ndarray) -> np.ndarray:
        return np.asarray(v, float).reshape(())

    def project(self, a: np.ndarray) -> np.ndarray:
        return np.array(1.0 if float(np.asarray(a, float).reshape(())) >= 0 else -1.0)

    def retract(self, x: np.ndarray, eps: np.ndarray) -> np.ndarray:
        return np.asarray(x, float).reshape(())

    def tangent(self, x: np.ndarray) -> np.ndarray:
        return np.zeros((1, 0))

    def constraints(self) -> list[tuple[str, np.ndarray]]:
        return [("w²", np.diag([-1.0, 1.0]))] if self.equation else []
