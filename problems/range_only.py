"""Range-only localisation with the "quad" lifting (AutoTight, Dümbgen et al. 2024, range-only "y_n").

N unknown positions p_n ∈ R^d (d = 2 or 3), K known anchors a_k.  Each position measures its distance to
every anchor: d̃_nk = ‖a_k − p_n‖ + n_nk, n_nk ~ N(0, σ²).  Cost (squared-distance residuals):

    f(p) = Σ_nk (d̃_nk² − ‖a_k − p_n‖²)²  =  Σ_nk (d̃_nk² − ‖a_k‖² + 2 a_kᵀ p_n − tr Z_n)²

Lifting ("quad"): z_n = vech(p_n p_nᵀ) = [x², xy, (xz,) y², (yz, z²)] (upper triangle, row by row, no
scaling), so each residual is linear in [h, p_n, z_n]:  x = [h, p_0, z_0, …, p_{N−1}, z_{N−1}].
Primary constraints: h·z_n = vech(p_n p_nᵀ) (d(d+1)/2 per position).  The lifted variety of one
position, (1, p, vech ppᵀ), has 6 (d = 2) or 20 (d = 3) independent quadratic relations
(the peer prints "found 14 learned templates" beside 6 known ones for d = 3).

Written on the factor-graph layer (``autotight.graph``): one variable p (a stack of N points in R^d) with
the lifting block z = vech(p pᵀ), one residual per (n, k); the layer derives the model, with one
"position" factor per n (h, p_n, z_n) holding its cost and primary constraints; no data (its relations do
not depend on the anchors), so a learned set carries to any N.
"""

from __future__ import annotations

import numpy as np

from autotight.graph import Euclidean, Factor, Variable, derive
from autotight.problem import Instance, Meta, Param

from . import _landmark_terms as lt

NAME = "range_only"
DESCRIPTION = "Range-only localisation of N points from K anchors, lifting z_n = vech(p_n p_nᵀ) (AutoTight)."
PARAMS = {
    "dim": Param(3, "dimension d of the positions: 2 or 3"),
    "n_positions": Param(3, "number N of unknown positions", low=1),
    "n_anchors": Param(6, "number K of known anchors", low=1),
    "sigma": Param(0.01, "distance noise standard deviation (m)", low=0.0),
    "extent": Param(2.0, "anchors and positions lie in a box of this half-width (m)", low=0.0, low_open=True),
}
META = Meta(check_params={"dim": 3, "n_positions": 2, "n_anchors": 6, "sigma": 0.01, "extent": 2.0},
            paper_claim={"source": "AutoTight _results_test/terminal_output.log, RO (y_n) row: d = 3, N = 3",
                         "set": "paper", "default": "61 constraints → 33 required; rank-tight (SVR 2.3e9)"})


def vech(p: np.ndarray) -> np.ndarray:
    """Upper triangle of ppᵀ, row by row (no √2)."""
    p = np.asarray(p, float)
    i, j = np.triu_indices(len(p))
    return p[i] * p[j]


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    e = params["extent"]
    anchors = rng.uniform(-e, e, (params["n_anchors"], d))
    p = rng.uniform(-e, e, (params["n_positions"], d))
    dist = np.linalg.norm(anchors[None, :, :] - p[:, None, :], axis=2)  # (N, K)
    meas = dist + params["sigma"] * rng.standard_normal(dist.shape)
    return Instance(NAME, dict(params), {"anchors": anchors, "ranges": meas}, {"p": p})


def variables(inst: Instance) -> list[Variable]:
    """p_n ∈ R^d with z_n = vech(p_n p_nᵀ); their model factors are of type "position"."""
    return [Variable("p", Euclidean(inst.measurements["anchors"].shape[1]), lifting={"z": vech}, type="position")]


def factors(inst: Instance):
    """e_nk = d̃_nk² − ‖a_k‖² + 2 a_kᵀ p_n − tr(p_n p_nᵀ), affine in (h, p_n, z_n)."""
    anchors, ranges = inst.measurements["anchors"], inst.measurements["ranges"]
    diagonal = np.equal(*np.triu_indices(anchors.shape[1]))  # the entries of vech on the diagonal
    for n, row in enumerate(ranges):
        for a, r in zip(anchors, row):
            yield Factor(f"p{n}", lambda v, a=a, r=r: [r * r - a @ a + 2 * a @ v.x - v.z[diagonal].sum()])


build, lift, cost, sample, local_solve, recover = derive(variables, factors)


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    e = inst.params["extent"]
    return {"p": rng.uniform(-e, e, inst.truth["p"].shape)}


def errors(inst: Instance, state: dict) -> dict:
    diff = np.asarray(state["p"], float) - inst.truth["p"]
    return {"position": float(np.sqrt(np.mean(np.sum(diff ** 2, axis=1))))}
