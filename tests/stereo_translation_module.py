"""Planar stereo localisation of a translating camera: a substitution variable and a product block.

A rectified stereo pair (focal length f, principal point c_u, baseline b) at an unknown position t ∈ ℝ²,
axes fixed to the world's, sees J known landmarks p_j at q_j = p_j + t (camera frame, depth q_j,y > 0) and
measures the left and right image coordinates

    y_j = M [q_j,x/q_j,y, 1, 1/q_j,y] + n_j,   M = [[f, c_u, f b/2], [f, c_u, −f b/2]],  n_j ~ N(0, σ² I) px.

Cost Σ_j ‖y_j − M ū_j‖²/f² (normalised image units).

Lifting (the stereo substitution of AutoTight's Stereo2DLifter, at its level "urT"):
x = [h, t, (u_j, w_j)_j] with u_j = [q_j,x, 1]/q_j,y ∈ ℝ² and w_j = vec_row(u_j tᵀ) ∈ ℝ⁴
(N = 3 + 6J).  The cost is quadratic in [h, u_j]; primary constraints per landmark are the substitution
q_j,y u_j = [q_j,x; 1] (2 rows, q_j affine in [h, t]) and the product h·w_j = u_j ⊗ t (4 rows).  No valid
quadratic relation has a diagonal entry on t_y or on some of the product's columns, and the cost does not
touch them: rank 1 is out of reach, the relaxation can at best be cost-tight (``--accept cost``), and a
certificate must set those columns aside (``autotight.face``).  The primary constraints alone are not
tight; relations learned per landmark make the relaxation cost-tight.  A test module
(tests/test_face_discovery.py), not a shipped problem.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from autotight.constraints import Factor, Model, Variables
from autotight.model import Constraint, QuadForm
from autotight.problem import Instance, LocalResult, Param

NAME = "stereo_translation"
PARAMS = {
    "J": Param(3, "number of landmarks", low=2),
    "sigma": Param(1.0, "pixel noise standard deviation", low=0.0),
    "prior_sigma": Param(0.5, "standard deviation of the position prior (metres)", low=0.0, low_open=True),
}
FOCAL, CU, BASELINE = 484.5, 322.0, 0.24
M = np.array([[FOCAL, CU, FOCAL * BASELINE / 2], [FOCAL, CU, -FOCAL * BASELINE / 2]])
#: the smallest depth q_j,y a sample or a local solve may reach (u is singular at depth 0)
MIN_DEPTH = 0.2


def generate(params: dict, rng: np.random.Generator) -> Instance:
    """Landmarks at uniform pixels with depth in [1, 5] seen from t ∈ [−1, 1]²."""
    J = params["J"]
    depth = rng.uniform(1.0, 5.0, J)
    q = np.column_stack([(rng.uniform(0.0, 2 * CU, J) - CU) / FOCAL * depth, depth])
    t = rng.uniform(-1.0, 1.0, 2)
    y = _ubar(q) @ M.T + params["sigma"] * rng.standard_normal((J, 2))
    prior = t + params["prior_sigma"] * rng.standard_normal(2)
    return Instance(NAME, dict(params), {"p": q - t, "y": y, "prior": prior}, {"t": t})


def _ubar(q: np.ndarray) -> np.ndarray:
    return np.column_stack([q[:, 0] / q[:, 1], np.ones(len(q)), 1.0 / q[:, 1]])


def _variables(J: int) -> Variables:
    return Variables([("t", 2)] + [b for j in range(J) for b in ((f"u_{j}", 2), (f"w_{j}", 4))])


def build(inst: Instance) -> Model:
    p, Y = inst.measurements["p"], inst.measurements["y"]
    V = _variables(len(p))
    Mu = M[:, [0, 2]] / FOCAL  # acting on u = [q_x/q_y, 1/q_y]
    tp, sp_ = inst.measurements["prior"], float(inst.params["prior_sigma"])
    prior = QuadForm(V).add("t", "t", np.eye(2)).linear("t", -2.0 * tp).const(tp @ tp).matrix() / (FOCAL * sp_) ** 2
    factors = [Factor("prior", "prior", ("h", "t"), cost=sp.csr_array(prior), data=tp)]
    for j in range(len(p)):
        u, w = f"u_{j}", f"w_{j}"
        e0 = (Y[j] - M[:, 1]) / FOCAL  # residual e = e0 − Mu u
        cost = QuadForm(V).add(u, u, Mu.T @ Mu).linear(u, -2.0 * Mu.T @ e0).const(e0 @ e0).matrix()
        cons = []
        for k in range(2):  # (p_y h + t_y) u_k − rhs_k h = 0, rhs = [p_x h + t_x, h]
            e = np.zeros((1, 2))
            e[0, k] = 1.0
            Etu = np.zeros((2, 2))
            Etu[1, k] = 1.0
            qf = QuadForm(V).add("h", u, p[j, 1] * e).add("t", u, Etu)
            qf = qf.const(-p[j, 0]).linear("t", [-1.0, 0.0]) if k == 0 else qf.const(-1.0)
            cons.append(Constraint(qf.matrix(), 0.0, name=f"s{j}:substitution{k}"))
        for a in range(2):
            for b in range(2):
                E = np.zeros((1, 4))
                E[0, 2 * a + b] = 1.0
                Eut = np.zeros((2, 2))
                Eut[a, b] = -1.0
                cons.append(Constraint(QuadForm(V).add("h", w, E).add(u, "t", Eut).matrix(), 0.0,
                                       name=f"s{j}:w{a}{b}h=u{a}t{b}"))
        factors.append(Factor(f"s{j}", "stereo", ("h", "t", u, w), cost=sp.csr_array(cost), constraints=cons,
                              roles=("h", "t", "u", "w"), data=p[j]))
    J = len(p)
    for i, j in sorted({tuple(sorted((i, (i + 1) % J))) for i in range(J)}):  # a learning group per pair
        factors.append(Factor(f"pair{i}_{j}", "stereo_pair", ("h", "t", f"u_{i}", f"w_{i}", f"u_{j}", f"w_{j}"),
                              roles=("h", "t", "u_i", "w_i", "u_j", "w_j"), data=np.concatenate([p[i], p[j]])))
    return Model(V, factors)


def _q(inst: Instance, t: np.ndarray) -> np.ndarray:
    return inst.measurements["p"] + np.asarray(t, dtype=float)


def _residuals(inst: Instance, t: np.ndarray) -> np.ndarray:
    """The image residuals (normalised by f), then the prior's (t − t̃)/(f σ_t) in the same units."""
    prior = (np.asarray(t, dtype=float) - inst.measurements["prior"]) / (FOCAL * float(inst.params["prior_sigma"]))
    return np.concatenate([((inst.measurements["y"] - _ubar(_q(inst, t)) @ M.T) / FOCAL).ravel(), prior])


