"""Planar bearing localisation with a substitution variable and a product block nothing bounds.

A camera at r ∈ ℝ² looks along +y at J known landmarks p_j (depths p_j,y − r_y > 0) and measures the
image coordinate u_j = (p_j,x − r_x)/(p_j,y − r_y) with noise: z_j = u_j + σ·ε_j; a position prior
r̃ = r + σ_r·ε (σ_r: parameter ``prior_sigma``) bounds r.

Lifting (the stereo-style substitution, with a product block):  x = [h, r, (u_j, w_j)_j],
w_j = u_j·r ∈ ℝ² (N = 3 + 3J).  Cost Σ_j (z_j − u_j)²/σ² + ‖r − r̃‖²/σ_r².
Primary constraints per landmark: u_j·(p_j,y − r_y) = p_j,x − r_x (the substitution) and w_j·h = u_j·r
(the product).  w_j,y = u_j r_y = p_j,y u_j − p_j,x + r_x is affine, so quadratic relations bound it;
w_j,x = u_j r_x appears squared in no valid quadratic relation and not in the cost: its columns are
free, rank 1 is out of reach, and the relaxation can at best be cost-tight (``--accept cost``).
A test module (tests/test_face.py), not a shipped problem.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from autotight.constraints import Factor, Model, Variables
from autotight.model import Constraint, QuadForm
from autotight.problem import Instance, LocalResult, Param

NAME = "free_columns_bearing"
PARAMS = {
    "J": Param(4, "number of landmarks", low=3),
    "sigma": Param(0.01, "noise std of the image coordinates", low=0.0, low_open=True),
    "prior_sigma": Param(0.3, "noise std of the position prior (at 10 the primary relaxation is not tight)",
                         low=0.0, low_open=True),
}
#: the smallest depth p_j,y − r_y a sample may have
MIN_DEPTH = 1.0


def generate(params: dict, rng: np.random.Generator) -> Instance:
    J, sigma = params["J"], params["sigma"]
    r = rng.uniform(-0.5, 0.5, 2)
    p = np.column_stack([rng.uniform(-3.0, 3.0, J), rng.uniform(4.0, 8.0, J)])
    u = (p[:, 0] - r[0]) / (p[:, 1] - r[1])
    z = u + sigma * rng.standard_normal(J)
    prior = r + params["prior_sigma"] * rng.standard_normal(2)
    return Instance(NAME, dict(params), {"p": p, "z": z, "prior": prior}, {"r": r})


def _variables(J: int) -> Variables:
    return Variables([("r", 2)] + [b for j in range(J) for b in ((f"u_{j}", 1), (f"w_{j}", 2))])


def build(inst: Instance) -> Model:
    p, z, sigma = inst.measurements["p"], inst.measurements["z"], float(inst.params["sigma"])
    V = _variables(len(z))
    rp, sr = inst.measurements["prior"], float(inst.params["prior_sigma"])
    prior = QuadForm(V).add("r", "r", 1.0).linear("r", -2.0 * rp).const(rp @ rp).matrix() / sr ** 2
    factors = [Factor("prior", "prior", ("h", "r"), cost=sp_csr(prior), data=rp)]
    for j in range(len(z)):
        u, w = f"u_{j}", f"w_{j}"
        cost = QuadForm(V).add(u, u, 1.0).linear(u, [-2.0 * z[j]]).const(z[j] ** 2).matrix() / sigma ** 2
        # u (p_y h − r_y) − (p_x h − r_x) h = 0
        sub = QuadForm(V).add("h", u, [p[j, 1]]).add(u, "r", [[0.0, -1.0]]).const(-p[j, 0]).linear("r", [1.0, 0.0])
        cons = [Constraint(sub.matrix(), 0.0, name=f"b{j}:substitution")]
        for k in range(2):
            e = np.zeros((1, 2))
            e[0, k] = 1.0
            cons.append(Constraint(QuadForm(V).add("h", w, e).add(u, "r", -e).matrix(), 0.0, name=f"b{j}:w{k}h=u·r{k}"))
        factors.append(Factor(f"b{j}", "bearing", ("h", "r", u, w), cost=sp_csr(cost), constraints=cons,
                              roles=("h", "r", "u", "w"), data=p[j]))
    return Model(V, factors)


def sp_csr(A):
    import scipy.sparse as sp

    return sp.csr_array(A)


def _residuals(inst: Instance, r: np.ndarray) -> np.ndarray:
    """The whitened residuals: (z_j − u_j(r))/σ, then (r − r̃)/σ_r."""
    return np.concatenate([(inst.measurements["z"] - _u(inst, r)) / float(inst.params["sigma"]),
                           (r - inst.measurements["prior"]) / float(inst.params["prior_sigma"])])


def _u(inst: Instance, r: np.ndarray) -> np.ndarray:
    p = inst.measurements["p"]
    return (p[:, 0] - r[0]) / (p[:, 1] - r[1])


def lift(inst: Instance, state: dict) -> np.ndarray:
    r = np.asarray(state["r"], dtype=float)
    u = _u(inst, r)
    vals = {"r": r} | {f"u_{j}": u[j:j + 1] for j in range(u.size)} | {f"w_{j}": u[j] * r for j in range(u.size)}
    return _variables(u.size).assemble(vals)


def cost(inst: Instance, state: dict) -> float:
    e = _residuals(inst, np.asarray(state["r"], dtype=float))
    return float(e @ e)


def _feasible(inst: Instance, r: np.ndarray) -> np.ndarray:
    """r moved back (in y) so that every depth is at least MIN_DEPTH."""
    r = np.array(r, dtype=float)
    r[1] = min(r[1], float(inst.measurements["p"][:, 1].min()) - MIN_DEPTH)
    return r


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    return {"r": _feasible(inst, np.asarray(nominal["r"], dtype=float) + spread * rng.standard_normal(2))}


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    return {"r": _feasible(inst, rng.uniform(-2.0, 2.0, 2))}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Trust-region least squares on the whitened residuals over r (depths kept positive)."""
    top = float(inst.measurements["p"][:, 1].min()) - 1e-3
    sol = least_squares(lambda r: _residuals(inst, r), _feasible(inst, init["r"]),
                        bounds=([-np.inf, -np.inf], [np.inf, top]), xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=max_iter)
    state = {"r": sol.x}
    return LocalResult(state, cost(inst, state), int(sol.nfev), bool(sol.success))


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    x = np.asarray(Theta, dtype=float).reshape(-1)
    return {"r": x[1:3] / x[0]}
