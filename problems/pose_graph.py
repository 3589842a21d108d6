"""Pose graph: relative poses and a prior, optionally with a loop closure (Korotkine et al., App. C, D).

Poses T_k = (C_k, r_k), k < K, in d = 2 or 3 dimensions, on a noisy circle (heading turns by 2π/K per
step).  Relative measurements T_j = T_i ΔT between consecutive poses, plus (0, K−1) → loop closure
T_0 = T_{K−1} ΔT; ΔC perturbed by exp(σν^∧), Δr by N(0, σ² I).  A prior on pose 0.

    min  Σ_(i,j) (‖r_j − r_i − C_i Δr‖² + ‖C_j − C_i ΔC‖_F²) + ‖C_0 − Č‖_F² + ‖r_0 − ř‖²

Lifting: Θ = [I_d, C_0, r_0, …] (matrix, rank d) or x = [1, vec C_0, r_0, …] (vector, rank 1).
Primary constraints: C_kᵀC_k = I per pose.  No hand-derived redundant constraints.

Written on the factor-graph layer (``autotight.graph``): the variables C_k ∈ SO(d) (type "pose": factor "pose_k"
holds C_kᵀC_k = I, named ``orth(C_k:i,j)``) and r_k ∈ R^d, and one factor of its own per measurement term
(``Factor(own=True, roles=…)``: "relative_n" of type "relative_pose", roles (C_i, r_i, C_j, r_j); "prior", roles
(C, r)); the layer derives the model, ``lift`` and ``recover`` in either lifting (``derive(width=…)``: the matrix
lifting has width d) and ``sample``. Hand-written, because the layer would not give the same bits
(``_landmark_terms``): each term's lifted cost, declared in the Gram form (the layer's Mᵀ M of the read-off
residual sums the same products in another order, and derives no cost in the matrix lifting); ``cost`` (Σ ‖E‖_F²
term by term); ``local_solve`` (Gauss-Newton with the perturbation pose by pose [ψ_0, δr_0, …], where the layer's
orders it variable by variable and stacks the residuals by a sparse product); ``random_state`` (uniform rotations,
positions at the scale ``radius``).
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Variable
from autotight.problem import Instance, Param

from . import _landmark_terms as lt

NAME = "pose_graph"
DESCRIPTION = "Relative poses plus a prior, optional loop closure; matrix or vector lifting, 2D or 3D."
PARAMS = lt.common_params() | {
    "n_poses": Param(5, "number of poses K", low=2),
    "loop_closure": Param(True, "add the relative measurement from pose K−1 back to pose 0"),
    "sigma": Param(0.05, "noise std of the relative measurements (m, rad)", low=0.0),
    "prior_sigma": Param(0.05, "noise std of the prior's mean on pose 0 (rad and m)", low=0.0),
    "radius": Param(2.0, "radius of the circle the poses lie on (m)", low=0.0, low_open=True),
    "jitter": Param(0.1, "perturbation of the true poses off the circle (m, rad)", low=0.0),
}


def _circle(rng: np.random.Generator, K: int, d: int, radius: float, jitter: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses around a circle in the first two axes, heading along the tangent, jittered."""
    C, r = [], []
    for k in range(K):
        a = 2 * np.pi * k / K
        psi = np.zeros(lt.rot_dof(d))
        psi[-1] = a + np.pi / 2  # 2D angle, or rotation about z in 3D
        C.append(lt.noisy_rotation(rng, lt.exp_rot(psi, d), jitter))
        r.append(np.r_[radius * np.cos(a), radius * np.sin(a), np.zeros(d - 2)] + jitter * rng.standard_normal(d))
    return np.array(C), np.array(r)


def _edges(K: int, loop_closure: bool) -> list[tuple[int, int]]:
    return [(k, k + 1) for k in range(K - 1)] + ([(K - 1, 0)] if loop_closure and K > 2 else [])


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d, K, s, ps = lt.check_dim(params["dim"]), params["n_poses"], params["sigma"], params["prior_sigma"]
    C, r = _circle(rng, K, d, params["radius"], params["jitter"])
    E = _edges(K, params["loop_closure"])
    meas = {"rel_from": np.array([i for i, _ in E]), "rel_to": np.array([j for _, j in E]),
            "rel_C": np.array([lt.noisy_rotation(rng, C[i].T @ C[j], s) for i, j in E]),
            "rel_r": np.array([C[i].T @ (r[j] - r[i]) + s * rng.standard_normal(d) for i, j in E]),
            "prior_C": lt.noisy_rotation(rng, C[0], ps), "prior_r": r[0] + ps * rng.standard_normal(d)}
    return Instance(NAME, dict(params), meas, {"C": C, "r": r})


def terms(inst: Instance) -> list[lt.Term]:
    """One relative-pose term per edge, ‖r_j − r_i − C_i Δr‖² + ‖C_j − C_i ΔC‖_F², and the prior on pose 0."""
    m, p = inst.measurements, inst.params
    K, d = p["n_poses"], lt.check_dim(p["dim"])
    out = lt.relative_terms("relative", zip(m["rel_from"], m["rel_to"], m["rel_C"], m["rel_r"]), K, d,
                            "relative pose")
    out.append(lt.check_term(lt.prior_term("prior", *lt.check_pose(0, K, "prior"), m["prior_C"], m["prior_r"]), d))
    return out


def variables(inst: Instance) -> list[Variable]:
    """Poses C_k ∈ SO(d) and r_k ∈ R^d."""
    return lt.pose_variables(lt.check_dim(inst.params["dim"]))


def counts(inst: Instance) -> tuple[int, int]:
    """K poses, no landmark: x = [h, vec C_0, r_0, …, vec C_{K−1}, r_{K−1}] (or Θ's columns in that order)."""
    return inst.params["n_poses"], 0


(build, lift, cost, sample, local_solve, recover, random_state,
 errors) = lt.module_parts(terms, variables, counts, "radius")
