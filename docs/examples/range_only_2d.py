"""Range-only localisation in 2-D on the factor-graph layer (docs/range_only_2d.md).

N unknown points p_n ∈ R², K known anchors a_k, ranges d̃_nk = ‖a_k − p_n‖ + noise.  Cost
Σ_nk (d̃_nk² − ‖a_k − p_n‖²)².  Lifting z_n = vech(p_n p_nᵀ) = [x², xy, y²]: each residual
d̃² − ‖a‖² + 2aᵀp − (z₀ + z₂) is then affine in (h, p_n, z_n).
"""

import numpy as np

from autotight.graph import Euclidean, Factor, Variable, derive
from autotight.problem import Instance, Param

PARAMS = {
    "n_points": Param(2, "number N of unknown points", low=1),
    "n_anchors": Param(5, "number K of known anchors", low=3),
    "sigma": Param(0.01, "range noise standard deviation (m)", low=0.0),
}


def generate(params, rng):
    anchors = rng.uniform(-2.0, 2.0, (params["n_anchors"], 2))
    p = rng.uniform(-2.0, 2.0, (params["n_points"], 2))
    ranges = np.linalg.norm(anchors[None] - p[:, None], axis=2)
    ranges += params["sigma"] * rng.standard_normal(ranges.shape)
    return Instance("range_only_2d", dict(params), {"anchors": anchors, "ranges": ranges}, {"p": p})


def vech(p):
    return np.array([p[0] * p[0], p[0] * p[1], p[1] * p[1]])


# one variable per row of the truth's "p": a point in R² with its lifting block z = vech(p pᵀ)
VARIABLES = [Variable("p", Euclidean(2), lifting={"z": vech})]


def factors(inst):
    anchors, ranges = inst.measurements["anchors"], inst.measurements["ranges"]
    for n, row in enumerate(ranges):
        for a, r in zip(anchors, row):
            yield Factor(f"p{n}", lambda v, a=a, r=r: [r * r - a @ a + 2 * a @ v.x - v.z[0] - v.z[2]])


build, lift, cost, sample, local_solve, recover = derive(VARIABLES, factors)
