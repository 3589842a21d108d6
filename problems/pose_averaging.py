"""Pose averaging (Barfoot, Holmes, Dümbgen 2024, §3.2).

Estimate T = [[C, r], [0ᵀ, 1]] ∈ SE(3) from M noisy measurements T̃_m = cay(ν_m^∧) T, ν_m ~ N(0, σ² I).

Weights: W_m = I.  The paper uses W_m⁻¹ = σ² I; for isotropic noise that is the same problem with the
cost scaled by 1/σ² (same minimiser, same relaxation, same tightness), and W = I stays finite at σ = 0.
So every cost here is σ² times the paper's.

Lifting  x = [h, c₁, c₂, c₃, r, ρ₁, φ₁, …, ρ_M, φ_M]  (n = 13 + 6M),  cost  Σ ξ_mᵀ W_m ξ_m, ξ_m = [ρ_m; φ_m].

Written on the factor-graph layer (``autotight.graph``):

- variables: C ∈ SO(3) (blocks c₁, c₂, c₃; its factor "so3" holds c_iᵀc_j = δ_ij h²) and r ∈ R³ (no factor of
  its own: neither a constraint nor a cost is on r alone);
- factors: one family "pose_meas" of M factors "meas_m" on (C, r), each owning ξ_m = cay⁻¹(T T̃_m⁻¹)
  (blocks ρ_m, φ_m), defined by the 12 Cayley rows ``unary_cayley`` (its primary constraints); residual ξ_m, weight
  W_m; ``Factor.data`` [C̃_m r̃_m] (12 entries, row-major);
- paper families: R1 (3 per m) and R2 (1 per m), ``r1`` and ``r2``;
- cliques: each "pose_meas" factor's blocks (size 19), used when the SDP is decomposed (large M);
- local solver: the paper's Gauss-Newton on SE(3) (``local_solve``); the layer's derived one is
  ``layer_local_solve``.
"""

from __future__ import annotations

import numpy as np

from autotight import lie
from autotight.gauss_newton import block_weight, gauss_newton
from autotight.graph import Auxiliary, Euclidean, Family, Rotation, Variable, View, derive
from autotight.problem import Instance, LocalResult, Meta, Param

from ._pose import MEASURED_POSE_NAMES, unary_transport
from ._pose_rows import r1, r2, se3, unary_cayley

NAME = "pose_averaging"
DESCRIPTION = "Average M noisy SE(3) pose measurements (paper §3.2)."
#: the paper's claim for R1+R2 (Fig. 5, 1000 trials of M = 10 per σ; the figure's values are not stated in
#: the text), shown beside our verdicts in the report's "Against the paper" table
META = Meta(paper_claim={
    "source": "Fig. 5: 'the global solution remains highly rank 1 over a wide range of measurement noise values'",
    "set": "paper",
    "default": "log SVR above 5 (rank 1)",
})
PARAMS = {
    "M": Param(10, "number of pose measurements", low=1),
    "sigma": Param(0.1, "noise standard deviation of each ξ_m component (rad, and length units; ≤ 10)", low=0.0,
                   high=10.0),
    "scale": Param(1.0, "standard deviation of each component of the true translation (≤ 1e6)", low=0.0, high=1e6),
}
#: the measured pose's learned relations move with it by T ↦ T T̃⁻¹ (``autotight.discovery.transport``): a
#: template for relations that no polynomial of degree ≤ 2 in the measurement fits
TRANSPORTS = {"pose_meas": unary_transport}
#: names of each factor type's data entries (``Factor.data``), for printed closed forms
DATA_NAMES = {"pose_meas": MEASURED_POSE_NAMES}


def generate(params: dict, rng: np.random.Generator) -> Instance:
    M, sigma = params["M"], params["sigma"]
    T = lie.make_pose(lie.random_rotation(rng), params["scale"] * rng.standard_normal(3))
    T_meas = np.array([lie.cay_se3(sigma * rng.standard_normal(6)) @ T for _ in range(M)])
    W = np.repeat(np.eye(6)[None], M, axis=0)
    return Instance(NAME, dict(params), {"T_meas": T_meas, "W": W}, {"C": T[:3, :3], "r": T[:3, 3]})


