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

Written on the factor-graph layer (``autotight.graph``):

- variables: t ∈ R^d (no model factor of its own) and C ∈ SO(d) (block c = vec C; its factor "rotation" (h, c)
  holds CᵀC = I, named orth(i,j)) (``variables``);
- factors: per landmark "landmark_j" of type "stereo" (level "no") or "stereo_urT" on (t, C), owning
  u_j = [q_{<d}, 1]/q_d (block ``u{j}``) and, at "urT", w_j = vec_row(u_j tᵀ) (block ``w{j}``) (``lifted``):
  residual (y_j − M ū_j)/f, its lifted cost, the substitution rows subst(j:k) and the product rows urT(j:a,b)
  its primary constraints, data p_j; blocks (h, t, c, u_j[, w_j]);
- groups: at "urT", per landmark pair "pair_i_j" of type "stereo_pair" (h, u_i, w_i, u_j, w_j), data (p_i, p_j),
  no cost or constraint: a learning group for the relations between two landmarks without the pose (the peer's
  cost-tight set at "urT" needs its [h, z_0, z_1] group).  In 2-D every pair i < j (``all_pairs``), as the peer's
  templates take them: with only the cyclically consecutive ones a set learned at N = 3 was not tight at N = 20.
  In 3-D the cyclically consecutive pairs (``cyclic_pairs``, N of them): every pair would give its SDP at N = 20
  about 1700 constraints on 253 columns, one Clarabel solve of more than 10 minutes, and the 3-D set is not
  cost-tight at N = 3 to begin with (reports/peer_benchmark/report.md).  At N = 3 both are the same three pairs.
  At level "no" two landmarks' u have no quadratic relation, and their monomial data no clean spectral gap: no
  pair groups there;
