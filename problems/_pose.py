"""SE(3) building blocks shared by the Cayley-paper pose problems (Barfoot, Holmes, Dümbgen 2024, §3.2–§5).

Blocks of a pose T = [[C, r], [0ᵀ, 1]] with prefix p: the rotation columns ``{p}c1, {p}c2, {p}c3``
(as in ``_cayley``) and the translation ``{p}r``, each of size 3.  A pose residual ξ = [ρ; φ] named
s is the two blocks ``rho_{s}``, ``phi_{s}`` (size 3 each).

Residual convention (notes §2–§3): ξ = cay⁻¹(T T̃⁻¹)^∨, equivalently (I − ½ξ^∧) T = (I + ½ξ^∧) T̃,
which column by column is quadratic:

    rotation     a_i − b_i − ½ φ × (a_i + b_i) = 0          (i = 1, 2, 3; 9 rows)
    translation  a_r − b_r − ½ φ × (a_r + b_r) − ρ = 0      (3 rows)

with (a, a_r) the columns of T and (b, b_r) those of T̃:

- measured pose T̃ (unary):      b_i = c̃_i,  b_r = r̃;
- relation T₂ = cay(ξ^∧) T̃ T₁ (binary, T̃ = [[C̃, r̃], [0ᵀ, 1]]):  a = T₂,  b_i = C̃ c₁,ᵢ,  b_r = C̃ r₁ + r̃.
  With C̃ = I, r̃ = 0 this is the continuous-time relation T₂ = cay(ξ^∧) T₁ (§5).

Redundant families (paper, re-derived in the notes):

- R1 (unary)  ½ (c_i + c̃_i)ᵀ ρ = c_iᵀ r − c̃_iᵀ r̃                          (3 rows);
- R2 (unary)  rᵀ r = rᵀ r̃ − ½ rᵀ r̃^∧ φ + rᵀ ρ                            (1 row);
- R3 (binary) ½ (c₂,ᵢ + C̃ c₁,ᵢ)ᵀ ρ = c₂,ᵢᵀ r₂ − c₁,ᵢᵀ (r₁ + C̃ᵀ r̃)         (3 rows).

R1 and R3 are the same identity, ½(a_i + b_i)ᵀρ = a_iᵀa_r − b_iᵀb_r; R3 uses C̃ᵀC̃ = I.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.affine import Affine, cayley_rows, const, sum_quads, var
from autotight.model import Constraint, Variables

from ._cayley import orthonormality, rot_blocks, rotation_cayley

POSE_ROLES = ("c1", "c2", "c3", "r")
XI_ROLES = ("rho", "phi")
#: names of a measured pose's 12 data entries [C̃ r̃] (row-major 3×4), for printed closed forms
MEASURED_POSE_NAMES = tuple(f"C̃_{i + 1}{j + 1}" if j < 3 else f"r̃_{i + 1}" for i in range(3) for j in range(4))


# ----------------------------------------------------------------------------- block names


def pose_blocks(prefix: str = "") -> list[str]:
    """Names of a pose's blocks: ``[{p}c1, {p}c2, {p}c3, {p}r]``."""
    return rot_blocks(prefix) + [trans_block(prefix)]


def trans_block(prefix: str = "") -> str:
    """Name of a pose's translation block, ``{p}r``."""
    return f"{prefix}r"


def xi_blocks(suffix: str) -> list[str]:
    """Names of a pose residual's blocks: ``[rho_{s}, phi_{s}]``."""
    return [f"rho_{suffix}", f"phi_{suffix}"]


def declare_pose(prefix: str = "") -> list[tuple[str, int]]:
    """(name, size) pairs of a pose's blocks, for ``Variables``."""
    return [(b, 3) for b in pose_blocks(prefix)]


def declare_xi(suffix: str) -> list[tuple[str, int]]:
    """(name, size) pairs of a pose residual's blocks, for ``Variables``."""
    return [(b, 3) for b in xi_blocks(suffix)]


# ----------------------------------------------------------------------------- values


def split_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) pose → (C (3, 3), r (3,))."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"a pose must have shape (4, 4), got {T.shape}")
    return T[:3, :3], T[:3, 3]


def pose_values(C: np.ndarray, r: np.ndarray, prefix: str = "") -> dict[str, np.ndarray]:
    """Block values of a pose: its rotation columns and translation."""
    out = {b: np.asarray(C, dtype=float)[:, i] for i, b in enumerate(rot_blocks(prefix))}
    out[trans_block(prefix)] = np.asarray(r, dtype=float)
    return out


def xi_values(xi: np.ndarray, suffix: str) -> dict[str, np.ndarray]:
    """Block values of a pose residual ξ = [ρ; φ] (6,)."""
    rho, phi = xi_blocks(suffix)
    return {rho: np.asarray(xi[:3], dtype=float), phi: np.asarray(xi[3:], dtype=float)}


def pose_from_x(V: Variables, x: np.ndarray, prefix: str = "") -> tuple[np.ndarray, np.ndarray]:
    """The raw (C (3, 3), r (3,)) of a pose from a lifted vector x with h = 1 (C not projected)."""
    C = np.column_stack([x[V.slice(b)] for b in rot_blocks(prefix)])
    return C, x[V.slice(trans_block(prefix))].copy()