#: C ∈ SO(3) as its columns c₁, c₂, c₃, and the translation r
VARIABLES = [Variable("C", Rotation(3), type="so3", block=("c1", "c2", "c3")), Variable("r", Euclidean(3))]


def residual(C: View, r: View, Tm: np.ndarray) -> np.ndarray:
    """ξ = cay⁻¹(T T̃⁻¹)^∨ = [ρ; φ] of each measurement at states (R, 6); CayleySingularityError at angle π."""
    return lie.cay_inv_se3_batch(se3(C.x, r.x) @ lie.inv_se3_batch(se3(Tm[:, :, :3], Tm[:, :, 3])))


def residual_jacobian(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """∂ξ/∂(ψ, δ) (R, 6, 6) for C ← exp(ψ^∧) C, r ← r + δ: 𝒥_c(ξ)⁻¹ times ∂ε/∂(ψ, δ) of the left perturbation
    T ← exp(ε^∧) T it is to first order, ε = [ρ; φ] = [δ + r^∧ψ; ψ]."""
    A = np.zeros((len(Tm), 6, 6))
    A[:, :3, :3], A[:, :3, 3:], A[:, 3:, :3] = lie.hat_batch(r.x), np.eye(3), np.eye(3)
    return lie.jac_cay_se3_inv_batch(np.hstack([xi.rho, xi.phi])) @ A


def factors(inst: Instance):
    """The M measurement factors as one family: ξ_m by ``residual`` and ``unary_cayley``; cost ξ_mᵀ W_m ξ_m; R1, R2."""
    T_meas = np.asarray(inst.measurements["T_meas"], float)
    xi = Auxiliary({"rho": 3, "phi": 3}, value=residual, equations=unary_cayley, jacobian=residual_jacobian)
    yield Family(("C", "r"), lambda C, r, xi, Tm: np.hstack([xi.rho, xi.phi]), data=T_meas[:, :3, :],
                 type="pose_meas", weight=inst.measurements["W"], auxiliary=xi, paper={"R1": r1, "R2": r2},
                 names=[f"meas_{m}" for m in range(len(T_meas))], clique=True)


build, lift, cost, sample, layer_local_solve, recover = derive(VARIABLES, factors)


def local_solve(inst: Instance, init: dict, max_iter: int = 200, rel_tol: float = 1e-12) -> LocalResult:
    """The paper's Gauss-Newton (App. A.3, LM-damped) on SE(3): (Σ 𝒥⁻ᵀ W 𝒥⁻¹) ε = −Σ 𝒥⁻ᵀ W ξ_m with 𝒥⁻¹ = 𝒥_c(ξ_m)⁻¹,
    T ← cay(ε^∧) T (paper (74)).  The layer's derived solver (``layer_local_solve``: C ← exp(ψ^∧) C, r ← r + δ)
    reaches the same optima as fast by another path, so not to the same last bits; the SDP is solved in the
    frame of the local optimum's lifting, and a loose relaxation's numbers and, at a large M, the interior-point
    solver's final status follow those bits: the module keeps the paper's solver, whose results it reports."""
    Tm, W = np.asarray(inst.measurements["T_meas"]), block_weight(np.asarray(inst.measurements["W"]))

    def linearize(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xi, J = lie.residuals_se3(np.broadcast_to(T, Tm.shape), Tm)  # all M measurements in one pass
        return xi.ravel(), J.reshape(-1, 6), W

    res = gauss_newton(linearize, lambda T, eps: lie.cay_se3(eps) @ T, lie.make_pose(init["C"], init["r"]),
                       max_iter=max_iter, rel_tol=rel_tol)
    res.state = {"C": res.state[:3, :3], "r": res.state[:3, 3]}
    return res


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    """Uniform rotation, translation ~ N(0, max(scale, 1)² I) (drawn again at a Cayley singularity)."""
    s = max(float(inst.params.get("scale", 1.0)), 1.0)
    return sample(inst, rng, {"C": lie.random_rotation(rng), "r": s * rng.standard_normal(3)}, 0.0)


def errors(inst: Instance, state: dict) -> dict:
    """Rotation error (deg) and translation error ‖r − r_true‖ against the ground truth."""
    return {"rotation_deg": lie.rotation_error_deg(state["C"], inst.truth["C"]),
            "translation": float(np.linalg.norm(state["r"] - inst.truth["r"]))}
