"""Rotation averaging (Barfoot, Holmes, Dümbgen 2024, §3.1).

Estimate C ∈ SO(3) from M noisy measurements C̃_m = cay(φ_m^∧) C, φ_m ~ N(0, W_m⁻¹).

Lifting  x = [h, c₁, c₂, c₃, φ₁, …, φ_M]  (n = 10 + 3M),  cost  Σ φ_mᵀ W_m φ_m.
Primary constraints: c_iᵀc_j = δ_ij h² and, per m, c_i − c̃_{m,i} − ½ φ_m × (c_i + c̃_{m,i}) = 0.
The paper finds Shor's relaxation tight without redundant constraints.

The worked example of docs/problem_contract.md: it imports only public names (``autotight.constraints``,
``autotight.problem``, ``autotight.lie``, ``autotight.gauss_newton``).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from autotight import lie
from autotight.constraints import (Factor, Model, Variables, draw_valid, measured_columns, orthonormality, rot_blocks,
                                   rotation_cayley, rotation_values, state_columns, weighted_norm)
from autotight.gauss_newton import gauss_newton
from autotight.problem import Instance, LocalResult, Param

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


def _variables(M: int) -> Variables:
    return Variables([(c, 3) for c in rot_blocks()] + [(f"phi_{m}", 3) for m in range(M)])


def build(inst: Instance) -> Model:
    Cm, Ws = inst.measurements["C_meas"], inst.measurements["W"]
    M = len(Cm)
    V = _variables(M)
    factors = [Factor("rotation", "so3", ("h", *rot_blocks()), constraints=orthonormality(V, factor="rotation"))]
    for m in range(M):
        name, phi = f"meas_{m}", f"phi_{m}"
        cons = rotation_cayley(V, state_columns(), measured_columns(Cm[m]), phi, name)
        factors.append(Factor(name, "rotation_meas", ("h", *rot_blocks(), phi), cost=weighted_norm(V, phi, Ws[m]),
                              constraints=cons, roles=("h", "c1", "c2", "c3", "phi")))
    return Model(V, factors)


def residuals(inst: Instance, C: np.ndarray) -> list[np.ndarray]:
    return [lie.cay_inv(C @ Cm.T) for Cm in inst.measurements["C_meas"]]


def lift(inst: Instance, state: dict) -> np.ndarray:
    C = state["C"]
    vals = rotation_values(C) | {f"phi_{m}": p for m, p in enumerate(residuals(inst, C))}
    return _variables(len(inst.measurements["C_meas"])).assemble(vals)


def cost(inst: Instance, state: dict) -> float:
    return float(sum(p @ W @ p for p, W in zip(residuals(inst, state["C"]), inst.measurements["W"])))


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """C = exp(spread·ν^∧) C_nominal, ν ~ N(0, I); redrawn if a residual hits the Cayley singularity."""
    return draw_valid(lambda: {"C": lie.exp_so3(spread * rng.standard_normal(3)) @ nominal["C"]},
                      lambda state: residuals(inst, state["C"]))


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    return sample(inst, rng, {"C": lie.random_rotation(rng)}, 0.0)


def _linearize(inst: Instance, C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacked residuals φ_m, Jacobians J_c(φ_m)⁻¹ w.r.t. ψ (C = cay(ψ^∧) C_op), block-diagonal W."""
    es, Js = [], []
    for Cm in inst.measurements["C_meas"]:
        phi, J = lie.residual_so3(C, Cm)
        es.append(phi)
        Js.append(J)
    W = block_diag(*inst.measurements["W"])
    return np.concatenate(es), np.vstack(Js), W


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton (App. A.2, with LM damping): (Σ J_mᵀ W_m J_m) ψ = −Σ J_mᵀ W_m φ_m, C ← cay(ψ^∧) C."""
    res = gauss_newton(lambda C: _linearize(inst, C), lambda C, psi: lie.cay(psi) @ C, init["C"].copy(),
                       max_iter=max_iter)
    res.state = {"C": res.state}
    return res


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """C from the rank-1 factor x: the raw 3×3 block (its det is reported) projected to SO(3)."""
    x = Theta.reshape(-1)
    x = x / x[0]
    C_raw = x[1:10].reshape(3, 3, order="F")
    return {"C": lie.project_to_so3(C_raw), "det_raw": np.array(np.linalg.det(C_raw))}


def errors(inst: Instance, state: dict) -> dict:
    return {"rotation_deg": lie.rotation_error_deg(state["C"], inst.truth["C"])}
