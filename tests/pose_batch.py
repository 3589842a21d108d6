"""The pose factors of ``problems._pose`` for many factors at once (``autotight.factor_batch``): the batched
build of the hand-written pose modules, kept as the reference the layer-written modules are compared with.

Each builder here writes one factor's matrices on the factor's own columns: h, then its blocks in the
order of ``BLOCKS_*`` (pose blocks c1, c2, c3, r of 3 columns each; ρ, φ of a residual).  Block names
carry placeholders that ``rename`` replaces per factor: ``POSE1``/``POSE2`` the pose prefixes, ``XI``
the residual's suffix and ``NAME`` the factor's name, so that each constraint is named exactly as the
per-factor builders of ``_pose`` name it.  Data: a measured pose as its 12 entries [C̃ r̃] row-major
(``pose_data``); a weight as its 36 entries.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from autotight.factor_batch import FactorBatch
from autotight.model import Variables

from problems._pose import (binary_cayley, declare_pose, declare_xi, pose_orthonormality, r1_unary, r2_unary, r3_binary,
                    unary_cayley, weighted_cost)

POSE1, POSE2, XI, NAME = "\x01", "\x02", "\x03", "\x04"


def pose_data(T: np.ndarray) -> np.ndarray:
    """(…, 4, 4) poses → (…, 12) entries [C̃ r̃] row-major."""
    T = np.asarray(T, float)
    return T[..., :3, :].reshape(*T.shape[:-2], 12)


def _pose(d: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :] = np.asarray(d, float).reshape(3, 4)
    return T


def _rotation_vars() -> Variables:
    return Variables(declare_pose(POSE1)[:3])


def _unary_vars() -> Variables:
    return Variables(declare_pose(POSE1) + declare_xi(XI))


def _binary_vars() -> Variables:
    return Variables(declare_pose(POSE1) + declare_pose(POSE2) + declare_xi(XI))


@lru_cache(maxsize=None)
def rotation_batch() -> FactorBatch:
    """The 6 orthonormality rows of a rotation (no data); columns h, c1, c2, c3."""
    V = _rotation_vars()
    return FactorBatch(lambda d: pose_orthonormality(V, POSE1), V.N, 0, 1)


@lru_cache(maxsize=None)
def unary_cayley_batch() -> FactorBatch:
    """The 12 Cayley rows of ξ = cay⁻¹(T T̃⁻¹) (affine in T̃); columns h, pose, ρ, φ."""
    V = _unary_vars()
    return FactorBatch(lambda d: unary_cayley(V, POSE1, _pose(d), XI, NAME), V.N, 12, 1)


@lru_cache(maxsize=None)
def binary_cayley_batch() -> FactorBatch:
    """The 12 Cayley rows of ξ = cay⁻¹(T₂ T₁⁻¹ T̃⁻¹) (affine in T̃); columns h, pose 1, pose 2, ρ, φ."""
    V = _binary_vars()
    return FactorBatch(lambda d: binary_cayley(V, POSE1, POSE2, _pose(d), XI, NAME), V.N, 12, 1)


@lru_cache(maxsize=None)
def unary_cost_batch() -> FactorBatch:
    """ξᵀ W ξ of a unary factor (linear in the 36 entries of W); columns as ``unary_cayley_batch``."""
    V = _unary_vars()
    return FactorBatch(lambda w: [weighted_cost(V, XI, np.reshape(w, (6, 6)))], V.N, 36, 1)


@lru_cache(maxsize=None)
def binary_cost_batch() -> FactorBatch:
    """ξᵀ W ξ of a binary factor; columns as ``binary_cayley_batch``."""
    V = _binary_vars()
    return FactorBatch(lambda w: [weighted_cost(V, XI, np.reshape(w, (6, 6)))], V.N, 36, 1)


@lru_cache(maxsize=None)
def r1_batch() -> FactorBatch:
    """The paper's R1 rows (quadratic in T̃); columns as ``unary_cayley_batch``."""
    V = _unary_vars()
    return FactorBatch(lambda d: r1_unary(V, POSE1, _pose(d), XI, NAME, factor=NAME), V.N, 12, 2)


@lru_cache(maxsize=None)
def r2_batch() -> FactorBatch:
    """The paper's R2 row; columns as ``unary_cayley_batch``."""
    V = _unary_vars()
    return FactorBatch(lambda d: r2_unary(V, POSE1, _pose(d), XI, NAME, factor=NAME), V.N, 12, 2)


@lru_cache(maxsize=None)
def r3_batch() -> FactorBatch:
    """The paper's R3 rows (quadratic in T̃); columns as ``binary_cayley_batch``."""
    V = _binary_vars()
    return FactorBatch(lambda d: r3_binary(V, POSE1, POSE2, _pose(d), XI, NAME, factor=NAME), V.N, 12, 2)


def renamer(subs: list[dict[str, str]]):
    """``rename(name, f)`` replacing each placeholder of factor f by subs[f][placeholder]."""
    def rename(name: str, f: int) -> str:
        for k, v in subs[f].items():
            name = name.replace(k, v)
        return name
    return rename
