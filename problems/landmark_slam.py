"""Landmark SLAM: a few poses, unknown landmarks, odometry and a prior (Korotkine et al., App. A, C, D).

Poses T_k = (C_k, r_k), k < K, and landmarks ℓ_j, j < L, in d = 2 or 3 dimensions.
Measurements (noise std σ): landmark j from pose k, y = C_kᵀ(ℓ_j − r_k) + n; odometry
ΔC = C_kᵀ C_{k+1} perturbed by exp(σν^∧) and Δr = C_kᵀ(r_{k+1} − r_k) + n; a prior on pose 0.

    min  Σ_obs ‖(ℓ_j − r_k) − C_k y‖² + Σ_k (‖r_{k+1} − r_k − C_k Δr‖² + ‖C_{k+1} − C_k ΔC‖_F²)
         + ‖C_0 − Č‖_F² + ‖r_0 − ř‖²

Lifting: Θ = [I_d, C_0, r_0, …, ℓ_0, …] (matrix, rank d) or x = [1, vec C_0, r_0, …, ℓ_0, …] (vector).
Primary constraints: C_kᵀC_k = I per pose.  No hand-derived redundant constraints.

Written on the factor-graph layer (``autotight.graph``): the variables C_k ∈ SO(d) (type "pose": factor "pose_k"
holds C_kᵀC_k = I, named ``orth(C_k:i,j)``), r_k ∈ R^d and ℓ_j ∈ R^d, and one factor of its own per measurement
term (``Factor(own=True, roles=…)``: "landmark_n" of type "landmark", roles (C, r, l); "odometry_n" of type
"relative_pose", roles (C_i, r_i, C_j, r_j); "prior", roles (C, r)); the layer derives the model, ``lift`` and
``recover`` in either lifting (``derive(width=…)``: the matrix lifting has width d) and ``sample``. Hand-written,
because the layer would not give the same bits (``_landmark_terms``): each term's lifted cost, declared in the Gram
form (the layer's Mᵀ M of the read-off residual sums the same products in another order, and derives no cost in the
matrix lifting); ``cost`` (Σ ‖E‖_F² term by term); ``local_solve`` (Gauss-Newton with the perturbation pose by pose
[ψ_0, δr_0, …], where the layer's orders it variable by variable and stacks the residuals by a sparse product);
``random_state`` (uniform rotations, positions at the scale ``extent``).
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Variable
from autotight.problem import Instance, Param

from . import _landmark_terms as lt

NAME = "landmark_slam"
DESCRIPTION = "Poses, unknown landmarks, odometry and a prior; matrix or vector lifting, 2D or 3D (Korotkine et al.)."
PARAMS = lt.common_params() | {
    "n_poses": Param(3, "number of poses K", low=1),
    "n_landmarks": Param(3, "number of unknown landmarks L", low=1),
    "obs_per_pose": Param(0, "landmarks observed from each pose (0 = all); every landmark is seen at least once",
                          low=0),
    "sigma": Param(0.05, "noise std of landmark and odometry measurements (m, rad)", low=0.0),
    "prior_sigma": Param(0.05, "noise std of the prior's mean on pose 0 (rad and m)", low=0.0),
    "step": Param(1.0, "distance travelled between poses (m)", low=0.0),
    "extent": Param(2.0, "landmarks lie within this distance of the trajectory's box (m)", low=0.0, low_open=True),
}


def _trajectory(rng: np.random.Generator, K: int, d: int, step: float) -> tuple[np.ndarray, np.ndarray]:
    """A random walk: C_{k+1} = C_k exp(0.3ν^∧), r_{k+1} = r_k + C_k [step, 0, …]."""
    C, r = [lt.random_rotation(rng, d)], [rng.standard_normal(d)]
    for _ in range(K - 1):
        r.append(r[-1] + C[-1] @ (step * np.eye(d)[0]))
        C.append(C[-1] @ lt.exp_rot(0.3 * rng.standard_normal(lt.rot_dof(d)), d))
    return np.array(C), np.array(r)


def _observations(rng: np.random.Generator, K: int, L: int, per_pose: int) -> list[tuple[int, int]]:
    """(pose, landmark) pairs: all, or per_pose per pose with landmark j guaranteed at pose j mod K."""
    if per_pose == 0 or per_pose >= L:
        return [(k, j) for k in range(K) for j in range(L)]
    seen = {(j % K, j) for j in range(L)}
    for k in range(K):
        mine = {j for kk, j in seen if kk == k}
        extra = rng.permutation([j for j in range(L) if j not in mine])[:max(per_pose - len(mine), 0)]
        seen |= {(k, int(j)) for j in extra}
    return sorted(seen)


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d, K, L = lt.check_dim(params["dim"]), params["n_poses"], params["n_landmarks"]
    s, ps = params["sigma"], params["prior_sigma"]
    C, r = _trajectory(rng, K, d, params["step"])
    ls = rng.uniform(r.min(0) - params["extent"], r.max(0) + params["extent"], (L, d))
    obs = _observations(rng, K, L, params["obs_per_pose"])
    y = np.array([C[k].T @ (ls[j] - r[k]) for k, j in obs]) + s * rng.standard_normal((len(obs), d))
    dC = np.array([lt.noisy_rotation(rng, C[k].T @ C[k + 1], s) for k in range(K - 1)]).reshape(K - 1, d, d)
    dr = np.array([C[k].T @ (r[k + 1] - r[k]) for k in range(K - 1)]).reshape(K - 1, d)
    meas = {"obs_pose": np.array([k for k, _ in obs]), "obs_landmark": np.array([j for _, j in obs]), "y": y,
            "odo_from": np.arange(K - 1), "odo_to": np.arange(1, K), "odo_C": dC,
            "odo_r": dr + s * rng.standard_normal(dr.shape),
            "prior_C": lt.noisy_rotation(rng, C[0], ps), "prior_r": r[0] + ps * rng.standard_normal(d)}
    return Instance(NAME, dict(params), meas, {"C": C, "r": r, "l": ls})


def terms(inst: Instance) -> list[lt.Term]:
    """One term per landmark observation ‖(ℓ_j − r_k) − C_k y‖², per odometry step
    ‖r_{k+1} − r_k − C_k Δr‖² + ‖C_{k+1} − C_k ΔC‖_F², and the prior on pose 0."""
    m, p = inst.measurements, inst.params
    K, L, d = p["n_poses"], p["n_landmarks"], lt.check_dim(p["dim"])
    out = []
    for n, (k, j, y) in enumerate(zip(m["obs_pose"], m["obs_landmark"], np.asarray(m["y"], float))):
        C, r = lt.check_pose(k, K, "landmark measurement")
        out.append(lt.check_term(lt.landmark_term(f"landmark_{n}", C, r, lt.landmark_block(lt.check_landmark(j, L)),
                                                  y), d))
    out += lt.relative_terms("odometry", zip(m["odo_from"], m["odo_to"], m["odo_C"], m["odo_r"]), K, d, "odometry")
    out.append(lt.check_term(lt.prior_term("prior", *lt.check_pose(0, K, "prior"), m["prior_C"], m["prior_r"]), d))
    return out


def variables(inst: Instance) -> list[Variable]:
    """Poses C_k ∈ SO(d), r_k ∈ R^d and landmarks ℓ_j ∈ R^d."""
    return lt.pose_variables(lt.check_dim(inst.params["dim"]), inst.params["n_landmarks"])


def counts(inst: Instance) -> tuple[int, int]:
    """K poses and L landmarks: x = [h, vec C_0, r_0, …, vec C_{K−1}, r_{K−1}, ℓ_0, …, ℓ_{L−1}] (or Θ's columns)."""
    return inst.params["n_poses"], inst.params["n_landmarks"]


(build, lift, cost, sample, local_solve, recover, random_state,
 errors) = lt.module_parts(terms, variables, counts, "extent")
