"""Localisation of one pose against known landmarks, with a prior (Korotkine et al., App. B and D).

Unknown pose (C, r), C ∈ SO(d), d = 2 or 3.  Landmark ℓ_j (known) is seen in the body frame as
y_j = Cᵀ(ℓ_j − r) + n_j, n_j ~ N(0, σ² I).  Prior: Č = exp(σ_p ν^∧) C, ř = r + σ_p n.

    min_{C, r}  Σ_j ‖(ℓ_j − r) − C y_j‖² + ‖C − Č‖_F² + ‖r − ř‖²

Lifting (param ``lifting``): Θ = [I_d, C, r] (matrix, rank d) or x = [1, vec C, r] (vector, rank 1).
Primary constraints: CᵀC = I (the det is dropped).  No hand-derived redundant constraints.
"""

from __future__ import annotations

import numpy as np

from autotight.problem import Instance, Param

from . import _landmark_terms as lt

NAME = "landmark_localization"
DESCRIPTION = "One pose from known landmarks plus a prior, matrix or vector lifting, 2D or 3D (Korotkine et al.)."
PARAMS = lt.common_params() | {
    "n_landmarks": Param(5, "number of known landmarks (each observed once)", low=1),
    "sigma": Param(0.05, "landmark measurement noise std (m)", low=0.0),
    "prior_sigma": Param(0.1, "noise std of the prior's mean (rad and m)", low=0.0),
    "extent": Param(2.0, "landmarks lie in a box of this half-width around the pose (m)", low=0.0, low_open=True),
}


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    C, r = lt.random_rotation(rng, d), rng.standard_normal(d)
    ells = r + rng.uniform(-params["extent"], params["extent"], (params["n_landmarks"], d))
    y = (ells - r) @ C + params["sigma"] * rng.standard_normal(ells.shape)  # rows Cᵀ(ℓ_j − r) + n_j
    ps = params["prior_sigma"]
    meas = {"landmarks": ells, "obs_landmark": np.arange(len(ells)), "y": y,
            "prior_C": lt.noisy_rotation(rng, C, ps), "prior_r": r + ps * rng.standard_normal(d)}
    return Instance(NAME, dict(params), meas, {"C": C[None], "r": r[None]})


def graph(inst: Instance) -> lt.PoseLandmarkGraph:
    """The pose, one known-landmark term per observation, and the prior."""
    m, p = inst.measurements, inst.params
    g = lt.PoseLandmarkGraph(lt.Lifting(p["lifting"], lt.check_dim(p["dim"])), n_poses=1)
    C, r = g.pose(0)
    ells = np.asarray(m["landmarks"], float)
    for n, (j, y) in enumerate(zip(m["obs_landmark"], np.asarray(m["y"], float))):
        g.add(lt.known_landmark_term(f"landmark_{n}", C, r, ells[lt.check_landmark(j, len(ells))], y))
    g.add(lt.prior_term("prior", C, r, m["prior_C"], m["prior_r"]))
    return g


build, lift, cost, sample, random_state, local_solve, recover, errors = lt.graph_problem(graph, "extent")
