"""A pose (C, t) in d = 2 or 3 dimensions as blocks of a vector lifting, for AutoTight's problems.

Convention (AutoTight, Dümbgen et al. 2024): the pose maps a world point p to q = C p + t; the lifted
blocks are ``t`` (d entries) and ``c`` = vec C (d² entries, columns stacked), so that
q = [I_d, pᵀ ⊗ I_d] [t; c].  The only primary constraints on the pose are CᵀC = I (the determinant is
dropped, as in the peer).  A state is {"C": (d, d), "t": (d,)} (plus problem-specific entries).

Local solvers perturb C ← exp(ψ^∧) C, t ← t + δ (ψ of size 1 in 2D, 3 in 3D; ``_landmark_terms``).
Modules on the factor-graph layer declare the pose with ``pose_variables`` (wahba, mono_localization) or as
the variables t and C (stereo, robust_wahba).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.constraints import Affine, Constraint, QuadForm, Variables
from autotight.gauss_newton import gauss_newton
from autotight.graph import Euclidean, Rotation, Variable
from autotight.problem import LocalResult

from . import _landmark_terms as lt

T_BLOCK, C_BLOCK = "t", "c"


def pose_blocks(d: int) -> list[tuple[str, int]]:
    """[("t", d), ("c", d²)]."""
    return [(T_BLOCK, d), (C_BLOCK, d * d)]


def point_map(p: np.ndarray) -> Affine:
    """q = C p + t as an affine expression in the blocks (d rows)."""
    p = np.asarray(p, float).ravel()
    d = len(p)
    return Affine({T_BLOCK: np.eye(d), C_BLOCK: np.kron(p[None, :], np.eye(d))})


def orthonormality(V: Variables, d: int, factor: str) -> list[Constraint]:
    """c_iᵀ c_j = δ_ij h² for i ≤ j (d(d+1)/2 constraints) on vec C."""
    out = []
    for i in range(d):
        for j in range(i, d):
            E = np.zeros((d, d))
            E[i, j] = 1.0
            qf = QuadForm(V).add(C_BLOCK, C_BLOCK, np.kron(E, np.eye(d)))
            if i == j:
                qf.const(-1.0)
            out.append(Constraint(qf.matrix(), 0.0, name=f"orth({i},{j})", factor=factor))
    return out


def point_jacobian(C: np.ndarray, p: np.ndarray) -> np.ndarray:
    """∂(C p + t)/∂[ψ, δ] (d × (dof + d)) for C ← exp(ψ^∧) C, t ← t + δ."""
    d = C.shape[0]
    return np.hstack([lt.rot_jacobian(C @ p, d), np.eye(d)])


def retract(state: dict, eps: np.ndarray) -> dict:
    C = np.asarray(state["C"], float)
    d = C.shape[0]
    k = lt.rot_dof(d)
    out = dict(state)
    out["C"] = lt.exp_rot(eps[:k], d) @ C
    out["t"] = np.asarray(state["t"], float) + eps[k:k + d]
    return out


def pose_gauss_newton(residual: Callable[[dict], tuple[np.ndarray, np.ndarray]], init: dict,
                      max_iter: int = 200) -> LocalResult:
    """Damped Gauss-Newton on SO(d) × R^d for cost ‖e‖², residual(state) -> (e, ∂e/∂[ψ, δ])."""

    def linearize(state: dict) -> tuple[np.ndarray, np.ndarray, sp.dia_array]:
        e, J = residual(state)
        return e, J, sp.eye_array(e.size, format="dia")

    start = {"C": np.asarray(init["C"], float), "t": np.asarray(init["t"], float)}
    return gauss_newton(linearize, retract, start, max_iter=max_iter)


def pose_errors(state: dict, truth: dict) -> dict[str, float]:
    """Rotation error (deg) and translation error (same units as t)."""
    return {"rotation_deg": lie.rotation_error_deg(state["C"], truth["C"]),
            "translation": float(np.linalg.norm(np.asarray(state["t"]) - truth["t"]))}


def pose_variables(inst) -> list[Variable]:
    """The pose of a module estimating one pose from ``inst.measurements["points"]``, on the factor-graph
    layer: t ∈ R^d (block t) and C ∈ SO(d) (block c = vec C), sharing one model factor of type "pose"."""
    d = inst.measurements["points"].shape[1]
    return [Variable("t", Euclidean(d), type="pose"), Variable("C", Rotation(d), type="pose", block=C_BLOCK)]


def random_pose_state(inst, rng: np.random.Generator) -> dict:
    """A start independent of the truth: a uniform rotation and t uniform in [−1, 1]^d."""
    d = inst.measurements["points"].shape[1]
    return {"C": lt.random_rotation(rng, d), "t": rng.uniform(-1.0, 1.0, d)}


def errors(inst, state: dict) -> dict[str, float]:
    """``pose_errors`` against the instance's truth."""
    return pose_errors(state, inst.truth)


def last_pose(fn: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``fn(a, b)`` of a pose, remembering the last pose's value (keyed by the bytes of a and b): for the factors
    of one instance that each need one row of a quantity computed for every measurement at once (the lifting
    evaluates every factor at the same pose).  Make one per ``factors(instance)`` call, closing over that
    instance's data only, so that it lives as long as the instance's factors."""
    last: list = [None, None]

    def at(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        key = np.asarray(a, float).tobytes() + np.asarray(b, float).tobytes()
        if last[0] != key:
            last[0], last[1] = key, fn(a, b)
        return last[1]

    return at
