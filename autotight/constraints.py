"""Public helpers for writing a problem module's cost and constraints (see docs/problem_contract.md).

Everything a module author needs to state a QCQP over a vector lifting x = [h, x₁, x₂, …]:

- the model: ``Variables`` (named blocks), ``QuadForm`` (a sparse symmetric matrix built by block
  name), ``Constraint``, ``Factor``, ``Model``, ``HOMOGENISING`` (= "h");
- affine expressions in the blocks (``Affine``, ``var``, ``const``, ``H`` = h) and the quadratic forms
  made of them: ``quad`` (uᵀ L w), ``linear`` (h·u), ``cross_rows`` ((φ × u)_k), ``cayley_rows``
  (a − b − ½ φ × (a + b) − ρ = 0), ``sum_quads``;
- rotations as three column blocks c₁, c₂, c₃: ``rot_blocks``, ``rotation_values`` (state → block
  values), ``state_columns``, ``measured_columns``, ``orthonormality`` (c_iᵀc_j = δ_ij h²),
  ``rotation_cayley`` (the Cayley residual relation of the paper, column by column);
- costs: ``weighted_norm`` (x_bᵀ W x_b);
- samplers: ``draw_valid`` (redraw a state whose residuals hit the Cayley singularity).

Residual convention: φ = cay⁻¹(C C̃ᵀ)^∨, i.e. column-wise  c_i − c̃_i − ½ φ × (c_i + c̃_i) = 0
(Barfoot, Holmes, Dümbgen 2024).  The other public modules for module authors are
``autotight.problem`` (Instance, LocalResult, Param), ``autotight.lie`` and ``autotight.gauss_newton``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

import autotight.lie as lie
from .affine import LEVI, H, Affine, cayley_rows, const, cross_rows, linear, quad, sum_quads, var
from .errors import SolverError
from .model import HOMOGENISING, Constraint, Factor, Model, QuadForm, Variables

COLS = ("c1", "c2", "c3")


def rot_blocks(prefix: str = "") -> list[str]:
    """Block names of the columns of a rotation: ``{prefix}c1, {prefix}c2, {prefix}c3``."""
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
                    factor: str | None = None, gate: Affine | None = None) -> list[Constraint]:
    """a_i − b_i − ½ φ × (a_i + b_i) = 0 for the three columns (9 constraints); ``gate`` as in
    ``cayley_rows``."""
    out = []
    for i in range(3):
        for k, A in enumerate(cayley_rows(V, phi, cols_a[i], cols_b[i], gate=gate)):
            out.append(Constraint(A, 0.0, name=f"{name}:col{i + 1}[{k}]", factor=factor))
    return out


def measured_columns(C_meas: np.ndarray) -> list[Affine]:
    """The columns of a known rotation as constants (times h)."""
    return [const(C_meas[:, i]) for i in range(3)]


def state_columns(prefix: str = "", M: np.ndarray | None = None) -> list[Affine]:
    """The columns of M·C as affine expressions (M = I by default)."""
    return [var(c, M) for c in rot_blocks(prefix)]


def rotation_values(C: np.ndarray, prefix: str = "") -> dict[str, np.ndarray]:
    """Block values {c1: C[:, 0], …} of a rotation, for ``Variables.assemble``."""
    return {b: C[:, i] for i, b in enumerate(rot_blocks(prefix))}


def weighted_norm(V: Variables, block: str, W: np.ndarray) -> sp.csr_array:
    """x_bᵀ W x_b."""
    return QuadForm(V).add(block, block, W).matrix()


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


__all__ = ["HOMOGENISING", "Variables", "QuadForm", "Constraint", "Factor", "Model",
           "Affine", "var", "const", "H", "LEVI", "quad", "linear", "cross_rows", "cayley_rows", "sum_quads",
           "COLS", "rot_blocks", "orthonormality", "rotation_cayley", "measured_columns", "state_columns",
           "rotation_values", "weighted_norm", "draw_valid"]
