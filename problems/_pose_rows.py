"""Stacked SE(3) rows shared by the pose problems written on the factor-graph layer (``autotight.graph``).

Each function takes the layer's stacked views (R factors): a pose (C, r) with C.x (R, 3, 3) and r.x (R, 3), the
factor's auxiliary ξ = [ρ; φ] (xi.rho, xi.phi (R, 3)) and its data Tm (R, 3, 4) = [C̃ r̃], and returns one row per
factor (R, k).
"""

from __future__ import annotations

import numpy as np

from autotight import lie
from autotight.graph import View


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise aᵀb of stacks (R, 3, …) and (R, 3), over the second axis: (R, …)."""
    return np.einsum("ri...,ri->r...", a, b)


def se3(C: np.ndarray, r: np.ndarray) -> np.ndarray:
    """[[C, r], [0ᵀ, 1]] of stacks C (R, 3, 3), r (R, 3): (R, 4, 4)."""
    T = np.zeros((len(C), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = C, r, 1.0
    return T


def cayley_rows(A: np.ndarray, a: np.ndarray, B: np.ndarray, b: np.ndarray, xi: View) -> np.ndarray:
    """(I − ½ξ^∧) [A a] − (I + ½ξ^∧) [B b] column by column (R, 12): A_i − B_i − ½ φ × (A_i + B_i) (9 rows),
    then a − b − ½ φ × (a + b) − ρ (3 rows), for stacks A, B (R, 3, 3) and a, b (R, 3)."""
    Phi = lie.hat_batch(xi.phi)
    rot = A - B - 0.5 * Phi @ (A + B)
    tr = a - b - 0.5 * (Phi @ (a + b)[:, :, None])[:, :, 0] - xi.rho
    return np.hstack([rot.swapaxes(1, 2).reshape(-1, 9), tr])


def unary_cayley(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """ξ = cay⁻¹(T T̃⁻¹): (I − ½ξ^∧) T = (I + ½ξ^∧) T̃ (12 rows)."""
    return cayley_rows(C.x, r.x, Tm[:, :, :3], Tm[:, :, 3], xi)


def r1(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """(R1, paper (35)) ½ (c_i + c̃_i)ᵀ ρ − c_iᵀ r + c̃_iᵀ r̃ = 0, i = 1, 2, 3."""
    Cm, rm = Tm[:, :, :3], Tm[:, :, 3]
    return 0.5 * dot(C.x + Cm, xi.rho) - dot(C.x, r.x) + dot(Cm, rm)


def r2(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """(R2, paper (32)) rᵀr − rᵀr̃ + ½ rᵀ r̃^∧ φ − rᵀρ = 0: rᵀ times the translation row, its cubic term dropped."""
    rm = Tm[:, :, 3]
    return (dot(r.x, r.x) - dot(r.x, rm) + 0.5 * dot(r.x, np.cross(rm, xi.phi)) - dot(r.x, xi.rho))[:, None]
