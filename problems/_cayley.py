"""Building blocks shared by the Cayley-paper problems (Barfoot, Holmes, Dümbgen 2024).

Rotation C = [c₁ c₂ c₃] is stored as three column blocks ``{p}c1, {p}c2, {p}c3``.
Residual convention: φ = cay⁻¹(C C̃ᵀ)^∨, i.e. column-wise  c_i − c̃_i − ½ φ × (c_i + c̃_i) = 0.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.affine import H, Affine, cayley_rows, const, quad, var
from autotight.errors import SolverError
from autotight.model import Constraint, QuadForm, Variables

COLS = ("c1", "c2", "c3")


def rot_blocks(prefix: str = "") -> list[str]:
    return [f"{prefix}{c}" for c in COLS]


def orthonormality(V: Variables, prefix: str = "", factor: str | None = None) -> list[Constraint]:
    """c_iᵀ c_j = δ_ij h² (6 constraints)."""
    cols = rot_blocks(prefix)
    out = []
    for i in range(3):
        for j in range(i, 3):
            qf = quad(V, var(cols[i]), var(cols[j]))
            if i == j:
                qf.const(-1.0)
            out.append(Constraint(qf.matrix(), 0.0, name=f"orth({cols[i]},{cols[j]})", factor=factor))
    return out


def rotation_cayley(V: Variables, cols_a: list[Affine], cols_b: list[Affine], phi: str, name: str,
                    factor: str | None = None) -> list[Constraint]:
    """a_i − b_i − ½ φ × (a_i + b_i) = 0 for the three columns (9 constraints)."""
    out = []
    for i in range(3):
        for k, A in enumerate(cayley_rows(V, phi, cols_a[i], cols_b[i])):
            out.append(Constraint(A, 0.0, name=f"{name}:col{i + 1}[{k}]", factor=factor))
    return out


def measured_columns(C_meas: np.ndarray) -> list[Affine]:
    return [const(C_meas[:, i]) for i in range(3)]


def state_columns(prefix: str = "", M: np.ndarray | None = None) -> list[Affine]:
    """The columns of M·C as affine expressions (M = I by default)."""
    return [var(c, M) for c in rot_blocks(prefix)]


def rotation_values(C: np.ndarray, prefix: str = "") -> dict[str, np.ndarray]:
    return {b: C[:, i] for i, b in enumerate(rot_blocks(prefix))}


def weighted_norm(V: Variables, block: str, W: np.ndarray) -> sp.csr_array:
    """x_bᵀ W x_b."""
    return QuadForm(V).add(block, block, W).matrix()


__all__ = ["H", "orthonormality", "rotation_cayley", "measured_columns", "state_columns", "rotation_values",
           "weighted_norm", "rot_blocks", "draw_valid"]


def draw_valid(draw: Callable[[], dict], residuals: Callable[[dict], object], tries: int = 100) -> dict:
    """draw() a state until its residuals avoid the Cayley singularity (rotation angle π)."""
    for _ in range(tries):
        state = draw()
        try:
            residuals(state)
            return state
        except lie.CayleySingularityError:
            continue
    raise SolverError(f"no sample away from the Cayley singularity in {tries} draws; reduce the spread")
