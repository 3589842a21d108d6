"""Tests for autotight.lie: round trips, group identities, and every Jacobian by central FD."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from autotight import lie
from autotight.errors import AutotightError
from autotight.lie import (
    CayleySingularityError,
    adjoint,
    cay,
    cay_inv,
    cay_inv_se3,
    cay_se3,
    curly_hat,
    exp_se3,
    exp_so3,
    hat,
    hat_se3,
    inv_se3,
    jac_cay,
    jac_cay_inv,
    jac_cay_se3,
    jac_cay_se3_inv,
    project_to_so3,
    random_pose,
    random_rotation,
    residual_se3,
    residual_se3_binary,
    residual_so3,
    rotation_from_axis_angle,
    vee,
    vee_se3,
)

SEEDS = [0, 1, 2, 3, 4]
H = 1e-6
RTOL = 1e-6


def fd_jac(f, x: np.ndarray, h: float = H) -> np.ndarray:
    """Central finite-difference Jacobian of f at x."""
    cols = [(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(x.size)]
    return np.column_stack(cols)


def assert_jac_close(num: np.ndarray, ana: np.ndarray) -> None:
    err = np.linalg.norm(num - ana)
    assert err <= RTOL * max(1.0, np.linalg.norm(ana)), f"FD mismatch {err:.2e}"


def is_rotation(C: np.ndarray, tol: float = 1e-12) -> bool:
    return np.allclose(C.T @ C, np.eye(3), atol=tol) and abs(np.linalg.det(C) - 1) < tol


# --------------------------------------------------------------------------- hats, adjoint


@pytest.mark.parametrize("seed", SEEDS)
def test_hat_vee(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = rng.standard_normal(3), rng.standard_normal(3)
    assert np.allclose(hat(a) @ b, np.cross(a, b))
    assert np.allclose(hat(a), -hat(a).T)
    assert np.allclose(vee(hat(a)), a)
    xi, zeta = rng.standard_normal(6), rng.standard_normal(6)
    assert np.allclose(vee_se3(hat_se3(xi)), xi)
    X = hat_se3(xi)
    assert np.allclose(X[:3, 3], xi[:3]) and np.allclose(X[:3, :3], hat(xi[3:])) and not X[3].any()
    # ξ^⋏ is the adjoint of the Lie algebra: [ξ^∧, ζ^∧] = (ξ^⋏ ζ)^∧
    Z = hat_se3(zeta)
    assert np.allclose(X @ Z - Z @ X, hat_se3(curly_hat(xi) @ zeta))


@pytest.mark.parametrize("seed", SEEDS)
def test_adjoint(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T, xi = random_pose(rng, 2.0), rng.standard_normal(6)
    Ti = inv_se3(T)
    assert np.allclose(T @ Ti, np.eye(4))
    assert np.allclose(T @ hat_se3(xi) @ Ti, hat_se3(adjoint(T) @ xi))
    assert np.allclose(T @ cay_se3(xi) @ Ti, cay_se3(adjoint(T) @ xi))
    assert np.allclose(adjoint(T) @ adjoint(Ti), np.eye(6))


# --------------------------------------------------------------------------- Cayley map


@pytest.mark.parametrize("seed", SEEDS)
def test_cay_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    phi = 2.0 * rng.standard_normal(3)
    C = cay(phi)
    assert is_rotation(C)
    assert np.allclose(cay_inv(C), phi)
    # rotation angle is 2 atan(|φ|/2) about φ
    assert np.allclose(C, rotation_from_axis_angle(phi, 2 * np.arctan(np.linalg.norm(phi) / 2)))
    R = random_rotation(rng)
    assert np.allclose(cay(cay_inv(R)), R)
    # implicit form used in the QCQPs: (I − ½φ^∧) C = (I + ½φ^∧)
    assert np.allclose((np.eye(3) - 0.5 * hat(phi)) @ C, np.eye(3) + 0.5 * hat(phi))


@pytest.mark.parametrize("seed", SEEDS)
def test_cay_se3_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xi = 2.0 * rng.standard_normal(6)
    T = cay_se3(xi)
    assert is_rotation(T[:3, :3]) and np.allclose(T[3], [0, 0, 0, 1])
    assert np.allclose(T[:3, :3], cay(xi[3:]))
    assert np.allclose(cay_inv_se3(T), xi)
    I = np.eye(4)
    assert np.allclose(cay_inv_se3(T), vee_se3(2 * (T - I) @ np.linalg.inv(T + I)))
    P = random_pose(rng, 3.0)
    assert np.allclose(cay_se3(cay_inv_se3(P)), P)


def test_near_pi_still_invertible() -> None:
    C = rotation_from_axis_angle(np.array([1.0, -2.0, 0.5]), np.pi - 1e-3)
    assert np.allclose(cay(cay_inv(C)), C, atol=1e-8)


@pytest.mark.parametrize("axis", [[1.0, 0, 0], [0, 0, 1.0], [1.0, 2.0, 3.0]])
def test_singular_at_pi(axis: list[float]) -> None:
    C = rotation_from_axis_angle(np.array(axis), np.pi)
    with pytest.raises(CayleySingularityError) as info:
        cay_inv(C)
    msg = str(info.value)
    assert "\n" not in msg and "singular" in msg and "cond=" in msg
    assert isinstance(info.value, ValueError) and isinstance(info.value, AutotightError)
    T = lie.make_pose(C, np.array([1.0, 2.0, 3.0]))
    with pytest.raises(CayleySingularityError):
        cay_inv_se3(T)
    with pytest.raises(CayleySingularityError):
        cay_inv(np.diag([1.0, -1.0, -1.0]))  # exactly singular


def test_input_validation() -> None:
    with pytest.raises(ValueError, match="shape"):
        hat(np.zeros(4))
    with pytest.raises(ValueError, match="non-finite"):
        cay(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        cay_se3(np.zeros(3))
    with pytest.raises(ValueError, match="not a rotation"):
        cay_inv(2 * np.eye(3))
    with pytest.raises(ValueError, match="not a rotation"):
        cay_inv(np.diag([1.0, 1.0, -1.0]))  # reflection: not a CayleySingularityError
    with pytest.raises(ValueError, match="last row"):
        cay_inv_se3(np.ones((4, 4)))


# --------------------------------------------------------------------------- constructors


@pytest.mark.parametrize("seed", SEEDS)
def test_exp_maps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xi = rng.standard_normal(6)
    assert np.allclose(exp_so3(xi[3:]), expm(hat(xi[3:])))
    assert np.allclose(exp_se3(xi), expm(hat_se3(xi)))
    assert np.allclose(exp_se3(1e-10 * xi), expm(hat_se3(1e-10 * xi)))


def test_random_rotation_uniform() -> None:
    rng = np.random.default_rng(7)
    Cs = np.array([random_rotation(rng) for _ in range(2000)])
    assert all(is_rotation(C) for C in Cs)
    # Haar measure: E[C] = 0 and E[tr C] = 0
    assert np.abs(Cs.mean(axis=0)).max() < 0.06


@pytest.mark.parametrize("seed", SEEDS)
def test_project_to_so3(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    assert np.allclose(project_to_so3(R), R)
    noisy = project_to_so3(R + 1e-3 * rng.standard_normal((3, 3)))
    assert is_rotation(noisy) and np.linalg.norm(noisy - R) < 1e-2
    assert is_rotation(project_to_so3(-R))  # det −1 input → det +1 output
    assert is_rotation(project_to_so3(rng.standard_normal((3, 3))))


# --------------------------------------------------------------------------- Jacobians


@pytest.mark.parametrize("seed", SEEDS)
def test_jac_cay_left(seed: int) -> None:
    rng = np.random.default_rng(seed)
    phi = rng.standard_normal(3)
    C = cay(phi)
    assert np.allclose(jac_cay(phi) @ jac_cay_inv(phi), np.eye(3))
    # cay(δ) cay(φ) = cay(φ + J⁻¹δ + O(δ²))
    assert_jac_close(fd_jac(lambda d: cay_inv(cay(d) @ C), np.zeros(3)), jac_cay_inv(phi))
    # cay(φ + δ) = cay(Jδ + O(δ²)) cay(φ)
    assert_jac_close(fd_jac(lambda d: cay_inv(cay(phi + d) @ C.T), np.zeros(3)), jac_cay(phi))
    # the right-sided version is different
    right = fd_jac(lambda d: cay_inv(C.T @ cay(phi + d)), np.zeros(3))
    assert np.linalg.norm(right - jac_cay(phi)) > 1e-3


@pytest.mark.parametrize("seed", SEEDS)
def test_jac_cay_se3_left(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xi = rng.standard_normal(6)
    T = cay_se3(xi)
    assert np.allclose(jac_cay_se3(xi) @ jac_cay_se3_inv(xi), np.eye(6))
    assert_jac_close(fd_jac(lambda e: cay_inv_se3(cay_se3(e) @ T), np.zeros(6)), jac_cay_se3_inv(xi))
    assert_jac_close(
        fd_jac(lambda e: cay_inv_se3(cay_se3(xi + e) @ inv_se3(T)), np.zeros(6)), jac_cay_se3(xi)
    )
    right = fd_jac(lambda e: cay_inv_se3(inv_se3(T) @ cay_se3(xi + e)), np.zeros(6))
    assert np.linalg.norm(right - jac_cay_se3(xi)) > 1e-3


@pytest.mark.parametrize("seed", SEEDS)
def test_residual_so3(seed: int) -> None:
    rng = np.random.default_rng(seed)
    C = random_rotation(rng)
    C_meas = exp_so3(0.7 * rng.standard_normal(3)) @ C
    phi, J = residual_so3(C, C_meas)
    assert np.allclose(cay(phi) @ C_meas, C)
    assert_jac_close(fd_jac(lambda p: residual_so3(cay(p) @ C, C_meas)[0], np.zeros(3)), J)


@pytest.mark.parametrize("seed", SEEDS)
def test_residual_se3(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = random_pose(rng, 2.0)
    T_meas = exp_se3(0.7 * rng.standard_normal(6)) @ T
    xi, J = residual_se3(T, T_meas)
    assert np.allclose(cay_se3(xi) @ T_meas, T)
    assert_jac_close(fd_jac(lambda e: residual_se3(cay_se3(e) @ T, T_meas)[0], np.zeros(6)), J)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("with_meas", [False, True])
def test_residual_se3_binary(seed: int, with_meas: bool) -> None:
    rng = np.random.default_rng(seed)
    T1 = random_pose(rng, 2.0)
    T2 = exp_se3(0.7 * rng.standard_normal(6)) @ T1
    T_meas = exp_se3(0.3 * rng.standard_normal(6)) if with_meas else None
    xi, J1, J2 = residual_se3_binary(T1, T2, T_meas)
    M = T2 @ inv_se3(T1) if T_meas is None else T2 @ inv_se3(T1) @ inv_se3(T_meas)
    assert np.allclose(cay_se3(xi), M)
    f1 = lambda e: residual_se3_binary(cay_se3(e) @ T1, T2, T_meas)[0]  # noqa: E731
    f2 = lambda e: residual_se3_binary(T1, cay_se3(e) @ T2, T_meas)[0]  # noqa: E731
    assert_jac_close(fd_jac(f1, np.zeros(6)), J1)
    assert_jac_close(fd_jac(f2, np.zeros(6)), J2)
    assert np.allclose(J1, -jac_cay_se3_inv(xi) @ adjoint(T2 @ inv_se3(T1)))


def test_gauss_newton_sign() -> None:
    """Rotation averaging GN with C ← cay(ψ^∧) C and (Σ JᵀJ) ψ = −Σ Jᵀφ converges to a stationary point."""
    rng = np.random.default_rng(11)
    C_true = random_rotation(rng)
    meas = [cay(0.3 * rng.standard_normal(3)) @ C_true for _ in range(10)]
    C = exp_so3(0.5 * rng.standard_normal(3)) @ C_true
    costs = []
    for _ in range(10):
        res = [residual_so3(C, M) for M in meas]
        A = sum(J.T @ J for _, J in res)
        g = sum(J.T @ e for e, J in res)
        costs.append(sum(e @ e for e, _ in res))
        C = cay(-np.linalg.solve(A, g)) @ C
    assert np.linalg.norm(g) < 1e-9 and costs[-1] <= costs[0]


def _random_poses(rng: np.random.Generator, B: int) -> np.ndarray:
    return np.array([lie.make_pose(lie.random_rotation(rng), 3 * rng.standard_normal(3)) for _ in range(B)])


def test_batched_residuals_equal_the_single_pose_ones() -> None:
    """The vectorised residuals and Jacobians of the local solvers agree with the single-pose maps, including
    a residual within 1e-3 rad of π (the near-singular branch) and the binary one without a measurement."""
    rng = np.random.default_rng(7)
    T1, T2, Tm = _random_poses(rng, 40), _random_poses(rng, 40), _random_poses(rng, 40)
    # residual T1 T_m⁻¹ at angle π − 1e-3: 1 + tr C < 1e-4 takes the single-pose branch
    Tm[3] = lie.make_pose(lie.cay(2 * np.tan((np.pi - 1e-3) / 2) * np.array([0.0, 0.6, 0.8])).T, np.zeros(3)) @ T1[3]
    xi, J = lie.residuals_se3(T1, Tm)
    for b in range(40):
        xb, Jb = lie.residual_se3(T1[b], Tm[b])
        assert np.abs(xi[b] - xb).max() <= 1e-12 * max(1.0, np.abs(xb).max())
        assert np.abs(J[b] - Jb).max() <= 1e-12 * max(1.0, np.abs(Jb).max())
    assert np.abs(xi[3, 3:]).max() > 1e3  # the branch was exercised: |φ| = 2 tan(θ/2) ≈ 2000
    for meas in (Tm, None):
        xi, J1, J2 = lie.residuals_se3_binary(T1, T2, meas)
        for b in range(40):
            ref = lie.residual_se3_binary(T1[b], T2[b], None if meas is None else meas[b])
            for got, want in zip((xi[b], J1[b], J2[b]), ref):
                assert np.abs(got - want).max() <= 1e-12 * max(1.0, np.abs(want).max())
    eps = rng.standard_normal((40, 6))
    stacked = lie.cay_se3_batch(eps)
    assert max(np.abs(stacked[b] - lie.cay_se3(eps[b])).max() for b in range(40)) <= 1e-14


def test_batched_residuals_raise_the_single_pose_errors() -> None:
    rng = np.random.default_rng(8)
    T = _random_poses(rng, 5)
    bad = T.copy()
    bad[2, :3, :3] *= 1.1  # not a rotation
    with pytest.raises(ValueError, match=r"T\[2\]\[:3, :3\] is not a rotation"):
        lie.residuals_se3(bad, T)
    flip = T.copy()
    flip[1] = lie.make_pose(lie.exp_so3(np.pi * np.array([1.0, 0.0, 0.0])), np.zeros(3)) @ T[1]  # residual at π
    with pytest.raises(CayleySingularityError):
        lie.residuals_se3(flip, T)
    with pytest.raises(ValueError, match=r"shape \(B, 4, 4\)"):
        lie.residuals_se3(T[0], T[0])


def test_checked_residuals_are_the_same_arithmetic_without_the_checks() -> None:
    """``checked=True`` skips the pose checks only: on poses the residuals and Jacobians are equal to the last bit
    (the local solver's results must not move), and a matrix that is not a pose passes unnoticed, which is why the
    discrete trajectory's solver checks its measurements and its start once, by name."""
    rng = np.random.default_rng(10)
    T1, T2, Tm = _random_poses(rng, 30), _random_poses(rng, 30), _random_poses(rng, 30)
    for got, want in zip(lie.residuals_se3(T1, Tm, checked=True), lie.residuals_se3(T1, Tm)):
        assert np.array_equal(got, want)
    for got, want in zip(lie.residuals_se3_binary(T1, T2, Tm, checked=True), lie.residuals_se3_binary(T1, T2, Tm)):
        assert np.array_equal(got, want)
    bad = T1.copy()
    bad[4, :3, :3] *= 1.1
    lie.residuals_se3(bad, Tm, checked=True)  # no check: no error
    with pytest.raises(ValueError, match=r"T\[4\]\[:3, :3\] is not a rotation"):
        lie.residuals_se3(bad, Tm)
    import problems.discrete_trajectory as dt
    from autotight.problem import load

    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": 5}), 0)
    start = {k: np.array(v, dtype=float) for k, v in inst.truth.items()}
    start["C"][2] *= 1.1
    with pytest.raises(ValueError, match=r"start\[2\]\[:3, :3\] is not a rotation"):
        dt.local_solve(inst, start)
    meas = np.array(inst.measurements["T_rel"], dtype=float)
    meas[1, :3, :3] *= 1.1
    inst.measurements["T_rel"] = meas
    with pytest.raises(ValueError, match=r"T_rel\[1\]\[:3, :3\] is not a rotation"):
        dt.local_solve(inst, inst.truth)


def test_batched_exp_and_inverse_cayley_equal_the_single_pose_ones() -> None:
    """exp_se3_batch, cay_inv_se3_batch and inv_se3_batch repeat the single-pose operations in the same
    order: equal to the last bit here (sampling for discovery must not move a committed result), on
    ordinary angles, a near-zero one (the series branch) and one near π (the solve branch)."""
    rng = np.random.default_rng(9)
    xi = rng.standard_normal((60, 6))
    xi[4, 3:] = 1e-10
    xi[5, 3:] = 0.0
    E = lie.exp_se3_batch(xi)
    assert max(np.abs(E[b] - lie.exp_se3(xi[b])).max() for b in range(60)) == 0.0
    T = _random_poses(rng, 30)
    T[7] = lie.make_pose(lie.cay(2 * np.tan((np.pi - 1e-3) / 2) * np.array([0.0, 0.6, 0.8])), np.ones(3))
    X = lie.cay_inv_se3_batch(T)
    assert max(np.abs(X[b] - lie.cay_inv_se3(T[b])).max() for b in range(30)) == 0.0
    Ti = lie.inv_se3_batch(T)
    assert max(np.abs(Ti[b] - lie.inv_se3(T[b])).max() for b in range(30)) == 0.0
    flip = T.copy()
    flip[2] = lie.make_pose(lie.exp_so3(np.pi * np.array([0.0, 0.0, 1.0])), np.zeros(3))
    with pytest.raises(CayleySingularityError):
        lie.cay_inv_se3_batch(flip)
    with pytest.raises(ValueError, match="finite"):
        lie.exp_se3_batch(np.full((2, 6), np.nan))


@pytest.mark.parametrize("angle", [1e-9, 1e-4, 0.3, 2.0, np.pi - 1e-7])
def test_rotation_error_deg_is_the_angle_of_the_relative_rotation(angle: float) -> None:
    rng = np.random.default_rng(3)
    C_ref = lie.random_rotation(rng)
    axis = rng.standard_normal(3)
    C = lie.rotation_from_axis_angle(axis / np.linalg.norm(axis), angle) @ C_ref
    # relative accuracy near 0 and π, where the arccos of the trace alone loses half the digits
    assert lie.rotation_error_deg(C, C_ref) == pytest.approx(np.degrees(angle), rel=1e-8)
    # the largest over a stack; 2-D rotations as well
    assert lie.rotation_error_deg(np.stack([C_ref, C]), np.stack([C_ref, C_ref])) == pytest.approx(np.degrees(angle),
                                                                                                    rel=1e-8)
    c, s = np.cos(angle), np.sin(angle)
    assert lie.rotation_error_deg(np.array([[c, -s], [s, c]]), np.eye(2)) == pytest.approx(np.degrees(angle), rel=1e-8)
    with pytest.raises(ValueError):
        lie.rotation_error_deg(np.eye(3), np.eye(2))
