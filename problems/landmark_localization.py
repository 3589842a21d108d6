"""Localisation of one pose against known landmarks, with a prior (Korotkine et al., App. B and D).

Unknown pose (C, r), C ∈ SO(d), d = 2 or 3.  Landmark ℓ_j (known) is seen in the body frame as
y_j = Cᵀ(ℓ_j − r) + n_j, n_j ~ N(0, σ² I).  Prior: Č = exp(σ_p ν^∧) C, ř = r + σ_p n.

    min_{C, r}  Σ_j ‖(ℓ_j − r) − C y_j‖² + ‖C − Č‖_F² + ‖r − ř‖²

Lifting (param ``lifting``): Θ = [I_d, C, r] (matrix, rank d) or x = [1, vec C, r] (vector, rank 1).
Primary constraints: CᵀC = I (the det is dropped).  No hand-derived redundant constraints.

Written on the factor-graph layer (``autotight.graph``): the variables C_k ∈ SO(d) (type "pose": factor "pose_k"
holds C_kᵀC_k = I, named ``orth(C_k:i,j)``) and r_k ∈ R^d (one pose, k = 0), and one factor of its own per
measurement term (``Factor(own=True, roles=…)``: "landmark_n" of type "known_landmark" and "prior", roles (C, r));
the layer derives the model, ``lift`` and ``recover`` in either lifting (``derive(width=…)``: the matrix lifting
has width d) and ``sample``. Hand-written, because the layer would not give the same bits (``_landmark_terms``):
each term's lifted cost, declared in the Gram form (the layer's Mᵀ M of the read-off residual sums the same
products in another order, and derives no cost in the matrix lifting); ``cost`` (Σ ‖E‖_F² term by term);
``local_solve`` (Gauss-Newton with the perturbation pose by pose [ψ_0, δr_0, …], where the layer's orders it
variable by variable and stacks the residuals by a sparse product); ``random_state`` (uniform rotations, positions
at the scale ``extent``).
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Variable
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


def terms(inst: Instance) -> list[lt.Term]:
    """One known-landmark term per observation, ‖(ℓ_j − r) − C y_j‖², and the prior ‖C − Č‖_F² + ‖r − ř‖²."""
    m, d = inst.measurements, lt.check_dim(inst.params["dim"])
    C, r = lt.check_pose(0, 1)
    ells = np.asarray(m["landmarks"], float)
    out = []
    for n, (j, y) in enumerate(zip(m["obs_landmark"], np.asarray(m["y"], float))):
        out.append(lt.check_term(lt.known_landmark_term(f"landmark_{n}", C, r, ells[lt.check_landmark(j, len(ells))],
                                                        y), d))
    out.append(lt.check_term(lt.prior_term("prior", C, r, m["prior_C"], m["prior_r"]), d))
    return out


def variables(inst: Instance) -> list[Variable]:
    """The pose C_0 ∈ SO(d) and r_0 ∈ R^d."""
    return lt.pose_variables(lt.check_dim(inst.params["dim"]))


def counts(inst: Instance) -> tuple[int, int]:
    """One pose, no unknown landmark: x = [h, vec C_0, r_0] (or Θ = [I_d, C_0, r_0])."""
    return 1, 0


(build, lift, cost, sample, local_solve, recover, random_state,
 errors) = lt.module_parts(terms, variables, counts, "extent")
