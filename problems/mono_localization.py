"""Monocular localisation from bearings to known landmarks (AutoTight's "mono", without outliers).

Unknown pose (C, t), q_i = C p_i + t the landmark p_i in the camera frame, C ∈ SO(d), d = 2 or 3.  Each
landmark is seen as a unit bearing u_i: the normalised image point [q_{1..d−1}/q_d, 1] plus noise
N(0, σ² I) on its first d − 1 entries, scaled to unit length.  Cost (distance of q_i to the ray u_i):

    f(C, t) = Σ_i q_iᵀ (I − u_i u_iᵀ) q_i

Lifting x = [h, t, vec C] (``_pose_vector``); primary constraints CᵀC = I.  One factor "camera"
(h, t, c) holds the cost and the constraints.  Landmarks are placed in front of the camera (depth in
[1, 5], inside a 90° field of view) and mapped to the world by the true pose.
"""

from __future__ import annotations

import numpy as np

from autotight.constraints import Factor, Model, Variables, sum_quads
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



def _variables(d: int) -> Variables:
    return Variables(pv.pose_blocks(d))


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


def build(inst: Instance) -> Model:
    P, U = inst.measurements["points"], inst.measurements["bearings"]
    d = P.shape[1]
    V = _variables(d)
    parts = []
    for p, u in zip(P, U):
        q = pv.point_map(p)
        parts.append((q, q, np.eye(d) - np.outer(u, u)))
    return Model(V, [Factor("camera", "pose", ("h", pv.T_BLOCK, pv.C_BLOCK), cost=sum_quads(V, parts),
                            constraints=pv.orthonormality(V, d, "camera"))])


def lift(inst: Instance, state: dict) -> np.ndarray:
    return _variables(len(state["t"])).assemble(pv.pose_values(state["C"], state["t"]))


def _residual(inst: Instance, state: dict) -> tuple[np.ndarray, np.ndarray]:
    """e_i = (I − u_i u_iᵀ) q_i (a projector, so ‖e_i‖² = q_iᵀ(I − u_iu_iᵀ)q_i) and its Jacobian."""
    P, U = inst.measurements["points"], inst.measurements["bearings"]
    C, t = np.asarray(state["C"], float), np.asarray(state["t"], float)
    d = len(t)
    es, Js = [], []
    for p, u in zip(P, U):
        Pr = np.eye(d) - np.outer(u, u)
        es.append(Pr @ (C @ p + t))
        Js.append(Pr @ pv.point_jacobian(C, p))
    return np.concatenate(es), np.vstack(Js)


#: the parts shared with the other single-pose modules (``_pose_vector.single_pose_parts``)
cost, sample, random_state, local_solve, recover, errors = pv.single_pose_parts(_residual, _variables)
