"""Discrete-time trajectory estimation (Barfoot, Holmes, Dümbgen 2024, §4).

Estimate K poses T_k from a noisy measurement of every pose, T_k = cay(ξ_k^∧) T̃_k, and a noisy
relative measurement between consecutive poses, T_{k+1} = cay(ξ_{k+1,k}^∧) T̃_{k+1,k} T_k.

Ground truth: a helix, T_{k+1} = exp(ϖ^∧) T_k with the constant body twist
ϖ = [speed, 0, climb, 0, 0, turn_rate] (per step), starting from a random orientation, with the world
origin at the centroid of the positions (see ``centred``).  T_k maps world to body k coordinates.
Noise: T̃_k = cay(ν_k^∧) T_k and T̃_{k+1,k} = cay(ν_{k+1,k}^∧) T_{k+1} T_k⁻¹ with ν ~ N(0, σ² I₆).
Weights W_k = W_{k+1,k} = I: for the paper's isotropic W⁻¹ = σ² I this is the same problem with the
cost scaled by σ² (same minimiser and relaxation), and it stays finite at σ = 0.

Lifting (0-based k)  x = [h, (c_{k,1}, c_{k,2}, c_{k,3}, r_k)_{k<K}, (ρ_k, φ_k)_{k<K}, (ρ_{k+1,k}, φ_{k+1,k})_{k<K−1}],
n = 1 + 12K + 6K + 6(K − 1).  Block names: pose k is ``T{k}_c1 … T{k}_r``, ξ_k is ``rho_{k}, phi_{k}``,
ξ_{k+1,k} is ``rho_{k+1}_{k}, phi_{k+1}_{k}``.
Cost  Σ ξ_kᵀ W_k ξ_k + Σ ξ_{k+1,k}ᵀ W_{k+1,k} ξ_{k+1,k}.
Factors: per k "so3" (orthonormality of C_k) and "pose_meas" {h, C_k, r_k, ξ_k} (12 Cayley rows);
per k < K − 1 "odometry" {h, C_k, r_k, C_{k+1}, r_{k+1}, ξ_{k+1,k}} (12 Cayley rows).
Factor data (``Factor.data``, for learned templates): the 12 entries [C̃ r̃] of the factor's measured
pose (row-major 3×4), T̃_k for "pose_meas" and T̃_{k+1,k} for "odometry"; "so3" has none.
Paper families: R1 (3 per k), R2 (1 per k), R3 (3 per k < K − 1).
Cliques: the unary and odometry factors' block sets (sizes 19 and 31) form a clique tree, so the
aggregate sparsity is chordal and the SDP decomposes into 2K − 1 small PSD blocks (see ``cliques``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.errors import ParameterError
from autotight.gauss_newton import BlockJacobian, BlockPattern, block_sparse, block_weight, gauss_newton
from autotight.model import Factor, Model, Variables
from autotight.problem import Instance, LocalResult, Meta, Param

from . import _pose_batch as pb
from ._cayley import draw_valid
from ._pose import MEASURED_POSE_NAMES
from ._pose import (POSE_ROLES, XI_ROLES, binary_cayley, binary_transport, declare_pose, declare_xi, pose_blocks,
                    pose_from_x, pose_orthonormality, r1_unary, r2_unary, r3_binary, unary_cayley, unary_transport,
                    weighted_cost, xi_blocks)

NAME = "discrete_trajectory"
DESCRIPTION = "Estimate K poses from pose and relative-pose measurements (paper §4)."
PARAMS = {
    "K": Param(20, "number of poses (≥ 2)", low=2),
    "sigma": Param(0.1, "noise standard deviation of every ξ component (rad, and length units)", low=0.0),
    "speed": Param(1.0, "forward distance travelled per step", low=0.0),
    "turn_rate": Param(0.3, "yaw rotation per step (rad); the Cayley map needs |turn| well below π", low=-2.5,
                       high=2.5),
    "climb": Param(0.1, "vertical distance per step (makes the path a helix)"),
}

META = Meta(
    #: the paper's claim for R1–R3 (Fig. 8, 100 trials per σ on one geometry; the figure's values are not
    #: stated in the text), shown beside our verdicts in the report's "Against the paper" table
    paper_claim={
        "source": "Fig. 8: 'the global solution remains highly rank 1 over a wide range of measurement noise values'",
        "set": "paper",
        "default": "log SVR above 5 (rank 1)",
    },
    #: a hint (``autotight.discovery.engine``): a learned set should carry to long chains, so ``discover`` also
    #: validates it on held-out chains of 200 poses (every failing one becomes a training instance), with our
    #: IPM unless --solver is given.  Selected at K = 5 alone the set is one pair, not tight at K = 100.
    carry_to={"params": {"K": 200}, "solver": "ipm"},
)

#: each factor type's learned relations move with its measurement (``Factor.data``) by this change of
#: variables (``autotight.discovery.transport``): templates for relations that no low-degree polynomial fits
TRANSPORTS = {"pose_meas": unary_transport, "odometry": binary_transport}
#: names of each factor type's data entries (``Factor.data``), for printed closed forms
DATA_NAMES = {"pose_meas": MEASURED_POSE_NAMES, "odometry": MEASURED_POSE_NAMES}

#: roles of an odometry factor: pose k, then pose k+1 (primed), then ξ_{k+1,k}
ODOMETRY_ROLES = ("h", *POSE_ROLES, *(f"{r}'" for r in POSE_ROLES), *XI_ROLES)


def pose_prefix(k: int) -> str:
    return f"T{k}_"


def unary_name(k: int) -> str:
    return f"{k}"


def binary_name(k: int) -> str:
    """Residual name of ξ_{k+1,k}."""
    return f"{k + 1}_{k}"


def _count(inst: Instance) -> int:
    K = len(inst.measurements["T_meas"])
    if K < 2:
        raise ParameterError(f"discrete_trajectory needs K ≥ 2 poses, got {K}")
    if len(inst.measurements["T_rel"]) != K - 1:
        raise ParameterError(f"{K} poses need {K - 1} relative measurements, got {len(inst.measurements['T_rel'])}")
    return K


def helix(K: int, T0: np.ndarray, speed: float, turn_rate: float, climb: float) -> np.ndarray:
    """(K, 4, 4) poses T_{k+1} = exp(ϖ^∧) T_k with ϖ = [speed, 0, climb, 0, 0, turn_rate]."""
    step = lie.exp_se3(np.array([speed, 0.0, climb, 0.0, 0.0, turn_rate]))
    Ts = [np.asarray(T0, dtype=float)]
    for _ in range(K - 1):
        Ts.append(step @ Ts[-1])
    return np.array(Ts)


def centred(Ts: np.ndarray) -> np.ndarray:
    """The same trajectory with the world origin moved to the centroid of the positions p_k = −C_kᵀ r_k.

    T_k ← T_k [[I, p̄], [0ᵀ, 1]]; relative poses are unchanged.  The relaxation is not invariant to the
    choice of origin: small |r_k| keeps the lifted SDP well scaled (at K = 20 the clique-decomposed solve
    reached a relative cost accuracy of ~1e-7 centred against ~1e-5 with the origin at a trajectory end).
    """
    p_bar = np.mean([-T[:3, :3].T @ T[:3, 3] for T in Ts], axis=0)
    return Ts @ lie.make_pose(np.eye(3), p_bar)


def generate(params: dict, rng: np.random.Generator) -> Instance:
    K, sigma = params["K"], params["sigma"]
    if K < 2:
        raise ParameterError(f"discrete_trajectory needs K ≥ 2 poses, got {K}")
    Ts = centred(helix(K, lie.make_pose(lie.random_rotation(rng), np.zeros(3)), params["speed"],
                       params["turn_rate"], params["climb"]))
    T_meas = np.array([lie.cay_se3(sigma * rng.standard_normal(6)) @ T for T in Ts])
    T_rel = np.array([lie.cay_se3(sigma * rng.standard_normal(6)) @ Ts[k + 1] @ lie.inv_se3(Ts[k])
                      for k in range(K - 1)])
    meas = {"T_meas": T_meas, "T_rel": T_rel, "W": np.repeat(np.eye(6)[None], K, axis=0),
            "W_rel": np.repeat(np.eye(6)[None], K - 1, axis=0)}
    return Instance(NAME, dict(params), meas, {"C": Ts[:, :3, :3].copy(), "r": Ts[:, :3, 3].copy()})


def _variables(K: int) -> Variables:
    blocks = [b for k in range(K) for b in declare_pose(pose_prefix(k))]
    blocks += [b for k in range(K) for b in declare_xi(unary_name(k))]
    blocks += [b for k in range(K - 1) for b in declare_xi(binary_name(k))]
    return Variables(blocks)


def cliques(K: int) -> list[tuple[str, ...]]:
    """The factors' own block sets: {h, pose k, ξ_k} (k < K) and {h, pose k, pose k+1, ξ_{k+1,k}} (k < K − 1).

    They form a clique tree (the binary cliques in a chain, each unary clique hung on a binary one
    holding its pose), so the aggregate sparsity is chordal and the decomposed SDP equals the dense one.
    Sizes 19 and 31; at K = 20 this solved ~1.5–2.5× faster than the coarser chain
    {h, pose k, ξ_k, pose k+1, ξ_{k+1,k}} (size 37) with the same cost.
    """
    out = [("h", *pose_blocks(pose_prefix(k)), *xi_blocks(unary_name(k))) for k in range(K)]
    out += [("h", *pose_blocks(pose_prefix(k)), *pose_blocks(pose_prefix(k + 1)), *xi_blocks(binary_name(k)))
            for k in range(K - 1)]
    return out


#: from this many poses on, ``build`` makes each factor type's constraints and costs for all factors at once
#: (``_pose_batch``; entries equal to rounding); below, factor by factor
BATCH_MIN_POSES = 32


def build(inst: Instance) -> Model:
    K = _count(inst)
    if K >= BATCH_MIN_POSES:
        return _build_batched(inst)
    m = inst.measurements
    V = _variables(K)
    factors: list[Factor] = []
    paper: dict[str, list] = {"R1": [], "R2": [], "R3": []}
    for k in range(K):
        p, s, name = pose_prefix(k), unary_name(k), f"meas_{k}"
        pose = pose_blocks(p)
        factors.append(Factor(f"rotation_{k}", "so3", ("h", *pose[:3]),
                              constraints=pose_orthonormality(V, p, factor=f"rotation_{k}"),
                              roles=("h", "c1", "c2", "c3")))
        factors.append(Factor(name, "pose_meas", ("h", *pose, *xi_blocks(s)), cost=weighted_cost(V, s, m["W"][k]),
                              constraints=unary_cayley(V, p, m["T_meas"][k], s, name),
                              roles=("h", *POSE_ROLES, *XI_ROLES), data=m["T_meas"][k][:3, :]))
        paper["R1"] += r1_unary(V, p, m["T_meas"][k], s, name, factor=name)
        paper["R2"] += r2_unary(V, p, m["T_meas"][k], s, name, factor=name)
    for k in range(K - 1):
        p1, p2, s, name = pose_prefix(k), pose_prefix(k + 1), binary_name(k), f"odom_{k + 1}_{k}"
        factors.append(Factor(name, "odometry", ("h", *pose_blocks(p1), *pose_blocks(p2), *xi_blocks(s)),
                              cost=weighted_cost(V, s, m["W_rel"][k]),
                              constraints=binary_cayley(V, p1, p2, m["T_rel"][k], s, name), roles=ODOMETRY_ROLES,
                              data=m["T_rel"][k][:3, :]))
        paper["R3"] += r3_binary(V, p1, p2, m["T_rel"][k], s, name, factor=name)
    return Model(V, factors, paper=paper, cliques=cliques(K))


def _build_batched(inst: Instance) -> Model:
    """``build`` with every factor type made at once (``_pose_batch``): the same model up to rounding."""
    K = _count(inst)
    m = inst.measurements
    V = _variables(K)
    N = V.N
    poses = [pose_blocks(pose_prefix(k)) for k in range(K)]
    un_cols = np.array([V.index(("h", *poses[k], *xi_blocks(unary_name(k)))) for k in range(K)])
    bi_cols = np.array([V.index(("h", *poses[k], *poses[k + 1], *xi_blocks(binary_name(k)))) for k in range(K - 1)])
    rot_cols = un_cols[:, :10]
    D_un, D_bi = pb.pose_data(m["T_meas"]), pb.pose_data(m["T_rel"])
    W_un, W_bi = np.asarray(m["W"], float).reshape(K, 36), np.asarray(m["W_rel"], float).reshape(K - 1, 36)
    rot_names, un_names = [f"rotation_{k}" for k in range(K)], [f"meas_{k}" for k in range(K)]
    bi_names = [f"odom_{binary_name(k)}" for k in range(K - 1)]
    un_subs = [{pb.POSE1: pose_prefix(k), pb.XI: unary_name(k), pb.NAME: un_names[k]} for k in range(K)]
    bi_subs = [{pb.POSE1: pose_prefix(k), pb.POSE2: pose_prefix(k + 1), pb.XI: binary_name(k), pb.NAME: bi_names[k]}
               for k in range(K - 1)]
    rot = pb.rotation_batch().constraints(np.zeros((K, 0)), rot_cols, N, rot_names, pb.renamer(un_subs))
    un = pb.unary_cayley_batch().constraints(D_un, un_cols, N, un_names, pb.renamer(un_subs))
    bi = pb.binary_cayley_batch().constraints(D_bi, bi_cols, N, bi_names, pb.renamer(bi_subs))
    un_cost = pb.unary_cost_batch().matrices(W_un, un_cols, N)
    bi_cost = pb.binary_cost_batch().matrices(W_bi, bi_cols, N)
    factors: list[Factor] = []
    for k in range(K):
        factors.append(Factor(rot_names[k], "so3", ("h", *poses[k][:3]), constraints=rot[k],
                              roles=("h", "c1", "c2", "c3")))
        factors.append(Factor(un_names[k], "pose_meas", ("h", *poses[k], *xi_blocks(unary_name(k))),
                              cost=un_cost[k][0], constraints=un[k], roles=("h", *POSE_ROLES, *XI_ROLES),
                              data=m["T_meas"][k][:3, :]))
    for k in range(K - 1):
        factors.append(Factor(bi_names[k], "odometry", ("h", *poses[k], *poses[k + 1], *xi_blocks(binary_name(k))),
                              cost=bi_cost[k][0], constraints=bi[k], roles=ODOMETRY_ROLES,
                              data=m["T_rel"][k][:3, :]))
    flat = lambda per: [c for cs in per for c in cs]  # noqa: E731
    paper = {"R1": flat(pb.r1_batch().constraints(D_un, un_cols, N, un_names, pb.renamer(un_subs))),
             "R2": flat(pb.r2_batch().constraints(D_un, un_cols, N, un_names, pb.renamer(un_subs))),
             "R3": flat(pb.r3_batch().constraints(D_bi, bi_cols, N, bi_names, pb.renamer(bi_subs)))}
    return Model(V, factors, paper=paper, cliques=cliques(K))


# ----------------------------------------------------------------------------- states and residuals


def _poses(state: dict) -> np.ndarray:
    C, r = np.asarray(state["C"], dtype=float), np.asarray(state["r"], dtype=float)
    if C.ndim != 3 or C.shape[1:] != (3, 3) or r.shape != (C.shape[0], 3):
        raise ParameterError(f"a trajectory state needs C (K, 3, 3) and r (K, 3), got {C.shape} and {r.shape}")
    T = np.repeat(np.eye(4)[None], len(C), axis=0)
    T[:, :3, :3], T[:, :3, 3] = C, r
    return T


def _state(Ts: np.ndarray) -> dict:
    return {"C": Ts[:, :3, :3].copy(), "r": Ts[:, :3, 3].copy()}


def residuals(inst: Instance, state: dict) -> tuple[np.ndarray, np.ndarray]:
    """(ξ_k (K, 6), ξ_{k+1,k} (K−1, 6)); raises CayleySingularityError at rotation angle π."""
    Ts = _poses(state)
    m = inst.measurements
    if len(Ts) != len(m["T_meas"]):
        raise ParameterError(f"a state of {len(Ts)} poses for an instance of K = {len(m['T_meas'])}")
    un = lie.cay_inv_se3_batch(Ts @ lie.inv_se3_batch(np.asarray(m["T_meas"])))
    bi = lie.cay_inv_se3_batch(Ts[1:] @ lie.inv_se3_batch(Ts[:-1]) @ lie.inv_se3_batch(np.asarray(m["T_rel"])))
    return un, bi.reshape(-1, 6)


def lift(inst: Instance, state: dict) -> np.ndarray:
    """x in the block order of the module docstring, all poses at once: per pose c1, c2, c3 (the columns
    of C), r; then every ξ_k; then every ξ_{k+1,k}."""
    K = _count(inst)
    un, bi = residuals(inst, state)
    C, r = np.asarray(state["C"], dtype=float), np.asarray(state["r"], dtype=float)
    poses = np.concatenate([np.swapaxes(C, 1, 2).reshape(K, 9), r], axis=1)
    return np.concatenate([[1.0], poses.ravel(), un.ravel(), bi.ravel()])[None, :]


def cost(inst: Instance, state: dict) -> float:
    un, bi = residuals(inst, state)
    m = inst.measurements
    return float(sum(e @ W @ e for e, W in zip(un, m["W"])) + sum(e @ W @ e for e, W in zip(bi, m["W_rel"])))


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """T_k = exp((spread·ν_k)^∧) T_nominal,k, ν_k ~ N(0, I₆) independently; redrawn near the Cayley singularity."""
    T0 = _poses(nominal)
    return draw_valid(lambda: _state(lie.exp_se3_batch(spread * rng.standard_normal((len(T0), 6))) @ T0),
                      lambda state: residuals(inst, state))


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    """Independent uniform rotations; translations ~ N(0, s² I) with s the spread of the true translations."""
    K = _count(inst)
    s = max(float(np.std(inst.truth["r"])), 1.0)
    nominal = {"C": np.array([lie.random_rotation(rng) for _ in range(K)]), "r": s * rng.standard_normal((K, 3))}
    return sample(inst, rng, nominal, 0.0)


# ----------------------------------------------------------------------------- local solver


def weight(inst: Instance) -> sp.csr_array:
    """The block-diagonal weight of the stacked residuals of ``linearize`` (sparse)."""
    m = inst.measurements
    return block_weight(np.concatenate([np.asarray(m["W"]), np.asarray(m["W_rel"])]), dense_max=0)


def linearize(inst: Instance, Ts: np.ndarray, W: sp.csr_array | None = None
              ) -> tuple[np.ndarray, sp.csr_array, sp.csr_array]:
    """Stacked residuals e = [ξ_0 … ξ_{K−1}, ξ_{1,0} … ξ_{K−1,K−2}] (6(2K−1),), sparse Jacobian w.r.t.
    ε = [ε_0 … ε_{K−1}] for T_k = cay(ε_k^∧) T_op,k (6(2K−1) × 6K), and the block-diagonal weight
    (``weight``; given as W, it is not built again)."""
    m = inst.measurements
    Ts = np.asarray(Ts)
    K = len(Ts)
    xi_u, J_u = lie.residuals_se3(Ts, np.asarray(m["T_meas"]))  # all factors of a type in one pass
    xi_b, J1, J2 = lie.residuals_se3_binary(Ts[:-1], Ts[1:], np.asarray(m["T_rel"]))
    # the 6 × 6 Jacobians at block (residual, pose): unary k → (k, k), binary k → (K + k, k) and (K + k, k + 1)
    brow = np.concatenate([np.arange(K), K + np.arange(K - 1), K + np.arange(K - 1)])
    bcol = np.concatenate([np.arange(K), np.arange(K - 1), np.arange(1, K)])
    J = block_sparse(brow, bcol, np.concatenate([J_u, J1, J2]), (6 * (2 * K - 1), 6 * K))
    return np.concatenate([xi_u.ravel(), xi_b.ravel()]), J, weight(inst) if W is None else W


def block_pattern(K: int) -> BlockPattern:
    """Where the 6 × 6 Jacobian blocks of ``linearize`` sit: unary k → (k, k), binary k → (K + k, k) and
    (K + k, k + 1)."""
    brow = np.concatenate([np.arange(K), K + np.arange(K - 1), K + np.arange(K - 1)])
    bcol = np.concatenate([np.arange(K), np.arange(K - 1), np.arange(1, K)])
    return BlockPattern(brow, bcol, 6, 6, (6 * (2 * K - 1), 6 * K))


def linearize_blocks(inst: Instance, Ts: np.ndarray, W: sp.csr_array, pattern: BlockPattern
                     ) -> tuple[np.ndarray, BlockJacobian, sp.csr_array]:
    """``linearize`` with the Jacobian as its 6 × 6 blocks and the weight blocks (``BlockJacobian`` on
    ``block_pattern(K)``), from which Gauss-Newton forms the block-tridiagonal normal equations directly;
    W: ``weight(inst)``."""
    m = inst.measurements
    Ts = np.asarray(Ts)
    xi_u, J_u = lie.residuals_se3(Ts, np.asarray(m["T_meas"]))
    xi_b, J1, J2 = lie.residuals_se3_binary(Ts[:-1], Ts[1:], np.asarray(m["T_rel"]))
    weights = np.concatenate([np.asarray(m["W"], float), np.asarray(m["W_rel"], float)])
    J = BlockJacobian(pattern, np.concatenate([J_u, J1, J2]), weights)
    return np.concatenate([xi_u.ravel(), xi_b.ravel()]), J, W


def retract(Ts: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """T_k ← cay(ε_k^∧) T_k (paper (77)); ε (6K,)."""
    return lie.cay_se3_batch(np.asarray(eps).reshape(-1, 6)) @ Ts


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton (App. A.4, LM-damped) on the sparse stacked system (HᵀWH) ε = −HᵀW e."""
    pattern = block_pattern(_count(inst))
    W = weight(inst)  # the same at every iterate, as the Jacobian's block pattern
    res = gauss_newton(lambda Ts: linearize_blocks(inst, Ts, W, pattern), retract, _poses(init), max_iter=max_iter)
    res.state = _state(res.state)
    return res


# ----------------------------------------------------------------------------- recovery and errors


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """Poses from the rank-1 factor x: raw rotation blocks (dets reported as "det_raw" (K,)) projected to SO(3)."""
    K = _count(inst)
    x = np.asarray(Theta, dtype=float).reshape(-1)
    x = x / x[0]
    V = _variables(K)
    raw = [pose_from_x(V, x, pose_prefix(k)) for k in range(K)]
    return {"C": np.array([lie.project_to_so3(C) for C, _ in raw]), "r": np.array([r for _, r in raw]),
            "det_raw": np.array([np.linalg.det(C) for C, _ in raw])}


def errors(inst: Instance, state: dict) -> dict:
    """Largest rotation error (deg) and largest translation error ‖r_k − r_k,true‖ over the trajectory."""
    return {"rotation_deg": lie.rotation_error_deg(state["C"], inst.truth["C"]),
            "translation": float(np.linalg.norm(state["r"] - inst.truth["r"], axis=1).max())}
