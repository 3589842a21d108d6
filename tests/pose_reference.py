"""Pose averaging's model as it was written by hand before it moved onto the factor-graph layer: factor by factor
(``_pose``) or all measurement factors at once (``pose_batch``), for the tests that compare against it."""

from __future__ import annotations

import numpy as np

from autotight.model import Factor, Model, Variables
import pose_batch as pb
from problems._pose import (POSE_ROLES, XI_ROLES, declare_pose, declare_xi, pose_blocks, pose_orthonormality, r1_unary,
                            r2_unary, unary_cayley, weighted_cost, xi_blocks)


def _variables(M: int) -> Variables:
    return Variables(declare_pose() + [b for m in range(M) for b in declare_xi(str(m))])


def _cliques(M: int) -> list[tuple[str, ...]]:
    return [("h", *pose_blocks(), *xi_blocks(str(m))) for m in range(M)]


def hand_written_model(inst, batched: bool = False) -> Model:
    """Blocks [h, c1, c2, c3, r, ρ_0, φ_0, …]; factors "rotation" (so3) and "meas_m" (pose_meas: 12 Cayley rows,
    cost ξ_mᵀ W_m ξ_m, data [C̃ r̃]); paper families R1, R2; one clique per measurement."""
    T_meas, Ws = inst.measurements["T_meas"], inst.measurements["W"]
    M = len(T_meas)
    V = _variables(M)
    pose = pose_blocks()
    factors = [Factor("rotation", "so3", ("h", *pose[:3]), constraints=pose_orthonormality(V, factor="rotation"))]
    names = [f"meas_{m}" for m in range(M)]
    if batched:
        cols = np.array([V.index(("h", *pose, *xi_blocks(str(m)))) for m in range(M)])
        rename = pb.renamer([{pb.POSE1: "", pb.XI: str(m), pb.NAME: names[m]} for m in range(M)])
        D, W = pb.pose_data(T_meas), np.asarray(Ws, float).reshape(M, 36)
        cay = pb.unary_cayley_batch().constraints(D, cols, V.N, names, rename)
        costs = [c[0] for c in pb.unary_cost_batch().matrices(W, cols, V.N)]
        paper = {"R1": [c for cs in pb.r1_batch().constraints(D, cols, V.N, names, rename) for c in cs],
                 "R2": [c for cs in pb.r2_batch().constraints(D, cols, V.N, names, rename) for c in cs]}
    else:
        cay = [unary_cayley(V, "", T_meas[m], str(m), names[m]) for m in range(M)]
        costs = [weighted_cost(V, str(m), Ws[m]) for m in range(M)]
        paper = {"R1": [c for m in range(M) for c in r1_unary(V, "", T_meas[m], str(m), names[m], factor=names[m])],
                 "R2": [c for m in range(M) for c in r2_unary(V, "", T_meas[m], str(m), names[m], factor=names[m])]}
    factors += [Factor(names[m], "pose_meas", ("h", *pose, *xi_blocks(str(m))), cost=costs[m], constraints=cay[m],
                       roles=("h", *POSE_ROLES, *XI_ROLES), data=T_meas[m][:3, :]) for m in range(M)]
    return Model(V, factors, paper=paper, cliques=_cliques(M))
