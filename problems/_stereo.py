"""Stereo localisation in d = 2 or 3 dimensions (AutoTight's Stereo2DLifter / Stereo3DLifter).

Unknown camera pose (C, t): a known landmark p_j (world) is q_j = C p_j + t in the camera frame.  A
rectified stereo pair with focal length f, principal point (c_u, c_v) and baseline b measures

    y_j = M [q_{j,1..d−1}/q_{j,d}, 1, 1/q_{j,d}] + n_j,   n_j ~ N(0, σ² I)  (pixels),

with M = [[f, c_u, f b/2], [f, c_u, −f b/2]] in 2D (left and right u) and the 4 × 4 matrix of the left
and right (u, v) in 3D.  Cost Σ_j ‖y_j − M ū_j‖² / f² (normalised image units).

Substitution (the peer's level "no"): u_j = [q_{j,1..d−1}, 1]/q_{j,d} (d entries), so the cost is
quadratic in [h, u_j] and the substitution is the quadratic q_{j,d} u_j = [q_{j,1..d−1}; 1]:

    x = [h, t, vec C, u_0, …, u_{N−1}]                       (level "no", n = 1 + d + d² + dN)
    x = [h, t, vec C, (u_j, w_j = vec_row(u_j tᵀ))_j]        (level "urT", n = 1 + d + d² + (d + d²)N)

Primary constraints: CᵀC = I (factor "rotation"), per landmark the d rows of q_d u = [q_{<d}; 1] and, at
"urT", h·w_j = u_j ⊗ t (d² rows).  The lifted variety at N = 3, d = 2 has 35 (level "no") and 191
(level "urT") independent quadratic relations, as the peer prints.

Factors: "rotation" (h, c); per landmark "stereo" (h, t, c, u_j[, w_j]) with data p_j; at level "urT", per
cyclically consecutive pair "stereo_pair" (h, u_i, w_i, u_j, w_j) with data (p_i, p_j), no cost or
constraint: a learning group for the relations between two landmarks without the pose (the peer's
cost-tight set at "urT" needs its [h, z_0, z_1] group).  At level "no" two landmarks' u have no quadratic
relation, and their monomial data no clean spectral gap: no pair groups there.  At level
"no" the factor's relations move with p_j by the change of variables t ↦ t + (p_jᵀ ⊗ I) vec C = q_j
(``transport``), an exact template for any landmark.  At "urT" that map would need u ⊗ vec C
(w' = u (t + C p)ᵀ), which the lifting does not hold; there the pose is rotated and scaled instead,
(C, t) ↦ (C R, t/‖p‖) with R e_1 = p/‖p‖, which takes q to q/‖p‖ and maps u and w = u tᵀ linearly
(``transport_urT``).  Pairs have no such map (one rotation and scale cannot take two landmarks to a
fixed reference pair): they are learned per factor.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from autotight.constraints import (Affine, Constraint, Factor, Model, QuadForm, Variables, const, quad, sum_quads,
                                   var)
from autotight.errors import ParameterError
from autotight.problem import Instance, LocalResult, Param

from . import _landmark_terms as lt
from . import _pose_vector as pv

LEVELS = ("no", "urT")
FOCAL, CU, CV, BASELINE = 484.5, 322.0, 247.0, 0.24  # the peer's camera


def params(n_landmarks: int, level: str) -> dict[str, Param]:
    return {
        "n_landmarks": Param(n_landmarks, "number N of known landmarks", low=1),
        "sigma": Param(1.0, "pixel noise standard deviation", low=0.0),
        "level": Param(level, "lifting: 'no' (u_j) or 'urT' (u_j and u_j tᵀ)", choices=LEVELS),
    }


def camera(d: int) -> np.ndarray:
    """M: 2 × 3 (d = 2) or 4 × 4 (d = 3), acting on ū = [q_{<d}/q_d, 1, 1/q_d]."""
    s = FOCAL * BASELINE / 2
    if d == 2:
        return np.array([[FOCAL, CU, s], [FOCAL, CU, -s]])
    return np.array([[FOCAL, 0, CU, s], [0, FOCAL, CV, 0], [FOCAL, 0, CU, -s], [0, FOCAL, CV, 0]])


def u_block(j: int) -> str:
    return f"u{j}"


def w_block(j: int) -> str:
    return f"w{j}"


def variables(d: int, N: int, level: str) -> Variables:
    blocks = pv.pose_blocks(d)
    for j in range(N):
        blocks.append((u_block(j), d))
        if level == "urT":
            blocks.append((w_block(j), d * d))
    return Variables(blocks)


def _level(inst: Instance) -> str:
    level = inst.params.get("level", "no")
    if level not in LEVELS:
        raise ParameterError(f"level must be one of {list(LEVELS)}, got {level!r}")
    return level


def generate(name: str, d: int, params: dict, rng: np.random.Generator) -> Instance:
    """Landmarks seen at uniform pixels with depth in [1, 5], mapped to the world by a random pose."""
    N = params["n_landmarks"]
    depth = rng.uniform(1.0, 5.0, N)
    pix = rng.uniform(0.0, 2 * np.array([CU, CV][:d - 1]), (N, d - 1))
    centre = np.array([CU, CV][:d - 1])
    q = np.hstack([(pix - centre) / FOCAL * depth[:, None], depth[:, None]])
    C, t = lt.random_rotation(rng, d), rng.uniform(-1.0, 1.0, d)
    points = (q - t) @ C  # rows Cᵀ(q_j − t)
    y = ubar(q) @ camera(d).T + params["sigma"] * rng.standard_normal((N, camera(d).shape[0]))
    return Instance(name, dict(params), {"points": points, "y": y}, {"C": C, "t": t})


def ubar(q: np.ndarray) -> np.ndarray:
    """[q_{<d}/q_d, 1, 1/q_d] per row of q (N, d) → (N, d + 1)."""
    qd = q[:, -1:]
    return np.hstack([q[:, :-1] / qd, np.ones_like(qd), 1.0 / qd])


def substitution(q: np.ndarray) -> np.ndarray:
    """u = [q_{<d}, 1]/q_d per row (N, d)."""
    return np.hstack([q[:, :-1], np.ones((len(q), 1))]) / q[:, -1:]


def _primary(V: Variables, j: int, p: np.ndarray, level: str, factor: str) -> list[Constraint]:
    d = len(p)
    q = pv.point_map(p)
    u = var(u_block(j), size=d)
    out = []
    for k in range(d):
        rhs = q.row(k) if k < d - 1 else const(1.0)
        qf = quad(V, q.row(d - 1), u.row(k))
        quad(V, const(1.0), -1.0 * rhs, into=qf)
        out.append(Constraint(qf.matrix(), 0.0, name=f"subst({j}:{k})", factor=factor))
    if level == "urT":
        for a in range(d):
            for b in range(d):
                E = np.zeros((1, d * d))
                E[0, a * d + b] = 1.0
                qf = QuadForm(V).add("h", w_block(j), E)
                Eut = np.zeros((d, d))
                Eut[a, b] = -1.0
                qf.add(u_block(j), pv.T_BLOCK, Eut)
                out.append(Constraint(qf.matrix(), 0.0, name=f"urT({j}:{a},{b})", factor=factor))
    return out


def build(inst: Instance) -> Model:
    P, Y = inst.measurements["points"], inst.measurements["y"]
    N, d = P.shape
    level = _level(inst)
    V = variables(d, N, level)
    M = camera(d)
    Mt = M[:, list(range(d - 1)) + [d]]  # columns acting on u = [q_{<d}/q_d, 1/q_d]
    m = M[:, d - 1]  # the column of the constant 1
    factors = [Factor("rotation", "rotation", ("h", pv.C_BLOCK), constraints=pv.orthonormality(V, d, "rotation"))]
    blocks = ("h", pv.T_BLOCK, pv.C_BLOCK)
    roles = ("h", "t", "c", "u") + (("w",) if level == "urT" else ())
    for j in range(N):
        name = f"landmark_{j}"
        e = Affine({"h": ((Y[j] - m) / FOCAL)[:, None], u_block(j): -Mt / FOCAL})
        own = (u_block(j),) + ((w_block(j),) if level == "urT" else ())
        factors.append(Factor(name, "stereo" if level == "no" else "stereo_urT", blocks + own,
                              cost=sum_quads(V, [(e, e, None)]), constraints=_primary(V, j, P[j], level, name),
                              roles=roles, data=P[j]))
    for i, j in pairs(N) if level == "urT" else []:
        own_i = (u_block(i),) + ((w_block(i),) if level == "urT" else ())
        own_j = (u_block(j),) + ((w_block(j),) if level == "urT" else ())
        factors.append(Factor(f"pair_{i}_{j}", "stereo_pair", ("h",) + own_i + own_j,
                              roles=("h",) + tuple(f"{r}_i" for r in roles[3:]) + tuple(f"{r}_j" for r in roles[3:]),
                              data=np.concatenate([P[i], P[j]])))
    return Model(V, factors)


def pairs(N: int) -> list[tuple[int, int]]:
    """Cyclically consecutive landmark pairs (j, j + 1 mod N): N pairs for N ≥ 3, one for N = 2."""
    if N < 2:
        return []
    return sorted({tuple(sorted((j, (j + 1) % N))) for j in range(N)})


def transport(data: np.ndarray) -> np.ndarray:
    """M on [h, t, vec C, u] (level "no"): t ↦ t + (pᵀ ⊗ I) vec C = q, the rest unchanged; the reference
    landmark is p = 0 (then q = t)."""
    p = np.asarray(data, float).ravel()
    d = len(p)
    n = 1 + d + d * d + d
    M = np.eye(n)
    M[1:1 + d, 1 + d:1 + d + d * d] = np.kron(p[None, :], np.eye(d))
    return M


def rotation_to(v: np.ndarray) -> np.ndarray:
    """A rotation R (d × d) with R e_1 = v/‖v‖."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    if len(v) == 2:
        return np.array([[v[0], -v[1]], [v[1], v[0]]])
    a = np.eye(3)[int(np.argmin(np.abs(v)))]  # the axis least aligned with v
    b = np.cross(v, a)
    b /= np.linalg.norm(b)
    return np.column_stack([v, np.cross(b, v), b])


