"""Pose graph: relative poses and a prior, optionally with a loop closure (Korotkine et al., App. C, D).

Poses T_k = (C_k, r_k), k < K, in d = 2 or 3 dimensions, on a noisy circle (heading turns by 2π/K per
step).  Relative measurements T_j = T_i ΔT between consecutive poses, plus (0, K−1) → loop closure
T_0 = T_{K−1} ΔT; ΔC perturbed by exp(σν^∧), Δr by N(0, σ² I).  A prior on pose 0.

    min  Σ_(i,j) (‖r_j − r_i − C_i Δr‖² + ‖C_j − C_i ΔC‖_F²) + ‖C_0 − Č‖_F² + ‖r_0 − ř‖²

Lifting: Θ = [I_d, C_0, r_0, …] (matrix, rank d) or x = [1, vec C_0, r_0, …] (vector, rank 1).
Primary constraints: C_kᵀC_k = I per pose.  No hand-derived redundant constraints.
"""

from __future__ import annotations

import numpy as np

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


def graph(inst: Instance) -> lt.PoseLandmarkGraph:
    """Per-pose orthonormality, one relative-pose term per edge, and the prior."""
    m, p = inst.measurements, inst.params
    g = lt.PoseLandmarkGraph(lt.Lifting(p["lifting"], lt.check_dim(p["dim"])), p["n_poses"])
    for n, (i, j, dC, dr) in enumerate(zip(m["rel_from"], m["rel_to"], m["rel_C"], m["rel_r"])):
        g.add(lt.relative_pose_term(f"relative_{n}", *g.pose(i, "relative pose"), *g.pose(j, "relative pose"),
                                    dC, dr))
    g.add(lt.prior_term("prior", *g.pose(0, "prior"), m["prior_C"], m["prior_r"]))
    return g


build, lift, cost, sample, random_state, local_solve, recover, errors = lt.graph_problem(graph, "radius")
