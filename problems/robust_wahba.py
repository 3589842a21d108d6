"""Robust point-to-point registration with truncated least squares (AutoTight's rPPR).

As ``wahba`` (q_i = C p_i + t, residual r_i = C p_i + t − y_i), with a binary label w_i ∈ {±1} per point
(1 inlier, −1 outlier) and the TLS cost of the peer:

    f(C, t, w) = ½ Σ_i [(1 + w_i)/β² ‖r_i‖² + 1 − w_i],     min_w f = Σ_i min(‖r_i‖²/β², 1).

Lifting (the peer's level "xwT"): x = [h, t, vec C, (w_i, z_i)_i] with z_i = w_i [t; vec C]
(n = 1 + (d + d²)(N + 1) + N).  With u_i = r_i (affine in h, t, c) and v_i = w_i r_i (affine in w_i,
z_i), (1 + w_i)‖r_i‖² = u_iᵀu_i + u_iᵀv_i, so the cost is quadratic.

Written on the factor-graph layer (``autotight.graph``):

- variables: t ∈ R^d; C ∈ SO(d) (block c), whose factor "rotation" (h, c) holds CᵀC = I; per point a label
  w_i ∈ {±1} (``Binary``: w_i² = h²) with the product block z_i = w_i [t; vec C] (primary constraints
  h·z_i = w_i [t; vec C]), whose factor "point_i" of type "tls_point" is (h, t, c, w_i, z_i).  The primary
  constraints keep the names saved sets carry: orth(j,k), w²(i), z(i:k) (``constraint_name``).
- factors: per point the TLS term, its lifted cost given (``tls_cost``: it is not eᵀWe of a residual affine in
  the lifting), which joins "point_i"; per pair i < j the learning group "pair_i_j" of type "tls_pair"
  (h, t, c, w_i, z_i, w_j, z_j), without cost or constraint, for the relations between two points (the peer
  learns on [h, t, c, z_0, z_1]).  None has data: the lifted variety does not depend on the measurements, so
  a learned set carries to any N.

The layer derives ``build``, ``lift``, ``recover`` and the pose's samples (its rotation step drawn first).
Written by hand: ``cost``, the TLS formula above, by which the local solver compares labellings (the layer's
Σ eᵀWe agrees to rounding only); the labels' draws in ``sample`` (a binary variable has no steps); and
``local_solve``, the enumeration of the 2^N labellings (closed-form registration of each labelling's inliers),
so N ≤ ``MAX_BRUTE_FORCE``.

Outliers: the first ``n_outliers`` points are measured at a uniform random position in a box of
half-width ``outlier_extent`` instead of C p_i + t (the peer's published run has none).  Lifted columns t
and z_i's t part appear in no relation squared: rank 1 is not expected (the peer reports cost-tight with
SVR 34); use ``--accept cost``.
"""

from __future__ import annotations

import itertools
from typing import Iterator

import numpy as np

from autotight.constraints import Affine, QuadForm, Variables, sum_quads
from autotight.errors import ParameterError
from autotight.graph import Binary, Euclidean, Factor, Group, Rotation, Variable, View, derive
from autotight.problem import Instance, LocalResult, Meta, Param

from . import _landmark_terms as lt
from . import _pose_vector as pv

NAME = "robust_wahba"
DESCRIPTION = "Point-to-point registration with outliers: TLS with binary w_i, z_i = w_i [t; vec C] (AutoTight's rPPR)."
PARAMS = {
    "dim": Param(3, "dimension d: 2 or 3"),
    "n_points": Param(4, "number N of point correspondences", low=1),
    "n_outliers": Param(1, "how many of them are outliers", low=0),
    "sigma": Param(0.01, "inlier noise standard deviation", low=0.0),
    "beta": Param(0.1, "TLS threshold: a residual below β counts as an inlier", low=0.0, low_open=True),
    "outlier_extent": Param(2.0, "outliers are uniform in a box of this half-width", low=0.0, low_open=True),
}
META = Meta(paper_claim={"source": "AutoTight _results_test/terminal_output.log, rPPR row (wahba_3d_xwT_no_robust)",
                         "set": "paper", "default": "1771 constraints → 925 required; cost-tight (RDG 1.1e-6), SVR 34"})
MAX_BRUTE_FORCE = 12