def transport_urT(data: np.ndarray) -> np.ndarray:
    """M on [h, t, vec C, u, w = vec_row(u tᵀ)] (level "urT"): the pose (C, t) ↦ (C R, s t) with s = 1/‖p‖ and
    R e_1 = p/‖p‖, so that q' = C R e_1 + s t = s q: landmark p becomes the reference e_1.  Then
    u' = D u with D = diag(1, …, 1, 1/s) (u's last entry is 1/q_d) and w' = u' t'ᵀ = s D u tᵀ: every
    block maps linearly (vec(C R) = (Rᵀ ⊗ I) vec C).  Singular only for a landmark at the world origin."""
    p = np.asarray(data, float).ravel()
    d = len(p)
    sc = 1.0 / np.linalg.norm(p)
    D = np.ones(d)
    D[-1] = 1.0 / sc
    blocks = [np.ones((1, 1)), sc * np.eye(d), np.kron(rotation_to(p).T, np.eye(d)), np.diag(D),
              np.kron(np.diag(sc * D), np.eye(d))]
    n = sum(b.shape[0] for b in blocks)
    M = np.zeros((n, n))
    o = 0
    for b in blocks:
        M[o:o + b.shape[0], o:o + b.shape[0]] = b
        o += b.shape[0]
    return M