- sampler: C = exp(spread·ν^∧) C̄ then t = t̄ + spread·n (the rotation's step drawn first), drawn again until
  every landmark is at depth ≥ ``MIN_DEPTH`` (u = q/q_d is singular at q_d = 0; ``in_front``), up to
  ``SAMPLE_TRIES`` times.

At level "no" a landmark factor's relations move with p_j by the change of variables t ↦ t + (p_jᵀ ⊗ I) vec C
= q_j (``transport``), an exact template for any landmark.  At "urT" that map would need u ⊗ vec C
(w' = u (t + C p)ᵀ), which the lifting does not hold; there the pose is rotated and scaled instead,
(C, t) ↦ (C R, t/‖p‖) with R e_1 = p/‖p‖, which takes q to q/‖p‖ and maps u and w = u tᵀ linearly
(``transport_urT``).  Pairs have no such map (one rotation and scale cannot take two landmarks to a
fixed reference pair): they are learned per factor.

Hand-written parts, which keep the committed reports' numbers to the last bit: each landmark's lifted cost and
primary constraints are declared as matrices on its local columns [h, t, c, u(, w)] (``landmark_cost``,
``landmark_constraints``), since the layer's affine read-off and equation fit evaluate at h = 1 and round where
a measurement or a landmark coordinate meets a constant; u_j is computed from every landmark's camera point
at once (the rows of P Cᵀ + t and C p_j + t differ in the last bit); the random start (a uniform rotation,
t uniform in [−1, 1]^d) and the local solver (``local_solve``: Gauss-Newton with the analytic Jacobian in
[ψ, δ], ``_pose_vector.pose_gauss_newton``) are the module's, since the layer's derived solver (central
differences here, the cost being declared) reaches the same optima in the same iterations but not the same
bits (costs to 2e-13, liftings up to 1e-9 apart), and the SDP is solved in the frame of the local optimum's
lifting.
"""

from __future__ import annotations

from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from autotight.constraints import Affine, QuadForm, Variables, const, quad, sum_quads, var
from autotight.errors import ParameterError
from autotight.graph import Auxiliary, Euclidean, Factor, Group, Rotation, Variable, View, derive
from autotight.problem import Instance, LocalResult, Param

from . import _landmark_terms as lt
from . import _pose_vector as pv

LEVELS = ("no", "urT")
FOCAL, CU, CV, BASELINE = 484.5, 322.0, 247.0, 0.24  # the peer's camera
#: the least depth of every landmark in a sample (u = q/q_d is singular at q_d = 0)
MIN_DEPTH = 0.2
#: draws of ``sample`` before it gives up
SAMPLE_TRIES = 200


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


def variables(inst: Instance) -> list[Variable]:
    """t ∈ R^d (block t) and C ∈ SO(d) (block c = vec C, its own factor "rotation" holding orth(i,j))."""
    d = inst.measurements["points"].shape[1]
    return [Variable("t", Euclidean(d)),
            Variable("C", Rotation(d), type="rotation", block=pv.C_BLOCK, constraint_names="{constraint}")]


def local_blocks(d: int, level: str) -> Variables:
    """A landmark factor's local columns [h, t, c, u(, w)]."""
    return Variables(pv.pose_blocks(d) + [("u", d)] + ([("w", d * d)] if level == "urT" else []))


def landmark_cost(L: Variables, y: np.ndarray) -> sp.coo_array:
    """‖(y − M ū)/f‖² = ‖((y − m) h − M_u u)/f‖² on the local columns L (m: M's column of the constant 1, M_u
    its columns acting on u = [q_{<d}/q_d, 1/q_d])."""
    d = L.sizes["u"]
    M = camera(d)
    e = Affine({"h": ((y - M[:, d - 1]) / FOCAL)[:, None], "u": -M[:, list(range(d - 1)) + [d]] / FOCAL})
    return sum_quads(L, [(e, e, None)])


def landmark_constraints(L: Variables, j: int, p: np.ndarray, level: str) -> list[tuple[str, sp.coo_array]]:
    """On the local columns L: q_d u = [q_{<d}; h] (subst(j:k), q = C p + t) and, at "urT", h·w = u ⊗ t
    (urT(j:a,b))."""
    d = len(p)
    q = pv.point_map(p)
    u = var("u", size=d)
    out = []
    for k in range(d):
        rhs = q.row(k) if k < d - 1 else const(1.0)
        qf = quad(L, q.row(d - 1), u.row(k))
        quad(L, const(1.0), -1.0 * rhs, into=qf)
        out.append((f"subst({j}:{k})", qf.matrix()))
    if level == "urT":
        for a in range(d):
            for b in range(d):
                E = np.zeros((1, d * d))
                E[0, a * d + b] = 1.0
                qf = QuadForm(L).add("h", "w", E)
                Eut = np.zeros((d, d))
                Eut[a, b] = -1.0
                qf.add("u", pv.T_BLOCK, Eut)
                out.append((f"urT({j}:{a},{b})", qf.matrix()))
    return out


def lifted(u: np.ndarray, t: np.ndarray, level: str) -> np.ndarray:
    """[u_j(, w_j = vec_row(u_j tᵀ))] from u_j at the pose."""
    return u if level == "no" else np.concatenate([u, np.outer(u, t).ravel()])


def factors(inst: Instance) -> Iterator[Factor | Group]:
    """Per landmark its substitution blocks and the residual (y_j − M ū_j)/f; at "urT" the pairs' groups."""
    P, Y = inst.measurements["points"], inst.measurements["y"]
    N, d = P.shape
    level = _level(inst)
    L = local_blocks(d, level)
    M = camera(d)
    blocks = {"u": d} | ({"w": d * d} if level == "urT" else {})
    # u_j from every landmark's camera point at once (rows of P Cᵀ + t), once per pose for all N factors
    subst = pv.last_pose(lambda t, C: substitution(P @ C.T + t))
    for j in range(N):
        aux = Auxiliary(blocks, value=lambda t, C, j=j: lifted(subst(t.x, C.x)[j].copy(), t.x, level),
                        element="{block}{i}")

        def residual(t: View, C: View, a: View, y: np.ndarray = Y[j]) -> np.ndarray:
            return (y - M @ np.concatenate([a.u[:d - 1], [1.0], a.u[d - 1:]])) / FOCAL

        yield Factor(("t", "C"), residual, type="stereo" if level == "no" else "stereo_urT",
                     cost=landmark_cost(L, Y[j]), constraints=landmark_constraints(L, j, P[j], level),
                     constraint_names="{constraint}", data=P[j], auxiliary=aux, name=f"landmark_{j}")
    for i, j in (all_pairs(N) if d == 2 else cyclic_pairs(N)) if level == "urT" else []:
        yield Group((u_block(i), w_block(i), u_block(j), w_block(j)), "stereo_pair", roles=("u_i", "w_i", "u_j", "w_j"),
                    data=np.concatenate([P[i], P[j]]), name=f"pair_{i}_{j}")


def camera_points(inst: Instance, state: dict) -> np.ndarray:
    return inst.measurements["points"] @ np.asarray(state["C"], float).T + np.asarray(state["t"], float)


def in_front(inst: Instance, state: dict) -> bool:
    """Whether every landmark is at depth ≥ MIN_DEPTH in the camera."""
    return bool(np.min(camera_points(inst, state)[:, -1]) >= MIN_DEPTH)


build, lift, cost, sample, _, recover = derive(variables, factors, tangent=("C", "t"), keep=in_front,
                                               tries=SAMPLE_TRIES)


def cyclic_pairs(N: int) -> list[tuple[int, int]]:
    """Cyclically consecutive landmark pairs (j, j + 1 mod N): N pairs for N ≥ 3, one for N = 2."""
    if N < 2:
        return []
    return sorted({tuple(sorted((j, (j + 1) % N))) for j in range(N)})


def all_pairs(N: int) -> list[tuple[int, int]]:
    """Every landmark pair (i, j), i < j: N(N − 1)/2 pairs.  At N = 3 the same three as ``cyclic_pairs``."""
    return [(i, j) for i in range(N) for j in range(i + 1, N)]


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


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    return pv.pose_gauss_newton(lambda s: residual(inst, s), init, max_iter)


def module_parts(name: str, d: int) -> tuple[Callable, ...]:
    """(generate, build, lift, cost, sample, random_state, local_solve, recover, errors) for a module."""

    def gen(params: dict, rng: np.random.Generator) -> Instance:
        return generate(name, d, params, rng)

    return gen, build, lift, cost, sample, pv.random_pose_state, local_solve, recover, pv.errors
