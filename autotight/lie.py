"""SO(3)/SE(3) helpers built around the Cayley map (Barfoot et al., IJRR 2024, App. A.1).

Conventions (see ``/work/shared/notes/problems.md``):

- ``hat(φ)`` = φ^∧ with φ^∧ v = φ × v.
- Pose vector ξ = [ρ; φ] (6,), translation first; ξ^∧ = [[φ^∧, ρ], [0ᵀ, 0]] (4×4);
  ξ^⋏ = [[φ^∧, ρ^∧], [0, φ^∧]] (6×6); Ad(T) = [[C, r^∧C], [0, C]] for T = [[C, r], [0ᵀ, 1]].
- cay(A) = (I − ½A)⁻¹(I + ½A), cay⁻¹(M) = 2(M − I)(M + I)⁻¹, singular at rotation angle π.

Jacobian side (all verified by central finite differences in ``tests/test_lie.py``): the
Jacobians are *left* Jacobians. For a small δ,

    cay((φ + δ)^∧) ≈ cay((J_c(φ) δ)^∧) cay(φ^∧),      cay(δ^∧) cay(φ^∧) ≈ cay((φ + J_c(φ)⁻¹ δ)^∧),
    cay_se3(ξ + ε) ≈ cay_se3(𝒥_c(ξ) ε) cay_se3(ξ),    cay_se3(ε) cay_se3(ξ) ≈ cay_se3(ξ + 𝒥_c(ξ)⁻¹ ε).

(The right-sided versions, e.g. cay(φ^∧) cay(δ^∧), do not match these Jacobians.)

Hence, with left perturbations C = cay(ψ^∧) C_op and T = cay_se3(ε) T_op (paper (70), (74)):

    ∂/∂ψ cay_inv(C C̃ᵀ)            = J_c(φ)⁻¹                   (φ = cay_inv(C C̃ᵀ)),
    ∂/∂ε cay_inv_se3(T T̃⁻¹)       = 𝒥_c(ξ)⁻¹                   (ξ = cay_inv_se3(T T̃⁻¹)),
    ∂/∂ε₁ cay_inv_se3(T₂ T₁⁻¹ T̃⁻¹) = −𝒥_c(ξ)⁻¹ Ad(T₂ T₁⁻¹),      ∂/∂ε₂ (same) = 𝒥_c(ξ)⁻¹,

exactly (these are derivatives at ε = 0, not approximations). The Gauss-Newton step for
Σ eᵀWe with e ≈ e_op + Hε is (Σ HᵀWH) ε* = −Σ HᵀW e_op; note the minus sign.
"""

from __future__ import annotations

import numpy as np

from autotight.errors import AutotightError

#: cay_inv / cay_inv_se3 raise CayleySingularityError when cond₂(C + I) exceeds this.
#: cond₂(C + I) ≈ 2/(π − θ) near angle θ = π, so this rejects π − θ ≲ 2e-12 rad.
CAYLEY_COND_MAX = 1e12
#: Tolerance on ‖CᵀC − I‖_F used to decide whether an input is a rotation matrix.
ORTHO_TOL = 1e-6


class CayleySingularityError(AutotightError, ValueError):
    """The inverse Cayley map is undefined: the rotation angle is (numerically) π.

    Subclasses ValueError and AutotightError (so the CLI prints its one-line message).
    """


# ----------------------------------------------------------------------------- validation


def _finite(a: np.ndarray) -> bool:
    """All entries finite (the array method: cheaper than np.all on these tiny arrays)."""
    return bool(np.isfinite(a).all())