def generate(params: dict, rng: np.random.Generator) -> Instance:
    d = lt.check_dim(params["dim"])
    N, K = params["n_points"], params["n_outliers"]
    if K > N:
        raise ParameterError(f"n_outliers = {K} exceeds n_points = {N}")
    points = rng.standard_normal((N, d))
    C, t = lt.random_rotation(rng, d), rng.uniform(-1.0, 1.0, d)
    y = points @ C.T + t + params["sigma"] * rng.standard_normal(points.shape)
    e = params["outlier_extent"]
    y[:K] = rng.uniform(-e, e, (K, d))
    w = np.where(np.arange(N) < K, -1.0, 1.0)
    meas = {"points": points, "y": y, "beta": np.array(params["beta"])}
    return Instance(NAME, dict(params), meas, {"C": C, "t": t, "w": w})


def constraint_name(equation: str, row: int | None, index: int | None, **_: object) -> str:
    """A primary constraint's name (``Variable.constraint_names``): C's orth(j,k); point i's w²(i) and z(i:k), row k
    of z_i."""
    if index is None:
        return equation
    return f"{equation}({index})" if row is None else f"{equation}({index}:{row})"


def variables(inst: Instance) -> list[Variable]:
    """t ∈ R^d, C ∈ SO(d) (block c, factor "rotation") and the labels w ∈ {±1}^N, z_i = w_i [t; vec C]
    (factor "point_i" of type "tls_point")."""
    d = inst.measurements["points"].shape[1]
    t = Variable("t", Euclidean(d))
    C = Variable("C", Rotation(d), type="rotation", block=pv.C_BLOCK, constraint_names=constraint_name)
    w = Variable("w", Binary(), products={"z": (t, C)}, type="tls_point", factor="point",
                 constraint_names=constraint_name)
    return [t, C, w]


def _pose_map(p: np.ndarray) -> np.ndarray:
    """P with C p + t = P [t; vec C]."""
    d = len(p)
    return np.hstack([np.eye(d), np.kron(p[None, :], np.eye(d))])


def tls_cost(p: np.ndarray, y: np.ndarray, beta: float) -> np.ndarray:
    """The point's lifted TLS cost on its local columns [h, t, c, w, z]: (uᵀu + uᵀv)/(2β²) + (h² − h w)/2 with
    u = C p + t − h y and v = P z − w y = w u (P: ``_pose_map``)."""
    d = len(p)
    V = Variables(pv.pose_blocks(d) + [("w", 1), ("z", d + d * d)])
    u = pv.point_map(p) - Affine({"h": y[:, None]})
    v = Affine({"z": _pose_map(p), "w": -y[:, None]})
    Q = sum_quads(V, [(u, u, np.eye(d) / (2 * beta ** 2)), (u, v, np.eye(d) / (2 * beta ** 2))])
    return (Q + QuadForm(V).add("h", "h", 0.5).add("h", "w", -0.5).matrix()).toarray()


def tls_residual(t: View, C: View, w: View, p: np.ndarray, y: np.ndarray, beta: float) -> np.ndarray:
    """e = [(1 + w)/2 · r/β; (1 − w)/2] at states, so that eᵀe is the point's TLS term at w = ±1."""
    return np.r_[(1 + w.x) / 2 * (C.x @ p + t.x - y) / beta, (1 - w.x) / 2]


def factors(inst: Instance) -> Iterator[Factor | Group]:
    """Per point its TLS term on (t, C, w_i); per pair i < j the learning group on t, c, w_i, z_i, w_j, z_j."""
    P, Y, beta = inst.measurements["points"], inst.measurements["y"], float(inst.measurements["beta"])
    for i, (p, y) in enumerate(zip(P, Y)):
        yield Factor(("t", "C", f"w{i}"), lambda t, C, w, p=p, y=y: tls_residual(t, C, w, p, y, beta),
                     type="tls_point", cost=tls_cost(p, y, beta))
    for i, j in itertools.combinations(range(len(P)), 2):
        yield Group(("t", "c", f"w{i}", f"z{i}", f"w{j}", f"z{j}"), "tls_pair", name=f"pair_{i}_{j}",
                    roles=("t", "c", "w_i", "z_i", "w_j", "z_j"))


_parts = derive(variables, factors, tangent=("C", "t", "w"))
build = _parts.build


