"""Range-only localisation with the "quad" lifting (AutoTight, Dümbgen et al. 2024, range-only "y_n").

N unknown positions p_n ∈ R^d (d = 2 or 3), K known anchors a_k.  Each position measures its distance to
every anchor: d̃_nk = ‖a_k − p_n‖ + n_nk, n_nk ~ N(0, σ²).  Cost (squared-distance residuals):

    f(p) = Σ_nk (d̃_nk² − ‖a_k − p_n‖²)²  =  Σ_nk (d̃_nk² − ‖a_k‖² + 2 a_kᵀ p_n − tr Z_n)²

Lifting ("quad"): z_n = vech(p_n p_nᵀ) = [x², xy, (xz,) y², (yz, z²)] (upper triangle, row by row, no
scaling), so each residual is linear in [h, p_n, z_n]:  x = [h, p_0, z_0, …, p_{N−1}, z_{N−1}].
Primary constraints: h·z_n = vech(p_n p_nᵀ) (d(d+1)/2 per position).  The lifted variety of one
position, (1, p, vech ppᵀ), has 6 (d = 2) or 20 (d = 3) independent quadratic relations
(the peer prints "found 14 learned templates" beside 6 known ones for d = 3).

Factors: one "position" factor per n (h, p_n, z_n) with its cost and primary constraints; no data
(its relations do not depend on the anchors), so a learned set carries to any N.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from autotight.constraints import Affine, Constraint, Factor, Model, QuadForm, Variables, sum_quads
from autotight.gauss_newton import gauss_newton
from autotight.problem import Instance, LocalResult, Param

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
CHECK_PARAMS = {"dim": 3, "n_positions": 2, "n_anchors": 6, "sigma": 0.01, "extent": 2.0}
PAPER_CLAIM = {"source": "AutoTight _results_test/terminal_output.log, RO (y_n) row: d = 3, N = 3",
               "set": "paper", "default": "61 constraints → 33 required; rank-tight (SVR 2.3e9)"}


def tri(d: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of vech's entries (upper triangle, row by row)."""
    return np.triu_indices(d)


def vech(p: np.ndarray) -> np.ndarray:
    """Upper triangle of ppᵀ, row by row (no √2)."""
    p = np.asarray(p, float)
    i, j = tri(len(p))
    return p[i] * p[j]


def p_block(n: int) -> str:
    return f"p{n}"


def z_block(n: int) -> str:
    return f"z{n}"


def _variables(N: int, d: int) -> Variables:
    m = d * (d + 1) // 2
    return Variables([b for n in range(N) for b in ((p_block(n), d), (z_block(n), m))])


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    e = params["extent"]
    anchors = rng.uniform(-e, e, (params["n_anchors"], d))
    p = rng.uniform(-e, e, (params["n_positions"], d))
    dist = np.linalg.norm(anchors[None, :, :] - p[:, None, :], axis=2)  # (N, K)
    meas = dist + params["sigma"] * rng.standard_normal(dist.shape)
    return Instance(NAME, dict(params), {"anchors": anchors, "ranges": meas}, {"p": p})


def _residual(V: Variables, n: int, anchors: np.ndarray, ranges: np.ndarray) -> Affine:
    """e_k = d̃_k² − ‖a_k‖² + 2 a_kᵀ p_n − tr(p_n p_nᵀ), linear in (h, p_n, z_n) (K rows)."""
    d = anchors.shape[1]
    i, j = tri(d)
    trace = (i == j).astype(float)
    K = len(anchors)
    return Affine({"h": (ranges ** 2 - np.sum(anchors ** 2, axis=1))[:, None], p_block(n): 2 * anchors,
                   z_block(n): -np.tile(trace, (K, 1))})


def _lifting_constraints(V: Variables, n: int, d: int, factor: str) -> list[Constraint]:
    """h·z_n[k] = p_n[i] p_n[j] for vech index k = (i, j)."""
    out = []
    for k, (i, j) in enumerate(zip(*tri(d))):
        E = np.zeros((d, d))
        E[i, j] = 1.0
        ez = np.zeros((1, d * (d + 1) // 2))
        ez[0, k] = -1.0
        qf = QuadForm(V).add(p_block(n), p_block(n), E).add("h", z_block(n), ez)
        out.append(Constraint(qf.matrix(), 0.0, name=f"vech({n}:{i},{j})", factor=factor))
    return out


def build(inst: Instance) -> Model:
    anchors, ranges = inst.measurements["anchors"], inst.measurements["ranges"]
    N, d = ranges.shape[0], anchors.shape[1]
    V = _variables(N, d)
    factors = []
    for n in range(N):
        name = f"position_{n}"
        e = _residual(V, n, anchors, ranges[n])
        factors.append(Factor(name, "position", ("h", p_block(n), z_block(n)), cost=sum_quads(V, [(e, e, None)]),
                              constraints=_lifting_constraints(V, n, d, name), roles=("h", "p", "z")))
    return Model(V, factors)


def _positions(inst: Instance, state: dict) -> np.ndarray:
    return np.asarray(state["p"], float).reshape(inst.measurements["ranges"].shape[0], -1)


def lift(inst: Instance, state: dict) -> np.ndarray:
    p = _positions(inst, state)
    vals = {}
    for n, pn in enumerate(p):
        vals |= {p_block(n): pn, z_block(n): vech(pn)}
    return _variables(*p.shape).assemble(vals)


def _residuals(inst: Instance, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """e_nk = d̃_nk² − ‖a_k − p_n‖² (N·K,) and its Jacobian in p (N·K × N·d)."""
    a, y = inst.measurements["anchors"], inst.measurements["ranges"]
    N, d = p.shape
    diff = a[None, :, :] - p[:, None, :]  # (N, K, d)
    e = (y ** 2 - np.sum(diff ** 2, axis=2)).ravel()
    J = sp.block_diag([2 * diff[n] for n in range(N)], format="csr")
    return e, J


def cost(inst: Instance, state: dict) -> float:
    e, _ = _residuals(inst, _positions(inst, state))
    return float(e @ e)


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    p = _positions(inst, nominal)
    return {"p": p + spread * rng.standard_normal(p.shape)}


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    e = inst.params["extent"]
    return {"p": rng.uniform(-e, e, _positions(inst, inst.truth).shape)}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton (LM-damped) on the positions."""
    shape = _positions(inst, init).shape

    def linearize(p: np.ndarray) -> tuple[np.ndarray, sp.csr_array, sp.dia_array]:
        e, J = _residuals(inst, p.reshape(shape))
        return e, J, sp.eye_array(e.size, format="dia")

    res = gauss_newton(linearize, lambda p, eps: p + eps.reshape(shape), _positions(inst, init).copy(),
                       max_iter=max_iter)
    res.state = {"p": res.state}
    return res


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    x = np.asarray(Theta, float).reshape(-1)
    x = x / x[0]
    N, d = inst.measurements["ranges"].shape[0], inst.measurements["anchors"].shape[1]
    V = _variables(N, d)
    return {"p": np.array([x[V.slice(p_block(n))] for n in range(N)])}


def errors(inst: Instance, state: dict) -> dict:
    diff = _positions(inst, state) - inst.truth["p"]
    return {"position": float(np.sqrt(np.mean(np.sum(diff ** 2, axis=1))))}
