"""Rotation averaging (Barfoot, Holmes, Dümbgen 2024, §3.1).

Estimate C ∈ SO(3) from M noisy measurements C̃_m = cay(φ_m^∧) C, φ_m ~ N(0, W_m⁻¹).

Lifting  x = [h, c₁, c₂, c₃, φ₁, …, φ_M]  (n = 10 + 3M),  cost  Σ φ_mᵀ W_m φ_m.
Primary constraints: c_iᵀc_j = δ_ij h² and, per m, c_i − c̃_{m,i} − ½ φ_m × (c_i + c̃_{m,i}) = 0.
The paper finds Shor's relaxation tight without redundant constraints.

Written on the factor-graph layer (``autotight.graph``): the variable C ∈ SO(3) (blocks c₁, c₂, c₃, its own
factor of type "so3" holding c_iᵀc_j = δ_ij h²) and one factor "meas_m" of type "rotation_meas" per
measurement, owning the auxiliary block φ_m = cay⁻¹(C C̃_mᵀ) (its defining Cayley relation the primary
constraint, its residual φ_m, weight W_m).
"""

from __future__ import annotations

import numpy as np

from autotight import lie
from autotight.graph import Auxiliary, Factor, Rotation, Variable, derive
from autotight.problem import Instance, Param

NAME = "rotation_averaging"
DESCRIPTION = "Average M noisy rotation measurements (paper §3.1)."
PARAMS = {
    "M": Param(10, "number of rotation measurements", low=1),
    "sigma": Param(0.1, "noise standard deviation of each φ_m (rad; ≤ 10: beyond a few rad the measurements are "
                        "uniform on SO(3))", low=0.0, high=10.0),
    "anisotropy": Param(1.0, "ratio of largest to smallest noise std per axis (W_m anisotropic if > 1; "
                             "≤ 1e6: W_m reaches anisotropy²/σ²; above about 1e4 its condition number "
                             "anisotropy² exceeds what the SDP solver resolves and the instance is refused "
                             "before the solve)", low=1.0, high=1e6),
}


def _weights(rng: np.random.Generator, sigma: float, anisotropy: float) -> tuple[np.ndarray, np.ndarray]:
    """(W, W⁻¹) with W⁻¹ = R diag(σ² a_i²) Rᵀ, a = [1, √anisotropy, anisotropy]⁻¹-scaled."""
    s = max(sigma, 1e-6) * np.array([1.0, np.sqrt(anisotropy), anisotropy]) / anisotropy
    R = lie.random_rotation(rng) if anisotropy > 1 else np.eye(3)
    cov = R @ np.diag(s**2) @ R.T
    return np.linalg.inv(cov), cov


def generate(params: dict, rng: np.random.Generator) -> Instance:
    M, sigma = params["M"], params["sigma"]
    C = lie.random_rotation(rng)
    Ws, Cs = [], []
    for _ in range(M):
        W, cov = _weights(rng, sigma, params["anisotropy"])
        phi = rng.multivariate_normal(np.zeros(3), cov) if sigma > 0 else np.zeros(3)
        Cs.append(lie.cay(phi) @ C)
        Ws.append(W)
    return Instance(NAME, dict(params), {"C_meas": np.array(Cs), "W": np.array(Ws)}, {"C": C})


#: C ∈ SO(3) as its columns c₁, c₂, c₃
VARIABLES = [Variable("C", Rotation(3), type="so3", block=("c1", "c2", "c3"))]


def cayley(C: np.ndarray, C_meas: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(I − ½φ^∧) C − (I + ½φ^∧) C̃ column by column, c_i − c̃_i − ½ φ × (c_i + c̃_i) (9,): zero at φ = cay⁻¹(C C̃ᵀ)."""
    return (C - C_meas - 0.5 * lie.hat(phi) @ (C + C_meas)).ravel(order="F")


def factors(inst: Instance):
    """Per m: φ_m = cay⁻¹(C C̃_mᵀ), defined by ``cayley``; residual φ_m, weight W_m."""
    for m, (Cm, W) in enumerate(zip(inst.measurements["C_meas"], inst.measurements["W"])):
        phi = Auxiliary({"phi": 3}, value=lambda C, Cm=Cm: lie.cay_inv(C.x @ Cm.T),
                        equations=lambda C, a, Cm=Cm: cayley(C.x, Cm, a.phi),
                        jacobian=lambda C, a: lie.jac_cay_inv(a.phi))
        yield Factor("C", lambda C, a: a.phi, type="rotation_meas", weight=W, auxiliary=phi, name=f"meas_{m}")


build, lift, cost, sample, local_solve, recover = derive(VARIABLES, factors)


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    """A uniform rotation (drawn again at a Cayley singularity of a residual)."""
    return sample(inst, rng, {"C": lie.random_rotation(rng)}, 0.0)


def errors(inst: Instance, state: dict) -> dict:
    return {"rotation_deg": lie.rotation_error_deg(state["C"], inst.truth["C"])}