def _vec(x: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if not _finite(a):
        raise ValueError(f"{name} contains non-finite entries")
    return a


def _mat(M: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(M, dtype=float)
    if a.shape != (n, n):
        raise ValueError(f"{name} must have shape ({n}, {n}), got {a.shape}")
    if not _finite(a):
        raise ValueError(f"{name} contains non-finite entries")
    return a


def _det3(C: np.ndarray) -> float:
    return float(C[0, 0] * (C[1, 1] * C[2, 2] - C[1, 2] * C[2, 1]) - C[0, 1] * (C[1, 0] * C[2, 2] - C[1, 2] * C[2, 0])
                 + C[0, 2] * (C[1, 0] * C[2, 1] - C[1, 1] * C[2, 0]))


def _check_rotation(C: np.ndarray, name: str = "C") -> np.ndarray:
    C = _mat(C, 3, name)
    E = C.T @ C
    E[0, 0] -= 1.0
    E[1, 1] -= 1.0
    E[2, 2] -= 1.0
    err = float(np.sqrt((E * E).sum()))
    if err > ORTHO_TOL or _det3(C) <= 0:
        raise ValueError(
            f"{name} is not a rotation matrix (‖CᵀC − I‖ = {err:.2e}, det = {_det3(C):.3f}); "
            "use project_to_so3 first"
        )
    return C


def _check_pose(T: np.ndarray, name: str = "T") -> np.ndarray:
    T = _mat(T, 4, name)
    # the tolerance of np.allclose(T[3], e₄, atol=ORTHO_TOL): |a − b| ≤ ORTHO_TOL + 1e-5·|b|
    if (abs(T[3, 0]) > ORTHO_TOL or abs(T[3, 1]) > ORTHO_TOL or abs(T[3, 2]) > ORTHO_TOL
            or abs(T[3, 3] - 1.0) > ORTHO_TOL + 1e-5):
        raise ValueError(f"{name} last row must be [0, 0, 0, 1], got {T[3]}")
    _check_rotation(T[:3, :3], f"{name}[:3, :3]")
    return T


# ----------------------------------------------------------------------------- hats


def hat(phi: np.ndarray) -> np.ndarray:
    """(3,) → (3, 3) skew matrix φ^∧ with φ^∧ v = φ × v."""
    x, y, z = _vec(phi, 3, "phi")
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def vee(Phi: np.ndarray) -> np.ndarray:
    """(3, 3) → (3,), inverse of ``hat`` (uses the skew-symmetric part of Phi)."""
    P = _mat(Phi, 3, "Phi")
    S = 0.5 * (P - P.T)
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def hat_se3(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (4, 4) ξ^∧ = [[φ^∧, ρ], [0ᵀ, 0]]."""
    xi = _vec(xi, 6, "xi")
    X = np.zeros((4, 4))
    X[:3, :3] = hat(xi[3:])
    X[:3, 3] = xi[:3]
    return X


def vee_se3(Xi: np.ndarray) -> np.ndarray:
    """(4, 4) ξ^∧ → ξ = [ρ; φ] (6,), inverse of ``hat_se3`` (bottom row ignored)."""
    X = _mat(Xi, 4, "Xi")
    return np.concatenate([X[:3, 3], vee(X[:3, :3])])


def curly_hat(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (6, 6) ξ^⋏ = [[φ^∧, ρ^∧], [0, φ^∧]] (so ξ₁^⋏ ξ₂ = −ξ₂^⋏ ξ₁)."""
    xi = _vec(xi, 6, "xi")
    P = hat(xi[3:])
    A = np.zeros((6, 6))
    A[:3, :3] = P
    A[3:, 3:] = P
    A[:3, 3:] = hat(xi[:3])
    return A


# ----------------------------------------------------------------------------- poses


def make_pose(C: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(3, 3) C and (3,) r → (4, 4) T = [[C, r], [0ᵀ, 1]] (C is not checked)."""
    T = np.eye(4)
    T[:3, :3] = _mat(C, 3, "C")
    T[:3, 3] = _vec(r, 3, "r")
    return T


def inv_se3(T: np.ndarray) -> np.ndarray:
    """(4, 4) → (4, 4) T⁻¹ = [[Cᵀ, −Cᵀr], [0ᵀ, 1]] (assumes C orthogonal)."""
    T = _mat(T, 4, "T")
    C, r = T[:3, :3], T[:3, 3]
    return make_pose(C.T, -C.T @ r)


def adjoint(T: np.ndarray) -> np.ndarray:
    """(4, 4) T = [[C, r], [0ᵀ, 1]] → (6, 6) Ad(T) = [[C, r^∧C], [0, C]].

    Satisfies T ξ^∧ T⁻¹ = (Ad(T) ξ)^∧ and T cay_se3(ξ) T⁻¹ = cay_se3(Ad(T) ξ).
    """
    T = _mat(T, 4, "T")
    C, r = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = C
    A[3:, 3:] = C
    A[:3, 3:] = hat(r) @ C
    return A


# ----------------------------------------------------------------------------- Cayley map


def cay(phi: np.ndarray) -> np.ndarray:
    """(3,) φ → (3, 3) C = (I − ½φ^∧)⁻¹(I + ½φ^∧) ∈ SO(3); rotation angle 2·atan(|φ|/2)."""
    P = 0.5 * hat(phi)
    I = np.eye(3)
    return np.linalg.solve(I - P, I + P)


def _cond(A: np.ndarray) -> float:
    s = np.linalg.svd(A, compute_uv=False)
    return np.inf if s[-1] <= s[0] * np.finfo(float).tiny else float(s[0] / s[-1])


def _check_cayley_invertible(C: np.ndarray) -> None:
    cond = _cond(C + np.eye(3))
    if cond > CAYLEY_COND_MAX:
        angle = np.radians(rotation_error_deg(C, np.eye(3)))
        raise CayleySingularityError(
            f"Cayley map is singular: rotation angle is {angle:.6f} ≈ π (C + I is singular, "
            f"cond={cond:.3g} > {CAYLEY_COND_MAX:.0e}); re-choose the reference/nominal rotation"
        )


def cay_inv(C: np.ndarray) -> np.ndarray:
    """(3, 3) rotation C → (3,) φ = vee(2(C − I)(C + I)⁻¹), so that cay(φ) = C.

    Raises ValueError if C is not a rotation (‖CᵀC − I‖ > ORTHO_TOL or det ≤ 0) and
    CayleySingularityError if cond₂(C + I) > CAYLEY_COND_MAX (angle ≈ π).
    """
    C = _check_rotation(C)
    # For a rotation, 2(C − I)(C + I)⁻¹ = (C − Cᵀ)·2/(1 + tr C), i.e. φ = 2 tan(θ/2) a, and
    # cond₂(C + I) = 1/|cos(θ/2)| = 2/√(1 + tr C).
    t1 = 1.0 + C[0, 0] + C[1, 1] + C[2, 2]
    if t1 < 1e-4:  # near π the closed form loses accuracy: check and use the solve
        _check_cayley_invertible(C)
        I = np.eye(3)
        return vee(2.0 * np.linalg.solve((C + I).T, (C - I).T).T)
    s = 2.0 / t1
    return np.array([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]]) * s


def cay_se3(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (4, 4) T = (I − ½ξ^∧)⁻¹(I + ½ξ^∧) = [[cay(φ), (I − ½φ^∧)⁻¹ρ], [0ᵀ, 1]]."""
    X = 0.5 * hat_se3(xi)
    I = np.eye(4)
    return np.linalg.solve(I - X, I + X)


def cay_inv_se3(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose T → ξ = [ρ; φ] (6,) with cay_se3(ξ) = T: φ = cay_inv(C), ρ = (I − ½φ^∧) r.

    This equals vee_se3(2(T − I)(T + I)⁻¹). The singularity test is on C + I only (T + I is
    singular iff C + I is), so it does not depend on the translation's scale.
    """
    T = _check_pose(T)
    phi = cay_inv(T[:3, :3])
    r = T[:3, 3]
    rho = r - 0.5 * np.array([phi[1] * r[2] - phi[2] * r[1], phi[2] * r[0] - phi[0] * r[2],
                              phi[0] * r[1] - phi[1] * r[0]])
    return np.concatenate([rho, phi])


# ----------------------------------------------------------------------------- Jacobians


def jac_cay(phi: np.ndarray) -> np.ndarray:
    """(3,) → (3, 3) left Jacobian J_c(φ) = (I + ½φ^∧)/(1 + ¼φᵀφ)  (paper (64)).

    cay((φ + δ)^∧) ≈ cay((J_c(φ)δ)^∧) cay(φ^∧); equivalently ω = J_c(φ) φ̇ for Ċ = ω^∧C.
    """
    phi = _vec(phi, 3, "phi")
    return (np.eye(3) + 0.5 * hat(phi)) / (1.0 + 0.25 * phi @ phi)


def jac_cay_inv(phi: np.ndarray) -> np.ndarray:
    """(3,) → (3, 3) inverse left Jacobian J_c(φ)⁻¹ = I − ½φ^∧ + ¼φφᵀ  (paper (63)).

    cay(δ^∧) cay(φ^∧) ≈ cay((φ + J_c(φ)⁻¹δ)^∧), so ∂/∂ψ cay_inv(cay(ψ^∧) M)|₀ = J_c(φ)⁻¹
    with φ = cay_inv(M).
    """
    phi = _vec(phi, 3, "phi")
    return np.eye(3) - 0.5 * hat(phi) + 0.25 * np.outer(phi, phi)


def jac_cay_se3_inv(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (6, 6) inverse left Jacobian 𝒥_c(ξ)⁻¹ = I − ½ξ^⋏ + ¼Λ(ξ)  (paper (68)).

    Λ(ξ) = [[0, φ^∧ρ^∧], [0, φφᵀ]], as in the notes and paper: it follows from the exact
    kinematics ξ̇^∧ = (I − ½ξ^∧) ϖ^∧ (I + ½ξ^∧) for Ṫ = ϖ^∧T, and is checked numerically.
    Note the top-left block is I − ½φ^∧, *not* J_c(φ)⁻¹.
    cay_se3(ε) cay_se3(ξ) ≈ cay_se3(ξ + 𝒥_c(ξ)⁻¹ε).
    """
    xi = _vec(xi, 6, "xi")
    rho, phi = xi[:3], xi[3:]
    Lam = np.zeros((6, 6))
    Lam[:3, 3:] = hat(phi) @ hat(rho)
    Lam[3:, 3:] = np.outer(phi, phi)
    return np.eye(6) - 0.5 * curly_hat(xi) + 0.25 * Lam


def jac_cay_se3(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (6, 6) left Jacobian 𝒥_c(ξ) = (𝒥_c(ξ)⁻¹)⁻¹, closed form.

    𝒥_c(ξ)⁻¹ = [[I − ½φ^∧, −½(I − ½φ^∧)ρ^∧], [0, J_c(φ)⁻¹]] (block-triangular), hence
    𝒥_c(ξ) = [[(I − ½φ^∧)⁻¹, ½ρ^∧J_c(φ)], [0, J_c(φ)]] with
    (I − ½φ^∧)⁻¹ = (I + ½φ^∧ + ¼φφᵀ)/(1 + ¼φᵀφ).
    cay_se3(ξ + ε) ≈ cay_se3(𝒥_c(ξ) ε) cay_se3(ξ).
    """
    xi = _vec(xi, 6, "xi")
    rho, phi = xi[:3], xi[3:]
    J = jac_cay(phi)
    out = np.zeros((6, 6))
    out[:3, :3] = (np.eye(3) + 0.5 * hat(phi) + 0.25 * np.outer(phi, phi)) / (1.0 + 0.25 * phi @ phi)
    out[3:, 3:] = J
    out[:3, 3:] = 0.5 * hat(rho) @ J
    return out


# ----------------------------------------------------------------------------- residuals


def residual_so3(C: np.ndarray, C_meas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """φ = cay_inv(C C̃ᵀ) (3,) and its derivative (3, 3) w.r.t. ψ for C ← cay(ψ^∧) C, i.e. J_c(φ)⁻¹."""
    phi = cay_inv(_mat(C, 3, "C") @ _mat(C_meas, 3, "C_meas").T)
    return phi, jac_cay_inv(phi)


def residual_se3(T: np.ndarray, T_meas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ξ = cay_inv_se3(T T̃⁻¹) (6,) and its derivative (6, 6) w.r.t. ε for T ← cay_se3(ε) T, i.e. 𝒥_c(ξ)⁻¹."""
    xi = cay_inv_se3(_mat(T, 4, "T") @ inv_se3(T_meas))
    return xi, jac_cay_se3_inv(xi)


def residual_se3_binary(
    T1: np.ndarray, T2: np.ndarray, T_meas: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relative-pose residual ξ = cay_inv_se3(T₂ T₁⁻¹ T̃⁻¹) (T̃ = I if T_meas is None).

    Returns (ξ (6,), ∂ξ/∂ε₁ (6, 6), ∂ξ/∂ε₂ (6, 6)) for T_i ← cay_se3(ε_i) T_i:
    ∂ξ/∂ε₁ = −𝒥_c(ξ)⁻¹ Ad(T₂ T₁⁻¹) (T̃ not included in the adjoint), ∂ξ/∂ε₂ = 𝒥_c(ξ)⁻¹.
    """
    T21 = _mat(T2, 4, "T2") @ inv_se3(T1)
    M = T21 if T_meas is None else T21 @ inv_se3(T_meas)
    xi = cay_inv_se3(M)
    Jinv = jac_cay_se3_inv(xi)
    return xi, -Jinv @ adjoint(T21), Jinv


# ----------------------------------------------------------------------------- batched residuals
# The same maps on stacks of B poses (B, 4, 4), in one vectorised pass: the local solvers of long
# trajectories evaluate thousands of factors per Gauss-Newton step.  Each agrees with its
# single-pose version to rounding (tests); a stack with a pose that is not a rotation, or a residual
# near the Cayley singularity, is handed to the single-pose code, which raises its own error.


def _hat_batch(v: np.ndarray) -> np.ndarray:
    """(B, 3) → (B, 3, 3) skew matrices."""
    H = np.zeros(v.shape[:-1] + (3, 3))
    H[..., 0, 1], H[..., 0, 2], H[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    H[..., 1, 0], H[..., 2, 0], H[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return H


def _cross_batch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b of two (B, 3) stacks (np.cross's axis handling costs more than the product here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _det3_batch(C: np.ndarray) -> np.ndarray:
    """Determinants of a (B, 3, 3) stack by the triple product (LAPACK's batched det costs ~50× more here)."""
    return np.einsum("bi,bi->b", C[:, :, 0], _cross_batch(C[:, :, 1], C[:, :, 2]))


def _poses(T: np.ndarray, name: str) -> np.ndarray:
    """A (B, 4, 4) stack of finite poses with rotation blocks (else the single-pose check raises)."""
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (B, 4, 4), got {T.shape}")
    C = T[:, :3, :3]
    E = np.swapaxes(C, 1, 2) @ C - np.eye(3)
    bad = (~np.isfinite(T).all(axis=(1, 2))) | (np.sqrt((E * E).sum(axis=(1, 2))) > ORTHO_TOL) \
        | (_det3_batch(C) <= 0) | (np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]) > ORTHO_TOL + 1e-5).any(axis=1)
    for b in np.flatnonzero(bad):
        _check_pose(T[b], f"{name}[{b}]")
    return T


def _inv_se3_batch(T: np.ndarray) -> np.ndarray:
    Ct = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.zeros_like(T)
    out[:, :3, :3] = Ct
    out[:, :3, 3] = -(Ct @ T[:, :3, 3, None])[..., 0]
    out[:, 3, 3] = 1.0
    return out


def _cay_inv_se3_batch(T: np.ndarray) -> np.ndarray:
    """(B, 4, 4) poses → ξ (B, 6), as ``cay_inv_se3`` (poses near the singularity go through it)."""
    C, r = T[:, :3, :3], T[:, :3, 3]
    t1 = 1.0 + C[:, 0, 0] + C[:, 1, 1] + C[:, 2, 2]
    near = t1 < 1e-4
    phi = np.stack([C[:, 2, 1] - C[:, 1, 2], C[:, 0, 2] - C[:, 2, 0], C[:, 1, 0] - C[:, 0, 1]], axis=1)
    phi *= (2.0 / np.where(near, 1.0, t1))[:, None]
    xi = np.concatenate([r - 0.5 * _cross_batch(phi, r), phi], axis=1)
    for b in np.flatnonzero(near):
        xi[b] = cay_inv_se3(T[b])
    return xi


def inv_se3_batch(T: np.ndarray) -> np.ndarray:
    """``inv_se3`` on a stack: (B, 4, 4) poses → (B, 4, 4) inverses (checked as ``inv_se3`` does not:
    finite poses with rotation blocks)."""
    return _inv_se3_batch(_poses(T, "T"))


def cay_inv_se3_batch(T: np.ndarray) -> np.ndarray:
    """``cay_inv_se3`` on a stack: (B, 4, 4) poses → ξ (B, 6); the same errors (ValueError on a pose
    that is not one, CayleySingularityError at rotation angle π)."""
    return _cay_inv_se3_batch(_poses(T, "T"))


def _jac_cay_se3_inv_batch(xi: np.ndarray) -> np.ndarray:
    """ξ (B, 6) → 𝒥_c(ξ)⁻¹ (B, 6, 6), as ``jac_cay_se3_inv``."""
    rho, phi = xi[:, :3], xi[:, 3:]
    P, R = _hat_batch(phi), _hat_batch(rho)
    J = np.broadcast_to(np.eye(6), (xi.shape[0], 6, 6)).copy()
    J[:, :3, :3] -= 0.5 * P
    J[:, 3:, 3:] += -0.5 * P + 0.25 * phi[:, :, None] * phi[:, None, :]
    J[:, :3, 3:] = -0.5 * R + 0.25 * P @ R
    return J


def hat_batch(v: np.ndarray) -> np.ndarray:
    """``hat`` on a stack: (…, 3) → (…, 3, 3) skew matrices."""
    return _hat_batch(np.asarray(v, dtype=float))


def jac_cay_se3_inv_batch(xi: np.ndarray) -> np.ndarray:
    """``jac_cay_se3_inv`` on a stack: ξ = [ρ; φ] (B, 6) → 𝒥_c(ξ)⁻¹ (B, 6, 6)."""
    return _jac_cay_se3_inv_batch(np.asarray(xi, dtype=float))


def check_poses(T: np.ndarray, name: str = "T") -> np.ndarray:
    """T as a (B, 4, 4) float stack of finite poses with rotation blocks; ValueError naming ``name`` (and the
    pose's index) otherwise."""
    return _poses(T, name)


def _checked(T: np.ndarray, name: str, checked: bool) -> np.ndarray:
    return np.asarray(T, dtype=float) if checked else _poses(T, name)


def residuals_se3(T: np.ndarray, T_meas: np.ndarray, *, checked: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``residual_se3`` on stacks: T, T_meas (B, 4, 4) → ξ (B, 6), 𝒥_c(ξ)⁻¹ (B, 6, 6).  checked: T and T_meas are
    known to be poses (``check_poses``: a solver's measurements and start checked once, its iterates its own
    retractions of them), so neither they nor their products are checked again (the same arithmetic)."""
    T, Tm = _checked(T, "T", checked), _checked(T_meas, "T_meas", checked)
    xi = _cay_inv_se3_batch(_checked(T @ _inv_se3_batch(Tm), "T T_meas⁻¹", checked))
    return xi, _jac_cay_se3_inv_batch(xi)


def residuals_se3_binary(T1: np.ndarray, T2: np.ndarray, T_meas: np.ndarray | None = None, *, checked: bool = False
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``residual_se3_binary`` on stacks: T1, T2, T_meas (B, 4, 4) → ξ (B, 6), ∂ξ/∂ε₁, ∂ξ/∂ε₂ (B, 6, 6).
    checked: as ``residuals_se3``."""
    T1, T2 = _checked(T1, "T1", checked), _checked(T2, "T2", checked)
    T21 = T2 @ _inv_se3_batch(T1)
    M = T21 if T_meas is None else T21 @ _inv_se3_batch(_checked(T_meas, "T_meas", checked))
    xi = _cay_inv_se3_batch(_checked(M, "T2 T1⁻¹ T_meas⁻¹", checked))
    Jinv = _jac_cay_se3_inv_batch(xi)
    C, r = T21[:, :3, :3], T21[:, :3, 3]
    Ad = np.zeros_like(Jinv)
    Ad[:, :3, :3] = C
    Ad[:, 3:, 3:] = C
    Ad[:, :3, 3:] = _hat_batch(r) @ C
    return xi, -Jinv @ Ad, Jinv


def cay_se3_batch(xi: np.ndarray) -> np.ndarray:
    """``cay_se3`` on a stack: ξ (B, 6) → T (B, 4, 4)."""
    xi = np.asarray(xi, dtype=float)
    X = np.zeros((xi.shape[0], 4, 4))
    X[:, :3, :3] = 0.5 * _hat_batch(xi[:, 3:])
    X[:, :3, 3] = 0.5 * xi[:, :3]
    I = np.eye(4)
    return np.linalg.solve(I - X, I + X)


# ----------------------------------------------------------------------------- construction


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """(3,) axis-angle φ → (3, 3) exp(φ^∧) by Rodrigues' formula (rotation by |φ| about φ)."""
    phi = _vec(phi, 3, "phi")
    theta = np.linalg.norm(phi)
    P = hat(phi)
    if theta < 1e-8:
        return np.eye(3) + P + 0.5 * P @ P
    return np.eye(3) + np.sin(theta) / theta * P + (1 - np.cos(theta)) / theta**2 * P @ P


def rotation_from_axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3,) axis (normalised here) and angle [rad] → (3, 3) rotation."""
    axis = _vec(axis, 3, "axis")
    n = np.linalg.norm(axis)
    if n == 0:
        raise ValueError("axis must be nonzero")
    return exp_so3(axis / n * float(angle))


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """ξ = [ρ; φ] (6,) → (4, 4) exp(ξ^∧) = [[exp(φ^∧), V(φ)ρ], [0ᵀ, 1]]."""
    xi = _vec(xi, 6, "xi")
    rho, phi = xi[:3], xi[3:]
    theta = np.linalg.norm(phi)
    P = hat(phi)
    if theta < 1e-8:
        V = np.eye(3) + 0.5 * P + P @ P / 6.0
    else:
        V = np.eye(3) + (1 - np.cos(theta)) / theta**2 * P + (theta - np.sin(theta)) / theta**3 * P @ P
    return make_pose(exp_so3(phi), V @ rho)


def exp_se3_batch(xi: np.ndarray) -> np.ndarray:
    """``exp_se3`` on a stack: ξ (B, 6) → (B, 4, 4), with the same operations in the same order, so the
    same floating-point result (tests: equal to the last bit)."""
    xi = np.asarray(xi, dtype=float)
    if xi.ndim != 2 or xi.shape[1] != 6 or not np.all(np.isfinite(xi)):
        raise ValueError(f"xi must be a finite (B, 6) array, got shape {xi.shape}")
    rho, phi = xi[:, :3], xi[:, 3:]
    theta = np.sqrt((phi[:, None, :] @ phi[:, :, None])[:, 0, 0])  # as norm(φ) of one vector: a dot product
    small = (theta < 1e-8)[:, None, None]
    t = np.where(theta < 1e-8, 1.0, theta)[:, None, None]
    P = _hat_batch(phi)
    I = np.eye(3)
    C = np.where(small, I + P + (0.5 * P) @ P, I + np.sin(t) / t * P + ((1 - np.cos(t)) / t**2 * P) @ P)
    t3 = np.array([x**3 for x in t.ravel()]).reshape(t.shape)  # scalar pow: an array's t**3 rounds differently
    V = np.where(small, I + 0.5 * P + P @ P / 6.0,
                 I + (1 - np.cos(t)) / t**2 * P + ((t - np.sin(t)) / t3 * P) @ P)
    T = np.zeros((xi.shape[0], 4, 4))
    T[:, :3, :3] = C
    T[:, :3, 3] = (V @ rho[:, :, None])[..., 0]
    T[:, 3, 3] = 1.0
    return T


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly (Haar) distributed (3, 3) rotation, det +1, from a normalised Gaussian quaternion."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_pose(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """(4, 4) pose with uniform rotation and translation ~ N(0, scale² I)."""
    return make_pose(random_rotation(rng), scale * rng.standard_normal(3))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to a (3, 3) matrix: U diag(1, 1, det(UVᵀ)) Vᵀ from M = UΣVᵀ.

    Always returns det +1 (the sign fix handles reflections from O(3) relaxations).
    """
    M = _mat(M, 3, "M")
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def project_to_se3(T: np.ndarray) -> np.ndarray:
    """(4, 4) (or (3, 4)) matrix → pose with its rotation block projected onto SO(3)."""
    T = np.asarray(T, dtype=float)
    if T.shape not in ((3, 4), (4, 4)):
        raise ValueError(f"T must have shape (4, 4) or (3, 4), got {T.shape}")
    return make_pose(project_to_so3(T[:3, :3]), T[:3, 3])


def rotation_error_deg(C: np.ndarray, C_ref: np.ndarray) -> float:
    """Rotation error in degrees: the angle θ of R = C C_refᵀ, the largest over a stack.

    C, C_ref: rotations of the same shape, (d, d) or a stack (…, d, d), d ∈ {2, 3}.
    θ = atan2(‖R − Rᵀ‖_F / (2√2), (tr R − (d − 2)) / 2) ∈ [0°, 180°]: exact for a rotation at every
    angle (the arccos of the trace alone loses half the digits near 0 and π).  ValueError on bad shapes.
    """
    C, C_ref = np.asarray(C, dtype=float), np.asarray(C_ref, dtype=float)
    if C.shape != C_ref.shape or C.ndim < 2 or C.shape[-1] != C.shape[-2] or C.shape[-1] not in (2, 3):
        raise ValueError(f"rotation_error_deg needs two (…, d, d) stacks of equal shape with d in (2, 3), "
                         f"got {C.shape} and {C_ref.shape}")
    R = C @ np.swapaxes(C_ref, -1, -2)
    cos = (np.trace(R, axis1=-2, axis2=-1) - (R.shape[-1] - 2)) / 2
    sin = np.linalg.norm(R - np.swapaxes(R, -1, -2), axis=(-2, -1)) / (2 * np.sqrt(2))
    return float(np.degrees(np.arctan2(sin, cos)).max())
