"""Point-to-point registration (Wahba's problem with translation; AutoTight's "PPR").

Unknown pose (C, t), C ∈ SO(d), d = 2 or 3.  Known points p_i (world), measured in the sensor frame as
y_i = C p_i + t + n_i, n_i ~ N(0, σ² I).  Cost  Σ_i ‖C p_i + t − y_i‖².

Lifting x = [h, t, vec C] (n = 1 + d + d², as ``_pose_vector``); primary constraints CᵀC = I.  The lifted
variety (1, t, vec C) with C ∈ SO(3) has 20 independent quadratic relations (6 primary + 14 redundant:
row orthonormality and c_i × c_j = c_k); the peer learns 21 with h² = 1 and keeps 7.

Written on the factor-graph layer (``autotight.graph``): variables t ∈ R^d and C ∈ SO(d) (block c), both of
type "pose", and one residual C p_i + t − y_i per point; the layer derives one factor "pose" (h, t, c) holding
the cost and the constraints (no data: its relations do not depend on the measurements).
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Factor, derive
from autotight.problem import Instance, Meta, Param

from . import _landmark_terms as lt
from . import _pose_vector as pv

NAME = "wahba"
DESCRIPTION = "Point-to-point registration of one pose from known point pairs (AutoTight's PPR)."
PARAMS = {
    "dim": Param(3, "dimension d: 2 or 3"),
    "n_points": Param(4, "number of point correspondences", low=1),
    "sigma": Param(0.01, "measurement noise standard deviation", low=0.0),
}
META = Meta(paper_claim={"source": "AutoTight _results_test/terminal_output.log, PPR row (wahba_3d_no_no)",
                         "set": "paper", "default": "21 constraints → 7 required; rank-tight (SVR 8.8e9)"})


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    points = rng.standard_normal((params["n_points"], d))
    C, t = lt.random_rotation(rng, d), rng.uniform(-1.0, 1.0, d)
    y = points @ C.T + t + params["sigma"] * rng.standard_normal(points.shape)
    return Instance(NAME, dict(params), {"points": points, "y": y}, {"C": C, "t": t})


def factors(inst: Instance):
    """e_i = C p_i + t − y_i, affine in (t, vec C)."""
    for p, y in zip(inst.measurements["points"], inst.measurements["y"]):
        yield Factor(("t", "C"), lambda t, C, p=p, y=y: C.x @ p + t.x - y)


build, lift, cost, sample, local_solve, recover = derive(pv.pose_variables, factors)
random_state, errors = pv.random_pose_state, pv.errors
