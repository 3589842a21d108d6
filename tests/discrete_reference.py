"""Discrete trajectory's model as it was written by hand before it moved onto the factor-graph layer: factor by
factor (``_pose``) or every factor type at once (``pose_batch``), for the tests that compare against it."""

from __future__ import annotations

import numpy as np

from autotight.model import Factor, Model, Variables
import pose_batch as pb
from problems._pose import (POSE_ROLES, XI_ROLES, binary_cayley, declare_pose, declare_xi, pose_blocks,
                            pose_orthonormality, r1_unary, r2_unary, r3_binary, unary_cayley, weighted_cost, xi_blocks)
from problems.discrete_trajectory import ODOMETRY_ROLES, binary_name, cliques, pose_prefix, unary_name


def _variables(K: int) -> Variables:
    blocks = [b for k in range(K) for b in declare_pose(pose_prefix(k))]
    blocks += [b for k in range(K) for b in declare_xi(unary_name(k))]
    blocks += [b for k in range(K - 1) for b in declare_xi(binary_name(k))]
    return Variables(blocks)


def hand_written_model(inst, batched: bool = False) -> Model:
    """Blocks [h, (T{k}_c1, T{k}_c2, T{k}_c3, T{k}_r)_k, (rho_k, phi_k)_k, (rho_{k+1}_k, phi_{k+1}_k)_k]; per k the
    factors "rotation_k" (so3) and "meas_k" (pose_meas), then per k < K − 1 "odom_{k+1}_k" (odometry); paper
    families R1, R2, R3; the factors' cliques.  ``batched``: every factor type made at once (``pose_batch``),
    as the hand-written module did from 32 poses on."""
    m = inst.measurements
    K = len(m["T_meas"])
    V = _variables(K)
    return _batched(inst, K, V) if batched else _direct(inst, K, V)


def _direct(inst, K: int, V: Variables) -> Model:
    m = inst.measurements
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


def _batched(inst, K: int, V: Variables) -> Model:
    m = inst.measurements
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
    paper = {"R1": [c for cs in pb.r1_batch().constraints(D_un, un_cols, N, un_names, pb.renamer(un_subs)) for c in cs],
             "R2": [c for cs in pb.r2_batch().constraints(D_un, un_cols, N, un_names, pb.renamer(un_subs)) for c in cs],
             "R3": [c for cs in pb.r3_batch().constraints(D_bi, bi_cols, N, bi_names, pb.renamer(bi_subs)) for c in cs]}
    return Model(V, factors, paper=paper, cliques=cliques(K))


# ----------------------------------------------------------------------------- the hand-written module's other parts


def hand_written_lift(inst, state: dict) -> np.ndarray:
    """x (1, N): per pose c1, c2, c3, r; every ξ_k; every ξ_{k+1,k} (``discrete_trajectory.residuals``)."""
    from problems.discrete_trajectory import residuals

    C, r = np.asarray(state["C"], dtype=float), np.asarray(state["r"], dtype=float)
    un, bi = residuals(inst, state)
    poses = np.concatenate([np.swapaxes(C, 1, 2).reshape(len(C), 9), r], axis=1)
    return np.concatenate([[1.0], poses.ravel(), un.ravel(), bi.ravel()])[None, :]


def hand_written_cost(inst, state: dict) -> float:
    from problems.discrete_trajectory import residuals

    un, bi = residuals(inst, state)
    m = inst.measurements
    return float(sum(e @ W @ e for e, W in zip(un, m["W"])) + sum(e @ W @ e for e, W in zip(bi, m["W_rel"])))


def hand_written_recover(inst, Theta: np.ndarray) -> dict:
    """Poses from x / h: raw rotation blocks (their dets "det_raw") projected to SO(3) by ``lie.project_to_so3``."""
    from autotight import lie
    from problems._pose import pose_from_x

    K = len(inst.measurements["T_meas"])
    x = np.asarray(Theta, dtype=float).reshape(-1)
    x = x / x[0]
    V = _variables(K)
    raw = [pose_from_x(V, x, pose_prefix(k)) for k in range(K)]
    return {"C": np.array([lie.project_to_so3(C) for C, _ in raw]), "r": np.array([r for _, r in raw]),
            "det_raw": np.array([np.linalg.det(C) for C, _ in raw])}


def hand_written_module():
    """The discrete trajectory module with its hand-written build, lift, cost and recover (the rest, which the
    port kept: generate, sample, random_state, local_solve, errors, TRANSPORTS, META, is the module's own)."""
    import types

    import problems.discrete_trajectory as dt

    mod = types.ModuleType("discrete_trajectory_hand_written")
    mod.__dict__.update({k: v for k, v in vars(dt).items() if not k.startswith("__")})
    mod.build = lambda inst: hand_written_model(inst, batched=len(inst.measurements["T_meas"]) >= 32)
    mod.lift, mod.cost, mod.recover = hand_written_lift, hand_written_cost, hand_written_recover
    return mod
