"""Monocular localisation from bearings to known landmarks (AutoTight's "mono", without outliers).

Unknown pose (C, t), q_i = C p_i + t the landmark p_i in the camera frame, C ∈ SO(d), d = 2 or 3.  Each
landmark is seen as a unit bearing u_i: the normalised image point [q_{1..d−1}/q_d, 1] plus noise
N(0, σ² I) on its first d − 1 entries, scaled to unit length.  Cost (distance of q_i to the ray u_i):

    f(C, t) = Σ_i q_iᵀ (I − u_i u_iᵀ) q_i

Lifting x = [h, t, vec C] (``_pose_vector``); primary constraints CᵀC = I.  Written on the factor-graph
layer (``autotight.graph``): the pose t, C (``_pose_vector.pose_variables``) and one residual per
landmark; the layer derives one factor "pose" (h, t, c) holding the cost and the constraints.  Landmarks
are placed in front of the camera (depth in [1, 5], inside a 90° field of view) and mapped to the world
by the true pose.
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Factor, derive
from autotight.problem import Instance, Param

from . import _landmark_terms as lt
from . import _pose_vector as pv

NAME = "mono_localization"
DESCRIPTION = "One camera pose from unit bearings to known landmarks (AutoTight's mono, no outliers)."
PARAMS = {
    "dim": Param(3, "dimension d: 2 or 3"),
    "n_landmarks": Param(5, "number of landmarks", low=1),
    "sigma": Param(1e-3, "noise standard deviation on the normalised image coordinates", low=0.0),
}


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    n = params["n_landmarks"]
    depth = rng.uniform(1.0, 5.0, n)
    lateral = rng.uniform(-1.0, 1.0, (n, d - 1))  # tan of the angle off the axis: 90° field of view
    q = np.hstack([lateral * depth[:, None], depth[:, None]])
    C, t = lt.random_rotation(rng, d), rng.uniform(-1.0, 1.0, d)
    points = (q - t) @ C  # rows Cᵀ(q_i − t)
    img = np.hstack([lateral + params["sigma"] * rng.standard_normal(lateral.shape), np.ones((n, 1))])
    u = img / np.linalg.norm(img, axis=1, keepdims=True)
    return Instance(NAME, dict(params), {"points": points, "bearings": u}, {"C": C, "t": t})


def factors(inst: Instance):
    """e_i = (I − u_i u_iᵀ)(C p_i + t): a projector, so ‖e_i‖² = q_iᵀ(I − u_iu_iᵀ)q_i; affine in (t, vec C)."""
    P, U = inst.measurements["points"], inst.measurements["bearings"]
    for p, u in zip(P, U):
        Pr = np.eye(len(u)) - np.outer(u, u)
        yield Factor(("t", "C"), lambda t, C, p=p, Pr=Pr: Pr @ (C.x @ p + t.x))


build, lift, cost, sample, local_solve, recover = derive(pv.pose_variables, factors)
random_state, errors = pv.random_pose_state, pv.errors
