"""Stereo localisation in 1-D (AutoTight's Stereo1DLifter): a position x on a line from inverse distances.

Known landmarks a_j ∈ R; each is measured as y_j = 1/(x − a_j) + n_j, n_j ~ N(0, σ²).  Cost Σ_j (y_j − z_j)²
with the substitution z_j = 1/(x − a_j):

    x_lift = [h, x, z_0, …, z_{N−1}],   primary constraints  x·z_j − a_j h·z_j = h²  (one per landmark).

The peer's redundant relations: z_i − z_j = (a_i − a_j) z_i z_j, one per pair.  Factors: per landmark
"stereo1d" (h, x, z_j) with the cost and the primary constraint (data a_j); per cyclically consecutive
pair (i, j) (``_stereo.pairs``: N pairs, not N(N − 1)/2) "stereo1d_pair" (h, z_i, z_j) with data
(a_i, a_j) and no cost or constraint: a learning group, so that ``factors`` learns the pair relations.
Both types carry by exact transports (``TRANSPORTS``): x ↦ x − a_j h for a landmark, z ↦ (a_i − a_j) z
for a pair (a pair's basic solutions are rational in the data: no polynomial template fits them).
As in the peer, landmarks and x are uniform in [0, 1]; x keeps a distance ≥ ``gap`` from every landmark.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from autotight.constraints import Constraint, Factor, Model, QuadForm, Variables
from autotight.errors import ParameterError
from autotight.gauss_newton import gauss_newton
from autotight.problem import Instance, LocalResult, Param

from ._stereo import pairs

NAME = "stereo_1d"
DESCRIPTION = "1-D stereo localisation from inverse distances z_j = 1/(x − a_j) (AutoTight's stereo1d)."
PARAMS = {
    "n_landmarks": Param(3, "number N of landmarks", low=1),
    "sigma": Param(1e-3, "noise standard deviation of each y_j", low=0.0),
    "gap": Param(0.05, "smallest distance of x (truth and samples) from a landmark", low=0.0, low_open=True,
                 high=0.2),
}
MAX_TRIES = 1000


def z_block(j: int) -> str:
    return f"z{j}"


def _variables(N: int) -> Variables:
    return Variables([("x", 1)] + [(z_block(j), 1) for j in range(N)])


def _draw_x(rng: np.random.Generator, a: np.ndarray, gap: float, centre: float | None = None,
            spread: float = 0.0) -> float:
    for _ in range(MAX_TRIES):
        x = rng.uniform(0.0, 1.0) if centre is None else centre + spread * rng.standard_normal()
        if np.min(np.abs(x - a)) >= gap:
            return float(x)
    raise ParameterError(f"no position at distance ≥ gap = {gap} from every landmark in {MAX_TRIES} draws")


def generate(params: dict, rng: np.random.Generator) -> Instance:
    N, gap = params["n_landmarks"], params["gap"]
    for _ in range(MAX_TRIES):
        a = rng.uniform(0.0, 1.0, N)
        try:
            x = _draw_x(rng, a, gap)
            break
        except ParameterError:
            continue
    else:
        raise ParameterError(f"no layout of {N} landmarks leaves a gap {gap} for x; lower gap or n_landmarks")
    y = 1.0 / (x - a) + params["sigma"] * rng.standard_normal(N)
    return Instance(NAME, dict(params), {"landmarks": a, "y": y}, {"x": np.array([x])})


def build(inst: Instance) -> Model:
    a, y = inst.measurements["landmarks"], inst.measurements["y"]
    N = len(a)
    V = _variables(N)
    factors = []
    for j in range(N):
        name, z = f"landmark_{j}", z_block(j)
        Q = QuadForm(V).add("h", "h", y[j] ** 2).add("h", z, -2 * y[j]).add(z, z, 1.0).matrix()
        A = QuadForm(V).add("x", z, 1.0).add("h", z, -a[j]).add("h", "h", -1.0).matrix()
        factors.append(Factor(name, "stereo1d", ("h", "x", z), cost=Q,
                              constraints=[Constraint(A, 0.0, name=f"subst({j})", factor=name)],
                              roles=("h", "x", "z"), data=np.array([a[j]])))
    for i, j in pairs(N):
        factors.append(Factor(f"pair_{i}_{j}", "stereo1d_pair", ("h", z_block(i), z_block(j)),
                              roles=("h", "z_i", "z_j"), data=np.array([a[i], a[j]])))
    return Model(V, factors)


def landmark_transport(data: np.ndarray) -> np.ndarray:
    """M on [h, x, z] (type "stereo1d"): x ↦ x − a h, so x z = 1 + a z becomes x' z = 1 (reference a = 0)."""
    M = np.eye(3)
    M[1, 0] = -float(np.asarray(data).ravel()[0])
    return M


def pair_transport(data: np.ndarray) -> np.ndarray:
    """M on [h, z_i, z_j] (type "stereo1d_pair"): z ↦ (a_i − a_j) z, so z_i − z_j = (a_i − a_j) z_i z_j
    becomes z'_i − z'_j = z'_i z'_j (reference a_i − a_j = 1; singular only for coincident landmarks)."""
    a_i, a_j = np.asarray(data, float).ravel()[:2]
    return np.diag([1.0, a_i - a_j, a_i - a_j])


TRANSPORTS = {"stereo1d": landmark_transport, "stereo1d_pair": pair_transport}


def _x(state: dict) -> float:
    return float(np.asarray(state["x"], float).reshape(-1)[0])


def lift(inst: Instance, state: dict) -> np.ndarray:
    x, a = _x(state), inst.measurements["landmarks"]
    z = 1.0 / (x - a)
    return _variables(len(a)).assemble({"x": np.array([x])} | {z_block(j): z[j:j + 1] for j in range(len(a))})


def _residual(inst: Instance, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, y = inst.measurements["landmarks"], inst.measurements["y"]
    r = x[0] - a
    return y - 1.0 / r, (1.0 / r ** 2)[:, None]


def cost(inst: Instance, state: dict) -> float:
    e, _ = _residual(inst, np.array([_x(state)]))
    return float(e @ e)


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    a = inst.measurements["landmarks"]
    return {"x": np.array([_draw_x(rng, a, inst.params["gap"], _x(nominal), spread)])}


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    return {"x": np.array([_draw_x(rng, inst.measurements["landmarks"], inst.params["gap"])])}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton (LM-damped) in x."""

    def linearize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, sp.dia_array]:
        e, J = _residual(inst, x)
        return e, J, sp.eye_array(e.size, format="dia")

    res = gauss_newton(linearize, lambda x, eps: x + eps, np.array([_x(init)]), max_iter=max_iter)
    res.state = {"x": res.state}
    return res


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    x = np.asarray(Theta, float).reshape(-1)
    return {"x": np.array([x[1] / x[0]])}


def errors(inst: Instance, state: dict) -> dict:
    return {"position": abs(_x(state) - _x(inst.truth))}