def _labels(inst: Instance, state: dict) -> np.ndarray:
    N = len(inst.measurements["points"])
    w = np.asarray(state.get("w", np.ones(N)), float).reshape(-1)
    if w.shape != (N,) or not np.all(np.abs(w) == 1.0):
        raise ParameterError(f"state w must hold {N} entries ±1, got {w}")
    return w


def lift(inst: Instance, state: dict) -> np.ndarray:
    """The layer's lift with the labels checked (N entries ±1; absent: every point an inlier)."""
    return _parts.lift(inst, state | {"w": _labels(inst, state)})


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """The layer's recover (C projected on SO(d), t, each label the sign of w_i/h, det_raw), in the order of keys
    that ``solve --json`` has printed for this problem."""
    out = _parts.recover(inst, Theta)
    return {k: out[k] for k in ("C", "t", "w", "det_raw")}


def _sq_residuals(inst: Instance, C: np.ndarray, t: np.ndarray) -> np.ndarray:
    P, Y = inst.measurements["points"], inst.measurements["y"]
    return np.sum((P @ np.asarray(C).T + t - Y) ** 2, axis=1)


def cost(inst: Instance, state: dict) -> float:
    w, beta = _labels(inst, state), float(inst.measurements["beta"])
    r2 = _sq_residuals(inst, state["C"], state["t"])
    return float(0.5 * np.sum((1 + w) / beta ** 2 * r2 + 1 - w))


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """The layer's pose near ``nominal`` (C = exp(spread·ν^∧) C̄, then t = t̄ + spread·n) and each w_i = ±1 with
    probability ½ (``nominal``'s labels are not used)."""
    N = len(inst.measurements["points"])
    pose = _parts.sample(inst, rng, {**nominal, "w": np.ones(N)}, spread)
    return {"C": pose["C"], "t": pose["t"], "w": rng.choice([-1.0, 1.0], size=N)}


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    N, d = inst.measurements["points"].shape
    return {"C": lt.random_rotation(rng, d), "t": rng.uniform(-1.0, 1.0, d), "w": rng.choice([-1.0, 1.0], size=N)}


def register(P: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """argmin_{C ∈ SO(d), t} Σ ‖C p_i + t − y_i‖² in closed form (centroids and an SVD)."""
    pm, ym = P.mean(axis=0), Y.mean(axis=0)
    C = Rotation(P.shape[1]).project((Y - ym).T @ (P - pm))
    return C, ym - C @ pm


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """The best of the 2^N labellings (``init``'s labels are ignored): each labelling's inliers are registered
    in closed form (with fewer than d inliers the registration is not unique: Gauss-Newton on them from
    ``init``'s pose); the TLS cost of the result at that labelling.  A global solver over w for N ≤ 12,
    written by hand (the layer's solver moves continuous variables only)."""
    P, Y = inst.measurements["points"], inst.measurements["y"]
    N, d = P.shape
    if N > MAX_BRUTE_FORCE:
        raise ParameterError(f"the local solver enumerates 2^N labellings; N = {N} > {MAX_BRUTE_FORCE}")
    beta = float(inst.measurements["beta"])
    best: LocalResult | None = None
    iters = 0
    for bits in itertools.product([True, False], repeat=N):
        inl = np.array(bits)
        w = np.where(inl, 1.0, -1.0)
        if inl.sum() >= d:
            C, t = register(P[inl], Y[inl])
            res = LocalResult({"C": C, "t": t}, 0.0, 1, True)
        elif inl.any():
            def residual(s: dict, idx: np.ndarray = inl) -> tuple[np.ndarray, np.ndarray]:
                Cs, ts = np.asarray(s["C"]), np.asarray(s["t"])
                e = (P[idx] @ Cs.T + ts - Y[idx]).ravel() / beta
                return e, np.vstack([pv.point_jacobian(Cs, p) for p in P[idx]]) / beta
            res = pv.pose_gauss_newton(residual, init, max_iter)
        else:
            res = LocalResult({"C": np.asarray(init["C"], float), "t": np.asarray(init["t"], float)}, 0.0, 0, True)
        iters += res.iterations
        res.state = {"C": res.state["C"], "t": res.state["t"], "w": w}
        res.cost = cost(inst, res.state)
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    best.iterations = iters
    return best


def errors(inst: Instance, state: dict) -> dict:
    out = pv.pose_errors(state, inst.truth)
    if "w" in state:
        out["labels_wrong"] = float(np.sum(np.asarray(state["w"]) != inst.truth["w"]))
    return out