# ----------------------------------------------------------------------------- affine columns


def state_pose(prefix: str = "", C_rel: np.ndarray | None = None,
               r_rel: np.ndarray | None = None) -> tuple[list[Affine], Affine]:
    """Columns of T̃ T as affine expressions: ([C̃ c₁, C̃ c₂, C̃ c₃], C̃ r + r̃) (T̃ = I by default)."""
    cols = [var(c, C_rel) for c in rot_blocks(prefix)]
    r = var(trans_block(prefix), C_rel)
    if r_rel is not None:
        r = r + const(r_rel)
    return cols, r


def measured_pose(C_meas: np.ndarray, r_meas: np.ndarray) -> tuple[list[Affine], Affine]:
    """Columns of a measured pose as constants (times h): ([c̃₁, c̃₂, c̃₃], r̃)."""
    return [const(C_meas[:, i]) for i in range(3)], const(r_meas)


# ----------------------------------------------------------------------------- primary constraints


def pose_orthonormality(V: Variables, prefix: str = "", factor: str | None = None) -> list[Constraint]:
    """c_iᵀ c_j = δ_ij h² for the pose's rotation (6 rows)."""
    return orthonormality(V, prefix, factor=factor)


def pose_cayley(V: Variables, a: tuple[list[Affine], Affine], b: tuple[list[Affine], Affine], xi: str | Sequence[str],
                name: str, factor: str | None = None, gate: Affine | None = None) -> list[Constraint]:
    """(I − ½ξ^∧) A = (I + ½ξ^∧) B for poses A, B given as affine columns (9 rotation + 3 translation rows).

    xi: the residual's suffix (blocks ``rho_{xi}``, ``phi_{xi}``) or its two block names (ρ, φ).
    gate: a scalar affine g; the rows are multiplied by g, the ξ blocks holding g·ξ (``cayley_rows``).
    """
    rho, phi = xi_blocks(xi) if isinstance(xi, str) else xi
    (a_cols, a_r), (b_cols, b_r) = a, b
    out = rotation_cayley(V, a_cols, b_cols, phi, name, factor=factor, gate=gate)
    for k, A in enumerate(cayley_rows(V, phi, a_r, b_r, rho=var(rho), gate=gate)):
        out.append(Constraint(A, 0.0, name=f"{name}:r[{k}]", factor=factor))
    return out


def unary_cayley(V: Variables, prefix: str, T_meas: np.ndarray, xi: str | Sequence[str], name: str,
                 factor: str | None = None, gate: Affine | None = None) -> list[Constraint]:
    """ξ = cay⁻¹(T T̃⁻¹): the 12 Cayley rows of pose ``prefix`` against the measurement T̃ (4, 4)
    (``xi`` and ``gate`` as in ``pose_cayley``)."""
    return pose_cayley(V, state_pose(prefix), measured_pose(*split_pose(T_meas)), xi, name, factor, gate)


def binary_cayley(V: Variables, prefix1: str, prefix2: str, T_rel: np.ndarray | None, xi: str, name: str,
                  factor: str | None = None) -> list[Constraint]:
    """ξ = cay⁻¹(T₂ T₁⁻¹ T̃⁻¹): the 12 Cayley rows linking poses ``prefix1`` → ``prefix2`` (T̃ = I if None)."""
    C_rel, r_rel = (None, None) if T_rel is None else split_pose(T_rel)
    return pose_cayley(V, state_pose(prefix2), state_pose(prefix1, C_rel, r_rel), xi, name, factor)


# ----------------------------------------------------------------------------- paper families


def r1_unary(V: Variables, prefix: str, T_meas: np.ndarray, xi: str, name: str,
             factor: str | None = None) -> list[Constraint]:
    """(R1) ½ (c_i + c̃_i)ᵀ ρ = c_iᵀ r − c̃_iᵀ r̃, i = 1, 2, 3 (paper (35))."""
    C_m, r_m = split_pose(T_meas)
    rho = var(xi_blocks(xi)[0])
    r = var(trans_block(prefix))
    out = []
    for i, c in enumerate(rot_blocks(prefix)):
        ci, cm = var(c), const(C_m[:, i])
        A = sum_quads(V, [(ci + cm, rho, 0.5 * np.eye(3)), (ci, r, -np.eye(3)), (cm, const(r_m), np.eye(3))])
        out.append(Constraint(A, 0.0, name=f"{name}:R1[{i + 1}]", family="R1", factor=factor))
    return out


def r2_unary(V: Variables, prefix: str, T_meas: np.ndarray, xi: str, name: str,
             factor: str | None = None) -> list[Constraint]:
    """(R2) rᵀ r = rᵀ r̃ − ½ rᵀ r̃^∧ φ + rᵀ ρ (paper (32)): rᵀ times the translation row, cubic term dropped."""
    _, r_m = split_pose(T_meas)
    rho, phi = (var(b) for b in xi_blocks(xi))
    r = var(trans_block(prefix))
    A = sum_quads(V, [(r, r, np.eye(3)), (r, const(r_m), -np.eye(3)), (r, phi, 0.5 * lie.hat(r_m)),
                      (r, rho, -np.eye(3))])
    return [Constraint(A, 0.0, name=f"{name}:R2", family="R2", factor=factor)]