def camera_points(inst: Instance, state: dict) -> np.ndarray:
    return inst.measurements["points"] @ np.asarray(state["C"], float).T + np.asarray(state["t"], float)


def lift(inst: Instance, state: dict) -> np.ndarray:
    P = inst.measurements["points"]
    N, d = P.shape
    level = _level(inst)
    t = np.asarray(state["t"], float)
    vals = pv.pose_values(state["C"], t)
    for j, u in enumerate(substitution(camera_points(inst, state))):
        vals[u_block(j)] = u
        if level == "urT":
            vals[w_block(j)] = np.outer(u, t).ravel()
    return variables(d, N, level).assemble(vals)


def residual(inst: Instance, state: dict) -> tuple[np.ndarray, np.ndarray]:
    """e_j = (y_j − M ū_j)/f stacked, and its Jacobian in [ψ, δ]."""
    P, Y = inst.measurements["points"], inst.measurements["y"]
    d = P.shape[1]
    M = camera(d)
    C = np.asarray(state["C"], float)
    q = camera_points(inst, state)
    es, Js = [], []
    for p, y, qj in zip(P, Y, q):
        qd = qj[-1]
        D = np.zeros((d + 1, d))  # ∂ū/∂q
        D[:d - 1, :d - 1] = np.eye(d - 1) / qd
        D[:d - 1, d - 1] = -qj[:-1] / qd ** 2
        D[d, d - 1] = -1.0 / qd ** 2
        es.append((y - M @ ubar(qj[None])[0]) / FOCAL)
        Js.append(-(M @ D @ pv.point_jacobian(C, p)) / FOCAL)
    return np.concatenate(es), np.vstack(Js)


def cost(inst: Instance, state: dict) -> float:
    e, _ = residual(inst, state)
    return float(e @ e)


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float, min_depth: float = 0.2,
           tries: int = 200) -> dict:
    """A pose near ``nominal`` (``_pose_vector.sample_pose``), redrawn until every landmark is at depth
    ≥ min_depth (u = q/q_d is singular at q_d = 0)."""
    for _ in range(tries):
        s = pv.sample_pose(rng, nominal, spread)
        if np.min(camera_points(inst, s)[:, -1]) >= min_depth:
            return s
    raise ParameterError(f"no pose within spread {spread} keeps every landmark at depth ≥ {min_depth}")


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    d = inst.measurements["points"].shape[1]
    return {"C": lt.random_rotation(rng, d), "t": rng.uniform(-1.0, 1.0, d)}


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    return pv.pose_gauss_newton(lambda s: residual(inst, s), init, max_iter)


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    P = inst.measurements["points"]
    N, d = P.shape
    C, t, C_raw = pv.pose_from_vector(Theta, variables(d, N, _level(inst)), d)
    return {"C": C, "t": t, "det_raw": np.array(np.linalg.det(C_raw))}


def errors(inst: Instance, state: dict) -> dict:
    return pv.pose_errors(state, inst.truth)


def module_parts(name: str, d: int) -> tuple[Callable, ...]:
    """(generate, build, lift, cost, sample, random_state, local_solve, recover, errors) for a module."""

    def gen(params: dict, rng: np.random.Generator) -> Instance:
        return generate(name, d, params, rng)

    return gen, build, lift, cost, sample, random_state, local_solve, recover, errors