def lift(inst: Instance, state: dict) -> np.ndarray:
    t = np.asarray(state["t"], dtype=float)
    q = _q(inst, t)
    u = np.column_stack([q[:, 0], np.ones(len(q))]) / q[:, 1:2]
    vals = {"t": t} | {f"u_{j}": u[j] for j in range(len(q))} | {f"w_{j}": np.outer(u[j], t).ravel()
                                                                   for j in range(len(q))}
    return _variables(len(q)).assemble(vals)


def cost(inst: Instance, state: dict) -> float:
    e = _residuals(inst, np.asarray(state["t"], dtype=float))
    return float(e @ e)


def _feasible(inst: Instance, t: np.ndarray) -> np.ndarray:
    """t moved (in y) so that every depth is at least MIN_DEPTH."""
    t = np.array(t, dtype=float)
    t[1] = max(t[1], MIN_DEPTH - float(inst.measurements["p"][:, 1].min()))
    return t


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    return {"t": _feasible(inst, np.asarray(nominal["t"], dtype=float) + spread * rng.standard_normal(2))}


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    return {"t": _feasible(inst, rng.uniform(-1.0, 1.0, 2))}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Trust-region least squares on the residuals over t (depths kept ≥ MIN_DEPTH / 2)."""
    low = MIN_DEPTH / 2 - float(inst.measurements["p"][:, 1].min())
    sol = least_squares(lambda t: _residuals(inst, t), _feasible(inst, init["t"]),
                        bounds=([-np.inf, low], [np.inf, np.inf]), xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=max_iter)
    state = {"t": sol.x}
    return LocalResult(state, cost(inst, state), int(sol.nfev), bool(sol.success))


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    x = np.asarray(Theta, dtype=float).reshape(-1)
    return {"t": x[1:3] / x[0]}


def errors(inst: Instance, state: dict) -> dict:
    return {"t": float(np.linalg.norm(np.asarray(state["t"], dtype=float) - inst.truth["t"]))}