def r3_binary(V: Variables, prefix1: str, prefix2: str, T_rel: np.ndarray | None, xi: str, name: str,
              factor: str | None = None) -> list[Constraint]:
    """(R3) ½ (c₂,ᵢ + C̃ c₁,ᵢ)ᵀ ρ = c₂,ᵢᵀ r₂ − c₁,ᵢᵀ (r₁ + C̃ᵀ r̃), i = 1, 2, 3 (paper (44); T̃ = I if None)."""
    C_rel, r_rel = (np.eye(3), np.zeros(3)) if T_rel is None else split_pose(T_rel)
    rho = var(xi_blocks(xi)[0])
    r1, r2 = var(trans_block(prefix1)), var(trans_block(prefix2))
    shifted = r1 + const(C_rel.T @ r_rel) if np.any(r_rel) else r1
    out = []
    for i, (c1, c2) in enumerate(zip(rot_blocks(prefix1), rot_blocks(prefix2))):
        a, b = var(c2), var(c1, C_rel)
        A = sum_quads(V, [(a + b, rho, 0.5 * np.eye(3)), (a, r2, -np.eye(3)), (var(c1), shifted, np.eye(3))])
        out.append(Constraint(A, 0.0, name=f"{name}:R3[{i + 1}]", family="R3", factor=factor))
    return out


# ----------------------------------------------------------------------------- residuals


# ----------------------------------------------------------------------------- transports (learned templates)
#
# A factor's local columns θ (h, then its blocks in order; d = 1) satisfy the Cayley rows of measurement
# T̃ exactly when Mθ satisfies those of T̃ = I, so its learned relations are congruences Mᵀ A M of the
# relations at T̃ = I (``autotight.discovery.transport``).  ``data`` is [C̃ r̃] row-major (12,).


def _measured(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T = np.asarray(data, dtype=float).reshape(3, 4)
    return T[:, :3], T[:, 3]


def unary_transport(data: np.ndarray) -> np.ndarray:
    """M (19 × 19) on [h, c1, c2, c3, r, ρ, φ] for ξ = cay⁻¹(T T̃⁻¹): T ↦ T T̃⁻¹, i.e.
    c_i ↦ Σ_j C̃_ij c_j and r ↦ r − Σ_j (C̃ᵀ r̃)_j c_j; h, ρ, φ unchanged."""
    C, r = _measured(data)
    M = np.eye(19)
    M[1:10, 1:10] = np.kron(C, np.eye(3))
    M[10:13, 1:10] = -np.kron((C.T @ r)[None, :], np.eye(3))
    return M


def binary_transport(data: np.ndarray) -> np.ndarray:
    """M (31 × 31) on [h, c1, c2, c3, r, c1′, c2′, c3′, r′, ρ, φ] for ξ = cay⁻¹(T₂ T₁⁻¹ T̃⁻¹): T₁ ↦ T̃ T₁, i.e.
    c₁,ᵢ ↦ C̃ c₁,ᵢ and r₁ ↦ C̃ r₁ + r̃ h; pose 2, ρ, φ unchanged."""
    C, r = _measured(data)
    M = np.eye(31)
    M[1:13, 1:13] = np.kron(np.eye(4), C)
    M[10:13, 0] = r
    return M


def unary_residuals(T: np.ndarray, T_meas: Sequence[np.ndarray]) -> np.ndarray:
    """ξ_m = cay⁻¹(T T̃_m⁻¹)^∨ for each measurement, (M, 6); raises CayleySingularityError at angle π."""
    Tm = np.asarray(T_meas, dtype=float).reshape(-1, 4, 4)
    return lie.cay_inv_se3_batch(np.asarray(T, dtype=float) @ lie.inv_se3_batch(Tm)).reshape(-1, 6)


def weighted_cost(V: Variables, xi: str, W: np.ndarray) -> sp.csr_array:
    """ξᵀ W ξ for ξ = [ρ; φ] (W (6, 6)), as a sparse quadratic form."""
    rho, phi = (var(b) for b in xi_blocks(xi))
    W = np.asarray(W, dtype=float)
    return sum_quads(V, [(rho, rho, W[:3, :3]), (rho, phi, 2.0 * W[:3, 3:]), (phi, phi, W[3:, 3:])])


__all__ = ["POSE_ROLES", "XI_ROLES", "rot_blocks", "pose_blocks", "trans_block", "xi_blocks", "declare_pose",
           "declare_xi", "split_pose", "pose_values", "xi_values", "pose_from_x", "state_pose", "measured_pose",
           "pose_orthonormality", "pose_cayley", "unary_cayley", "binary_cayley", "r1_unary", "r2_unary",
           "r3_binary", "unary_residuals", "weighted_cost"]
__all__ += ["MEASURED_POSE_NAMES"]
