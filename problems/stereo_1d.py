"""Stereo localisation in 1-D (AutoTight's Stereo1DLifter): a position x on a line from inverse distances.

Known landmarks a_j ∈ R; each is measured as y_j = 1/(x − a_j) + n_j, n_j ~ N(0, σ²).  Cost Σ_j (y_j − z_j)²
with the substitution z_j = 1/(x − a_j):

    x_lift = [h, x, z_0, …, z_{N−1}],   primary constraints  x·z_j − a_j h·z_j = h²  (one per landmark).

The peer's redundant relations: z_i − z_j = (a_i − a_j) z_i z_j, one per pair.

Written on the factor-graph layer (``autotight.graph``):

- variable: x ∈ R, with no model factor of its own (neither a constraint nor a cost is on x alone);
- factors: per landmark "landmark_j" of type "stereo1d" on x, owning z_j = 1/(x − a_j) (block ``z{j}``):
  residual y_j − z_j, the substitution "subst(j)" its primary constraint, data a_j;
- groups: per cyclically consecutive pair (i, j) (``_stereo.cyclic_pairs``: N pairs, not N(N − 1)/2) "pair_i_j" of type
  "stereo1d_pair" on (z_i, z_j), data (a_i, a_j), no cost or constraint: a learning group, so that discovery
  learns the pair relations;
- sampler: x̄ + spread·ν, drawn again until x keeps a distance ≥ ``gap`` from every landmark (``apart``).

Hand-written parts, which keep the committed reports' numbers to the last bit: each landmark's lifted cost
and substitution are declared as matrices on its local columns [h, x, z] (``landmark_cost``, ``substitution``),
since the layer's affine read-off and equation fit evaluate at h = 1 and round where y_j or a_j meets the
constant; the random start (uniform in [0, 1] at distance ≥ gap) and the local solver (Gauss-Newton in x with
the analytic Jacobian 1/(x − a_j)²) are the module's, since the layer's derived solver (central differences
here, the cost being declared) reaches the same optima in the same iterations but not the same bits (costs to
2e-13, liftings up to 1e-10 apart), and the SDP is solved in the frame of the local optimum's lifting.

Both types carry by exact transports (``TRANSPORTS``): x ↦ x − a_j h for a landmark, z ↦ (a_i − a_j) z
for a pair (a pair's basic solutions are rational in the data: no polynomial template fits them).
As in the peer, landmarks and x are uniform in [0, 1]; x keeps a distance ≥ ``gap`` from every landmark.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import scipy.sparse as sp

from autotight.constraints import QuadForm, Variables
from autotight.errors import ParameterError
from autotight.gauss_newton import gauss_newton
from autotight.graph import Auxiliary, Euclidean, Factor, Group, Variable, derive
from autotight.problem import Instance, LocalResult, Param

from ._stereo import cyclic_pairs

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


def _draw_x(rng: np.random.Generator, a: np.ndarray, gap: float) -> float:
    for _ in range(MAX_TRIES):
        x = rng.uniform(0.0, 1.0)
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


#: the position on the line
VARIABLES = [Variable("x", Euclidean(1))]

#: a landmark factor's local columns [h, x, z]
LOCAL = Variables([("x", 1), ("z", 1)])


def landmark_cost(y: float) -> sp.coo_array:
    """(y − z)² = y² h² − 2y h·z + z² on [h, x, z]."""
    return QuadForm(LOCAL).add("h", "h", y ** 2).add("h", "z", -2 * y).add("z", "z", 1.0).matrix()


def substitution(a: float) -> sp.coo_array:
    """x·z − a h·z − h² = 0 on [h, x, z]: z = 1/(x − a)."""
    return QuadForm(LOCAL).add("x", "z", 1.0).add("h", "z", -a).add("h", "h", -1.0).matrix()


def factors(inst: Instance) -> Iterator[Factor | Group]:
    """Per landmark z_j = 1/(x − a_j) and the residual y_j − z_j; per consecutive pair a learning group."""
    a, y = inst.measurements["landmarks"], inst.measurements["y"]
    for j in range(len(a)):
        z = Auxiliary({"z": 1}, value=lambda x, a=a[j]: 1.0 / (x.x - a), element="{block}{i}")
        yield Factor("x", lambda x, z, y=y[j]: y - z.z, type="stereo1d", cost=landmark_cost(y[j]),
                     constraints=[(f"subst({j})", substitution(a[j]))], constraint_names="{constraint}",
                     data=np.array([a[j]]), auxiliary=z, name=f"landmark_{j}")
    for i, j in cyclic_pairs(len(a)):
        yield Group((z_block(i), z_block(j)), "stereo1d_pair", roles=("z_i", "z_j"), data=np.array([a[i], a[j]]),
                    name=f"pair_{i}_{j}")


def apart(inst: Instance, state: dict) -> bool:
    """Whether x keeps a distance ≥ gap from every landmark (z_j = 1/(x − a_j) stays bounded)."""
    return bool(np.min(np.abs(_x(state) - inst.measurements["landmarks"])) >= inst.params["gap"])


build, lift, cost, sample, _, recover = derive(VARIABLES, factors, keep=apart, tries=MAX_TRIES)


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


def _residual(inst: Instance, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, y = inst.measurements["landmarks"], inst.measurements["y"]
    r = x[0] - a
    return y - 1.0 / r, (1.0 / r ** 2)[:, None]


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    return {"x": np.array([_draw_x(rng, inst.measurements["landmarks"], inst.params["gap"])])}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton (LM-damped) in x (the module's, see the module docstring)."""

    def linearize(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, sp.dia_array]:
        e, J = _residual(inst, x)
        return e, J, sp.eye_array(e.size, format="dia")

    res = gauss_newton(linearize, lambda x, eps: x + eps, np.array([_x(init)]), max_iter=max_iter)
    res.state = {"x": res.state}
    return res


def errors(inst: Instance, state: dict) -> dict:
    return {"position": abs(_x(state) - _x(inst.truth))}
