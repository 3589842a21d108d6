"""Continuous-time trajectory estimation with a WNOA prior (Barfoot, Holmes, Dümbgen 2024, §5).

States {T_k, ϖ_k} at timestamps t_k (k = 0 … K−1 here; the paper counts from 1), Δt_k = t_{k+1} − t_k.
Pose measurements T̃_k = cay(ν_k^∧) T_k, ν_k ~ N(0, σ² I₆), at the measured k only (default: start,
middle, end).  Cost (paper (46)–(47)), with W_k = I/σ²:

    Σ_{measured k} ξ_kᵀ W_k ξ_k + (ϖ̌₀ − ϖ₀)ᵀ Q₁⁻¹ (ϖ̌₀ − ϖ₀) + Σ_{k<K−1} e_{k+1,k}ᵀ Q_{k+1,k}⁻¹ e_{k+1,k},
    e_{k+1,k} = [Δt_k ϖ_k − ξ_{k+1,k}; ϖ_k − ϖ_{k+1}],  Q_{k+1,k} = [[Δt³/3, Δt²/2], [Δt²/2, Δt]] ⊗ Q_c,
    ξ_k = cay⁻¹(T_k T̃_k⁻¹)^∨,  ξ_{k+1,k} = cay⁻¹(T_{k+1} T_k⁻¹)^∨.

Lifting x = [h, (c_{k,1}, c_{k,2}, c_{k,3}, r_k)_k, (ρ_k, φ_k)_{measured k}, (ρ_{k+1,k}, φ_{k+1,k})_{k<K−1}]
and, when ``marginalize`` is False (the default), also ϖ_k (6 each).  With ``marginalize`` (the paper's SDP)
ϖ is removed by the Schur complement: ``Model.cost`` = Q_xx − Q_xw Q_ww⁻¹ Q_wx, so ⟨Q, xxᵀ⟩ is the
cost minimised over ϖ (h stays in x: the ϖ₀ prior gives linear terms; the constant sits on h²), and
ϖ* = −Q_ww⁻¹ Q_wx x* is recovered after the solve.  Both SDPs have the same optimum (with Q_ww ≻ 0,
⟨Q_full, X⟩ minimised over the ϖ rows and columns of X ⪰ 0 is ⟨S, X_xx⟩), but only the ϖ-kept one
keeps the chain sparsity, so ``Model.cliques`` is the chain {h, pose k, pose k+1, ξ_{k+1,k}, ϖ_k,
ϖ_{k+1}} when ϖ is kept (and the model advises the SDP layer to decompose, ``Model.decompose``) and
None when marginalising.

Written on the factor-graph layer (``autotight.graph``), pose by pose (``derive(by_element=True)``); a state
is {"T": (K, 4, 4), "w": (K, 6)}, which ``layer_state`` gives the layer as its variables:

- variables: C_k ∈ SO(3) (blocks ``p{k}_c1, p{k}_c2, p{k}_c3``; its factor "so3" ``so3_k`` holds
  c_iᵀc_j = δ_ij h², named ``orth(p{k}_c1,p{k}_c2)``, …), r_k ∈ R³ (block ``p{k}_r``; no factor of its own) and,
  unless marginalised, the twists ϖ_k ∈ R⁶ (blocks ``w_k``, last in x; cost-only: in no model factor, so the
  model's cost is explicit, ``Variable.cost_only``);
- factor "pose_meas" ``meas_k`` per measured k (the family ``meas_family``) on (C_k, r_k), owning
  ξ_k = [ρ_k; φ_k] (blocks ``rho_k, phi_k``): residual ξ_k, weight W_k; constraints the 12 Cayley rows
  (I − ½ξ_k^∧) T_k = (I + ½ξ_k^∧) T̃_k (``meas_k:col1[0]`` … ``meas_k:r[2]``);
- the twist prior on ϖ₀ (``twist_prior``): residual ϖ̌₀ − ϖ₀, weight Q₁⁻¹, its lifted cost declared (no model
  factor: ϖ₀ is cost-only);
- factor "motion" ``motion_{k+1}_{k}`` per k < K−1 (``motion_family``) on (C_k, r_k, C_{k+1}, r_{k+1}) and,
  when kept, (ϖ_k, ϖ_{k+1}), owning ξ_{k+1,k} (blocks ``rho_{k+1}_{k}, phi_{k+1}_{k}``): residual e_{k+1,k},
  weight Q_{k+1,k}⁻¹ (the WNOA prior; marginalised, no residual: the Schur complement is the cost); constraints
  the 12 rows (I − ½ξ^∧) T_{k+1} = (I + ½ξ^∧) T_k (the discrete-time relation with C̃ = I, r̃ = 0); roles
  ``MOTION_ROLES``; its model factor lists the poses and ξ only;
- paper families (notes §4): R1, R2, R4, R5, R7 per measured k; R3, R6, R8 per k < K−1 (the families' ``paper``
  rows). R7 uses c_ℓ × c_m = c_n, so it holds on SO(3) only, not on O(3);
- the model factors carry no ``Factor.data`` (``record_data=False``), as the hand-written module's did: the sets
  discovered on it were learned without.  The families' data are [C̃ r̃ | c̃ᵢᵀr̃] and Δt_k (``meas_data``).

Hand-written, as in the module this one replaced, because the layer would not reproduce its results to the
bit: the marginalised cost (``marginal``: the Schur complement of the ϖ-kept cost assembled block by block,
``_full_cost``, which the optimal twists, ``random_state`` and the marginalised ``recover`` also use),
``cost`` (the local solver's stacked residual, also for a state without twists), the paper's sampler
(``sample``: T_k ← exp(ν_k^∧) T_k, ϖ_k ← ϖ_k + η_k) and local solver (``local_solve``: joint Gauss-Newton
with T_k ← cay(ε_k^∧) T_k, App. A.5), ``marginal_log_svr``, ``block_scale``, the cliques (``_cliques_chain``),
the presets and ``errors``; ``build`` puts the layer's model in the hand-written module's order (factors:
rotations, measurements, motions; R1 … R8) and sets its cliques, ``decompose`` advice and, marginalised, S.
The layer's matrices are the hand-written module's to the bit (cost, primary and paper constraints) with two
details: the prior's lifted cost is declared (``twist_prior``) and R1's constants c̃ᵢᵀr̃ are data
(``meas_data``), each computed as before.

Settings (``preset``): the paper states K = 21, measurements at the start, middle and end, W_k = I/σ²
and one trajectory geometry per noise level, but not Δt, Q_c, the trajectory or the prior on the
first twist.  ``preset=paper`` (the default): Δt = 0.1 s, Q_c = I, Q₁ = 0.1² I with ϖ̌₀ ~ N(ϖ₀, Q₁)
per seed, and one fixed smooth arc (constant body twist 1 m/s forward and 0.3 rad/s of yaw); a seed
changes only the measurement noise and ϖ̌₀.  ``preset=long_horizon``: Δt = 1 s and a random-walk twist
(TWIST_WANDER) with a random start rotation, a new geometry per seed.  A preset fills dt, geometry,
qc, prior_sigma and motion; any of them given explicitly wins.

Log SVR is reported as the paper does, on the marginalised X, whichever formulation was solved:
``marginal_log_svr(instance, X, cliques)`` (``marginal_X``: the x-block of the ϖ-kept X; a
clique-decomposed X is first completed from its clique blocks by the maximum-determinant completion,
``complete_psd``).

Why these choices, with the measurements behind them: ``docs/continuous_trajectory_notes.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from autotight import lie
from autotight.affine import Affine, const, quad, var
from autotight.errors import ParameterError, ProblemDefinitionError, SolverError
from autotight.gauss_newton import gauss_newton
from autotight.graph import Auxiliary, Euclidean, Factor, Family, Rotation, Variable, View, derive
from autotight.model import Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Meta, Param
from autotight.sdp.result import log_svr

from ._pose import (  # noqa: F401  (pose_values, xi_values, xi_blocks: the block helpers callers use with it)
    POSE_ROLES,
    XI_ROLES,
    declare_pose,
    declare_xi,
    pose_blocks,
    pose_values,
    trans_block,
    xi_blocks,
    xi_values,
)
from ._pose_rows import cayley_rows, dot, r2, unary_cayley

GEOMETRIES = ("arc", "random_walk")

NAME = "continuous_trajectory"
DESCRIPTION = "Continuous-time (WNOA prior) SE(3) trajectory from sparse pose measurements (paper §5)."
#: the paper's claim for R1–R8 (Fig. 11, 100 trials per σ on one geometry, and §5's text; the figure's values
#: are not stated in the text), shown beside our verdicts in the report's "Against the paper" table
META = Meta(
    paper_claim={
        "source": "Fig. 11 and §5: 'log SVR values mostly above 5 up to about σ = 1'",
        "set": "paper",
        "by_sigma": {0.001: "log SVR above 5, 'noticeably lower than neighbouring noise levels' (they marginalise ϖ)",
                     1.0: "log SVR 'mostly above 5'"},
        "default": "log SVR above 5 (rank 1)",
    },
    #: a hint (``autotight.discovery.engine``): a learned set should carry to longer trajectories, so ``discover``
    #: also validates it on held-out trajectories of 41 states (every failing one becomes a training instance),
    #: with our IPM unless --solver is given.  A set selected at K = 21 alone can miss a pair that rare K = 21
    #: instances and more K = 41 ones need (docs/continuous_trajectory_notes.md, "Discovery's carry hint").
    carry_to={"params": {"K": 41}, "solver": "ipm"},
)


@dataclass(frozen=True)
class PresetParam(Param):
    """A parameter whose default comes from the chosen ``preset`` (default None = "from the preset"; given as
    text, "None" is that too, as a record prints it).  ``kind`` is its type; bounds and choices are checked as for
    ``Param`` when a value is given."""

    kind: type = float

    def parse(self, name: str, value: Any) -> Any:
        if value is None or (isinstance(value, str) and value.strip() == "None"):
            return None
        return Param(self.kind(), self.help, self.low, self.high, self.low_open, self.choices).parse(name, value)


#: named settings: each fills the preset parameters (PresetParam) that the caller did not give
PRESETS: dict[str, dict[str, Any]] = {
    # the paper's Fig. 11: K = 21 states over a 2 s horizon, one fixed smooth arc (see the module docstring)
    "paper": {"dt": 0.1, "geometry": "arc", "qc": 1.0, "prior_sigma": 0.1, "motion": 1.0},
    # a 20 s horizon (about 6 rad of yaw over K = 21) and a new random-walk twist per seed
    "long_horizon": {"dt": 1.0, "geometry": "random_walk", "qc": 1.0, "prior_sigma": 0.1, "motion": 1.0},
}

PARAMS = {
    "preset": Param("paper", "named setting that fills dt, geometry, qc, prior_sigma and motion unless given",
                    choices=tuple(PRESETS)),
    "K": Param(21, "number of states {T_k, ϖ_k}", low=2),
    "sigma": Param(0.1, "pose measurement noise std per ξ component (W_k = I/σ²)", low=0.0, low_open=True),
    "dt": PresetParam(None, "time step Δt between states (used when `times` is empty; preset paper: 0.1)",
                      low=0.0, low_open=True),
    "geometry": PresetParam(None, "true trajectory: 'arc' (constant twist, fixed start: the same for every seed) "
                            "or 'random_walk' (random start rotation, twist wanders; preset paper: arc)",
                            choices=GEOMETRIES, kind=str),
    "qc": PresetParam(None, "power spectral density scale: Q_c = qc · diag(qc_diag) (preset paper: 1)",
                      low=0.0, low_open=True),
    "qc_diag": Param((), "6 diagonal entries of Q_c/qc (empty: all ones)"),
    "prior_sigma": PresetParam(None, "std of the prior on the first twist ϖ₀ (Q₁ = prior_sigma² I; preset paper: 0.1)",
                               low=0.0, low_open=True),
    "motion": PresetParam(None, "twist scale: the true body twist is motion·BASE_TWIST (preset paper: 1)", low=0.0),
    "measured": Param((), "indices of the measured states, 0-based (empty: start, middle, end)"),
    "times": Param((), "K increasing timestamps (empty: t_k = k·dt)"),
    "marginalize": Param(False, "remove ϖ from the lifting by the Schur complement (the paper's SDP); default: "
                                "keep it (the same optimum; 10× faster on our clique cover)"),
}

#: the true body twist [ρ̇; φ̇] per unit of `motion`: 1 m/s forward, 0.3 rad/s about the body z axis
BASE_TWIST = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.3])
#: random_walk geometry: the true twist wanders with this std per component and √s, per unit of `motion`
TWIST_WANDER = 0.05
#: arc geometry: the fixed start rotation (world-to-body), the same for every seed
ARC_START_ROTVEC = np.array([0.3, -0.2, 0.5])


def resolve(params: dict) -> dict:
    """params with every preset parameter that is None replaced by the preset's value."""
    preset = PRESETS[params.get("preset", "paper")]
    return {k: (preset[k] if v is None and k in preset else v) for k, v in params.items()} | \
        {k: v for k, v in preset.items() if k not in params}

#: roles of a motion factor: pose k, pose k+1 (primed), ξ_{k+1,k} (as discrete_trajectory's odometry factor)
MOTION_ROLES = ("h", *POSE_ROLES, *(f"{r}'" for r in POSE_ROLES), *XI_ROLES)


# ----------------------------------------------------------------------------- parameters and data


def _indices(params: dict, K: int) -> np.ndarray:
    raw = params.get("measured", ())
    if len(raw) == 0:
        return np.array(sorted({0, K // 2, K - 1}))
    idx = np.asarray(raw, dtype=float)
    if np.any(idx != np.round(idx)):
        raise ParameterError(f"measured indices must be integers, got {list(raw)}")
    idx = idx.astype(int)
    bad = idx[(idx < 0) | (idx >= K)]
    if bad.size:
        raise ParameterError(f"measured index {int(bad[0])} is outside the trajectory (0 … {K - 1})")
    if len(set(idx.tolist())) != idx.size:
        raise ParameterError(f"measured indices repeat: {idx.tolist()}")
    return np.sort(idx)


def _times(params: dict, K: int) -> np.ndarray:
    raw = params.get("times", ())
    if len(raw) == 0:
        return params["dt"] * np.arange(K, dtype=float)
    t = np.asarray(raw, dtype=float)
    if t.shape != (K,):
        raise ParameterError(f"times must list K = {K} timestamps, got {t.size}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ParameterError(f"timestamps must increase strictly, got {t.tolist()}")
    return t


def _qc(params: dict) -> np.ndarray:
    diag = np.ones(6) if len(params.get("qc_diag", ())) == 0 else np.asarray(params["qc_diag"], dtype=float)
    if diag.shape != (6,):
        raise ParameterError(f"qc_diag needs 6 entries, got {diag.size}")
    Qc = params["qc"] * np.diag(diag)
    _check_pd(Qc, "Q_c")
    return Qc


def _check_pd(M: np.ndarray, name: str) -> None:
    M = np.asarray(M, dtype=float)
    if M.shape != (6, 6) or not np.all(np.isfinite(M)) or not np.allclose(M, M.T):
        raise ParameterError(f"{name} must be a finite symmetric 6×6 matrix")
    if np.linalg.eigvalsh(M)[0] <= 0:
        raise ParameterError(f"{name} is not positive definite (smallest eigenvalue {np.linalg.eigvalsh(M)[0]:.3g})")


def generate(params: dict, rng: np.random.Generator) -> Instance:
    """Truth: T_{k+1} = cay((Δt_k ϖ_k)^∧) T_k with (``geometry``) "arc": ϖ_k = motion·BASE_TWIST and
    C₀ = exp(ARC_START_ROTVEC^∧), the same for every seed, or "random_walk": C₀ random and
    ϖ_k = motion·(BASE_TWIST + random walk); T_k is world-to-body, the world origin at the centroid of
    the positions.  Per seed: T̃_k = cay(ν_k^∧) T_k and the prior mean ϖ̌₀ ~ N(ϖ₀, Q₁)."""
    params = resolve(params)
    K = int(params["K"])
    if K < 2:
        raise ParameterError(f"K must be ≥ 2, got {K}")
    t, idx, Qc = _times(params, K), _indices(params, K), _qc(params)
    s, sig = float(params["motion"]), float(params["sigma"])
    dts = np.diff(t)
    w = np.empty((K, 6))
    if params["geometry"] == "arc":
        w[:] = s * BASE_TWIST
        C0 = lie.exp_so3(ARC_START_ROTVEC)
    else:
        w[0] = s * (BASE_TWIST + TWIST_WANDER * rng.standard_normal(6))
        for k in range(K - 1):
            w[k + 1] = w[k] + s * TWIST_WANDER * np.sqrt(dts[k]) * rng.standard_normal(6)
        C0 = lie.random_rotation(rng)
    T = np.empty((K, 4, 4))
    T[0] = lie.make_pose(C0, np.zeros(3))
    for k in range(K - 1):
        T[k + 1] = lie.cay_se3(dts[k] * w[k]) @ T[k]
    # world origin at the centroid of the vehicle positions p_k = −C_kᵀ r_k: T_k ← T_k T_w.  The
    # relaxation is invariant to the world frame; the SDP's conditioning is not (|r_k| enters X).
    centroid = np.mean([-Tk[:3, :3].T @ Tk[:3, 3] for Tk in T], axis=0)
    T = T @ lie.make_pose(np.eye(3), centroid)
    T_meas = np.array([lie.cay_se3(sig * rng.standard_normal(6)) @ T[k] for k in idx])
    Q1 = params["prior_sigma"] ** 2 * np.eye(6)
    w_prior = rng.multivariate_normal(w[0], Q1)
    meas = {"times": t, "measured": idx, "T_meas": T_meas, "W": np.repeat(np.eye(6)[None] / sig**2, idx.size, 0),
            "Qc": Qc, "Q1": Q1, "w_prior": w_prior}
    return Instance(NAME, params, meas, {"T": T, "w": w})


@dataclass(frozen=True)
class _Data:
    """Validated measurements of an instance."""

    K: int
    times: np.ndarray
    measured: np.ndarray
    T_meas: np.ndarray
    W: np.ndarray
    Qc: np.ndarray
    Q1: np.ndarray
    w_prior: np.ndarray
    marginalize: bool


def _data(inst: Instance) -> _Data:
    m = inst.measurements
    t = np.asarray(m["times"], dtype=float)
    K = t.size
    if K < 2:
        raise ParameterError(f"K must be ≥ 2, got {K}")
    if np.any(np.diff(t) <= 0):
        raise ParameterError(f"timestamps must increase strictly, got {t.tolist()}")
    idx = np.asarray(m["measured"], dtype=int).reshape(-1)
    if np.any((idx < 0) | (idx >= K)):
        raise ParameterError(f"a measured index in {idx.tolist()} is outside the trajectory (0 … {K - 1})")
    _check_pd(m["Qc"], "Q_c")
    _check_pd(m["Q1"], "Q₁")
    T_meas, W = np.asarray(m["T_meas"], dtype=float), np.asarray(m["W"], dtype=float)
    if T_meas.shape != (idx.size, 4, 4) or W.shape != (idx.size, 6, 6):
        raise ProblemDefinitionError(f"need one T_meas (4×4) and W (6×6) per measured index ({idx.size})")
    return _Data(K, t, idx, T_meas, W, np.asarray(m["Qc"], float), np.asarray(m["Q1"], float),
                 np.asarray(m["w_prior"], float), bool(inst.params.get("marginalize", False)))


# ----------------------------------------------------------------------------- the factor graph: variables


def pose_prefix(k: int) -> str:
    return f"p{k}_"


def meas_xi(k: int) -> str:
    """Suffix of the measurement residual ξ_k (blocks rho_{k}, phi_{k})."""
    return str(k)


def motion_xi(k: int) -> str:
    """Suffix of the motion residual ξ_{k+1,k} (blocks rho_{k+1}_{k}, phi_{k+1}_{k})."""
    return f"{k + 1}_{k}"


def twist_block(k: int) -> str:
    return f"w_{k}"


def _orthonormality_name(equation: str, index: int, **_: Any) -> str:
    """``orth(p{k}_c{i},p{k}_c{j})`` by block name for the equation ``orth(i−1,j−1)`` of ``Rotation.constraints``
    (``Variable.constraint_names``)."""
    i, j = (int(a) + 1 for a in equation[len("orth("):-1].split(","))
    return f"orth({pose_prefix(index)}c{i},{pose_prefix(index)}c{j})"


def variables(inst: Instance) -> list[Variable]:
    """C_k (blocks p{k}_c1, p{k}_c2, p{k}_c3), r_k (p{k}_r) and, unless marginalised, the cost-only ϖ_k (w_k)."""
    out = [Variable("C", Rotation(3), type="so3", block=("c1", "c2", "c3"), element="p{i}_{block}",
                    constraint_names=_orthonormality_name),
           Variable("r", Euclidean(3), element="p{i}_{block}")]
    if not _data(inst).marginalize:
        out.append(Variable("w", Euclidean(6), element="{block}_{i}", cost_only=True))
    return out


def layer_state(state: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """A state {"T": (K, 4, 4)[, "w": (K, 6)]} as the layer's variables {"C", "r"[, "w"]}."""
    T = np.asarray(state["T"], dtype=float)
    out = {"C": T[:, :3, :3], "r": T[:, :3, 3]}
    return out | ({"w": np.asarray(state["w"], dtype=float)} if "w" in state else {})


def _poses(C: np.ndarray, r: np.ndarray) -> list[np.ndarray]:
    return [lie.make_pose(Ck, rk) for Ck, rk in zip(C, r)]


def _xi(xi: View) -> np.ndarray:
    return np.hstack([xi.rho, xi.phi])


#: names of the 12 Cayley rows of a pose residual: the rotation's columns, then the translation
CAYLEY_ROWS = tuple(f"col{i + 1}[{k}]" for i in range(3) for k in range(3)) + tuple(f"r[{k}]" for k in range(3))


# ----------------------------------------------------------------------------- the pose measurements


def meas_data(d: _Data) -> np.ndarray:
    """Each measurement's data (M, 15): [C̃ r̃] (row-major 3×4), then R1's constants c̃ᵢᵀr̃ (i = 1, 2, 3) summed as
    the hand-written module summed them (``autotight.affine.quad``; the family's fit of the product would add
    its three terms in another order, to the last bit).  Every row is then affine in the data (``degree=1``)."""
    V = Variables([])
    dots = [[quad(V, const(Tm[:3, i]), const(Tm[:3, 3]), np.eye(3)).matrix().toarray()[0, 0] for i in range(3)]
            for Tm in d.T_meas]
    return np.hstack([d.T_meas[:, :3, :].reshape(-1, 12), np.array(dots).reshape(-1, 3)])


def _measured(D: np.ndarray) -> np.ndarray:
    """The measured poses [C̃ r̃] (R, 3, 4) of the data (R, 15) (``meas_data``)."""
    return D[:, :12].reshape(-1, 3, 4)


def _on_measured(fn: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """fn(*views, Tm (R, 3, 4)) on the data (R, 15) of ``meas_data``."""
    return lambda *views: fn(*views[:-1], _measured(views[-1]))


def meas_residual(C: View, r: View, Tm: np.ndarray) -> np.ndarray:
    """ξ_k = cay⁻¹(T_k T̃_k⁻¹)^∨ (R, 6), pose by pose as ``residuals`` (CayleySingularityError at angle π)."""
    meas = _poses(Tm[:, :, :3], Tm[:, :, 3])
    return np.array([lie.cay_inv_se3(T @ lie.inv_se3(M)) for T, M in zip(_poses(C.x, r.x), meas)]).reshape(-1, 6)


def r1(C: View, r: View, xi: View, D: np.ndarray) -> np.ndarray:
    """(R1, paper (35)) ½ (c_i + c̃_i)ᵀ ρ − c_iᵀ r + c̃_iᵀ r̃ = 0, i = 1, 2, 3, on the data [C̃ r̃ | c̃ᵢᵀr̃]
    (``meas_data``)."""
    return 0.5 * dot(C.x + _measured(D)[:, :, :3], xi.rho) - dot(C.x, r.x) + D[:, 12:]


def r4(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """(R4, paper (52)) φᵀ c_i = φᵀ c̃_i, i = 1, 2, 3."""
    return dot(C.x - Tm[:, :, :3], xi.phi)


def r5(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """(R5, paper (53)) φᵀ r = φᵀ r̃ + φᵀ ρ."""
    return dot(r.x - Tm[:, :, 3] - xi.rho, xi.phi)[:, None]


#: R7's rows ℓmn
R7_ROWS = ((0, 1, 2), (1, 2, 0), (2, 0, 1))


def r7(C: View, r: View, xi: View, Tm: np.ndarray) -> np.ndarray:
    """(R7, paper (55); SO(3) only) −½ φᵀ c_n = c_mᵀ c̃_ℓ − ½ c_mᵀ c̃_ℓ^∧ φ for ℓmn ∈ {123, 231, 312}."""
    c, cm = C.x, Tm[:, :, :3]
    return np.stack([0.5 * dot(c[:, :, n], xi.phi) + dot(c[:, :, m], cm[:, :, l])
                     - 0.5 * dot(c[:, :, m], np.cross(cm[:, :, l], xi.phi)) for l, m, n in R7_ROWS], axis=1)


def meas_family(d: _Data) -> Family:
    """The pose measurements ``meas_k`` on (C_k, r_k), owning ξ_k (``meas_residual``, the 12 Cayley rows
    ``unary_cayley``): residual ξ_k, weight W_k; R1, R2, R4, R5, R7."""
    ks = [int(k) for k in d.measured]
    xi = Auxiliary({"rho": 3, "phi": 3}, value=_on_measured(meas_residual), equations=_on_measured(unary_cayley),
                   names=CAYLEY_ROWS)
    paper = {"R1": r1, "R2": _on_measured(r2), "R4": _on_measured(r4), "R5": _on_measured(r5),
             "R7": _on_measured(r7)}
    return Family([(f"C{k}", f"r{k}") for k in ks], lambda C, r, xi, D: _xi(xi), data=meas_data(d),
                  type="pose_meas", weight=d.W, auxiliary=xi, paper=paper,
                  paper_labels={"R7": tuple(f"{l + 1}{m + 1}{n + 1}" for l, m, n in R7_ROWS)},
                  names=[f"meas_{k}" for k in ks], aux_names=[meas_xi(k) for k in ks], degree=1, record_data=False)


# ----------------------------------------------------------------------------- the prior on ϖ₀


def twist_prior(d: _Data) -> Factor:
    """The prior on ϖ₀: residual ϖ̌₀ − ϖ₀, weight Q₁⁻¹, and its lifted cost on [h, ϖ₀] declared, uᵀ Q₁⁻¹ u for the
    affine u = ϖ̌₀ h − ϖ₀ (``autotight.affine.quad``): read off the residual, its unit coefficients would be
    (ϖ̌₀ − 1) − ϖ̌₀, not −1, to the last bit."""
    L = np.linalg.inv(d.Q1)
    u = const(d.w_prior) - var("w", np.eye(6))
    C = quad(Variables([("w", 6)]), u, u, L).matrix().toarray()
    return Factor("w0", lambda w: d.w_prior - w.x, weight=L, cost=C, type="twist_prior", name="twist_prior")


# ----------------------------------------------------------------------------- the motions (WNOA prior)


def motion_residual(C1: View, r1: View, C2: View, r2: View, *rest: Any) -> np.ndarray:
    """ξ_{k+1,k} = cay⁻¹(T_{k+1} T_k⁻¹)^∨ (R, 6), pose by pose as ``residuals`` (``rest``: ϖ_k, ϖ_{k+1} when kept,
    then the data)."""
    return np.array([lie.cay_inv_se3(T2 @ lie.inv_se3(T1))
                     for T1, T2 in zip(_poses(C1.x, r1.x), _poses(C2.x, r2.x))]).reshape(-1, 6)


def motion_cayley(C1: View, r1: View, C2: View, r2: View, xi: View) -> np.ndarray:
    """ξ_{k+1,k} = cay⁻¹(T_{k+1} T_k⁻¹): (I − ½ξ^∧) T_{k+1} = (I + ½ξ^∧) T_k (12 rows)."""
    return cayley_rows(C2.x, r2.x, C1.x, r1.x, xi)


def wnoa_inverse_covariance(dt: float, Qc: np.ndarray) -> np.ndarray:
    """Q_{k+1,k}⁻¹ = [[12/Δt³, −6/Δt²], [−6/Δt², 4/Δt]] ⊗ Q_c⁻¹ (12×12)."""
    return np.kron(np.array([[12 / dt**3, -6 / dt**2], [-6 / dt**2, 4 / dt]]), np.linalg.inv(Qc))


def wnoa_error(C1: View, r1: View, C2: View, r2: View, w1: View, w2: View, xi: View, dt: np.ndarray) -> np.ndarray:
    """e_{k+1,k} = [Δt_k ϖ_k − ξ_{k+1,k}; ϖ_k − ϖ_{k+1}] (R, 12), dt (R, 1)."""
    return np.hstack([dt * w1.x - _xi(xi), w1.x - w2.x])


def r3(C1: View, r1: View, C2: View, r2: View, xi: View) -> np.ndarray:
    """(R3, paper (44), C̃ = I, r̃ = 0) ½ (c₂,ᵢ + c₁,ᵢ)ᵀ ρ − c₂,ᵢᵀ r₂ + c₁,ᵢᵀ r₁ = 0, i = 1, 2, 3."""
    return 0.5 * dot(C2.x + C1.x, xi.rho) - dot(C2.x, r2.x) + dot(C1.x, r1.x)


def r6(C1: View, r1: View, C2: View, r2: View, xi: View) -> np.ndarray:
    """(R6, paper (54)) φᵀ c₂,ᵢ = φᵀ c₁,ᵢ (i = 1, 2, 3) and φᵀ r₂ = φᵀ r₁ + φᵀ ρ."""
    return np.hstack([dot(C2.x - C1.x, xi.phi), dot(r2.x - r1.x - xi.rho, xi.phi)[:, None]])


def r8(C1: View, r1: View, C2: View, r2: View, xi: View) -> np.ndarray:
    """(R8, paper (56)) r₂ᵀ r₂ = (r₂ + r₁)ᵀ ρ + r₁ᵀ r₁."""
    return (dot(r2.x, r2.x) - dot(r2.x + r1.x, xi.rho) - dot(r1.x, r1.x))[:, None]


def _motion_rows(fn: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """A row function of (pose k, pose k+1, ξ) in the motion family's signature (C_k, r_k, C_{k+1}, r_{k+1}[, ϖ_k,
    ϖ_{k+1}], ξ, Δt)."""
    return lambda C1, r1, C2, r2, *rest: fn(C1, r1, C2, r2, rest[-2])


def motion_family(d: _Data) -> Family:
    """The motions ``motion_{k+1}_{k}`` on (T_k, T_{k+1}) and, kept, (ϖ_k, ϖ_{k+1}), owning ξ_{k+1,k}
    (``motion_residual``, ``motion_cayley``): residual e_{k+1,k} (``wnoa_error``), weight Q_{k+1,k}⁻¹
    (marginalised: no residual); R3, R6, R8.  Data Δt_k."""
    K, dts = d.K, np.diff(d.times)
    poses = [(f"C{k}", f"r{k}", f"C{k + 1}", f"r{k + 1}") for k in range(K - 1)]
    kept = not d.marginalize
    xi = Auxiliary({"rho": 3, "phi": 3}, value=motion_residual, equations=_motion_rows(motion_cayley),
                   names=CAYLEY_ROWS)
    return Family([p + (f"w{k}", f"w{k + 1}") for k, p in enumerate(poses)] if kept else poses,
                  wnoa_error if kept else None, data=dts[:, None], type="motion",
                  weight=np.array([wnoa_inverse_covariance(dt, d.Qc) for dt in dts]) if kept else None,
                  auxiliary=xi, paper={"R3": _motion_rows(r3), "R6": _motion_rows(r6), "R8": _motion_rows(r8)},
                  paper_labels={"R6": ("1", "2", "3", "r")}, names=[f"motion_{motion_xi(k)}" for k in range(K - 1)],
                  aux_names=[motion_xi(k) for k in range(K - 1)], roles=MOTION_ROLES, degree=1, record_data=False)


# ----------------------------------------------------------------------------- the model


def factors(inst: Instance) -> Iterator[Factor | Family]:
    """The pose measurements, the prior on ϖ₀ (kept only) and the motions, in the order of the cost (46)."""
    d = _data(inst)
    yield meas_family(d)
    if not d.marginalize:
        yield twist_prior(d)
    yield motion_family(d)


#: the layer's model, lift and recover (the module keeps the paper's cost, sampler and local solver)
_build, _lift, _, _, _, _recover = derive(variables, factors, by_element=True, state=layer_state)


def _cliques_chain(d: _Data) -> list[tuple[str, ...]]:
    """ϖ kept: per k < K−1 {h, pose k, pose k+1, ξ_{k+1,k}, ϖ_k, ϖ_{k+1}}, per measured k {h, pose k, ξ_k}."""
    out = [("h", *pose_blocks(pose_prefix(k)), *pose_blocks(pose_prefix(k + 1)), *xi_blocks(motion_xi(k)),
            twist_block(k), twist_block(k + 1)) for k in range(d.K - 1)]
    return out + [("h", *pose_blocks(pose_prefix(int(k))), *xi_blocks(meas_xi(int(k)))) for k in d.measured]


def _marginalized_cover(d: _Data) -> list[tuple[str, ...]]:
    """ϖ marginalised: the Schur complement couples h and all motion ξ, so one bag must hold them all.

    A tree decomposition (path B_0 – … – B_{K−2}) with the full bag in the middle, j = (K−2)//2:
    B_i = {h, pose i, pose i+1} ∪ {ξ_{l+1,l} : i lies between l and j}, so B_i holds ξ_{l+1,l} for
    l ≤ i (i < j), for l ≥ i (i > j) and for every l (i = j).  Pose i+1 lies in B_i and B_{i+1} only
    and each ξ_{l+1,l} in the contiguous run from B_l to B_j: the running intersection property
    holds.  Per measured k a leaf {h, pose k, ξ_k}.  Largest bag: 1 + 24 + 6(K−1).
    """
    j = (d.K - 2) // 2
    out = []
    for i in range(d.K - 1):
        ls = range(d.K - 1) if i == j else range(0, i + 1) if i < j else range(i, d.K - 1)
        out.append(("h", *pose_blocks(pose_prefix(i)), *pose_blocks(pose_prefix(i + 1)),
                    *(b for l in ls for b in xi_blocks(motion_xi(l)))))
    return out + [("h", *pose_blocks(pose_prefix(int(k))), *xi_blocks(meas_xi(int(k)))) for k in d.measured]


def marginalized_cliques(inst: Instance) -> list[tuple[str, ...]]:
    """A block-level clique tree covering the marginalised model (not used by default; see above)."""
    return _marginalized_cover(_data(inst))


def build(inst: Instance) -> Model:
    """The layer's model (``factors``) in the hand-written module's order, factors by kind (the rotations
    ``so3_k``, the measurements, the motions; the layer writes each rotation before the first factor on its
    pose) and R1 … R8, with the module's cliques and advice: ϖ kept, the chain (``_cliques_chain``) and
    ``decompose`` (Clarabel on our cover is 4× faster than its own chordal decomposition at K = 21);
    marginalised, the cost S (``marginal``) and no cliques."""
    d = _data(inst)
    model = _build(inst)
    kinds = {"so3": 0, "pose_meas": 1, "motion": 2}
    order = {f"so3_{k}": k for k in range(d.K)}
    model.factors = sorted(model.factors, key=lambda f: (kinds[f.type], order.get(f.name, 0)))
    model.paper = {f"R{i}": model.paper[f"R{i}"] for i in range(1, 9)}
    if d.marginalize:
        model.cost, model.cliques, model.decompose = marginal(inst).S, None, None
    else:
        model.cliques, model.decompose = _cliques_chain(d), True
    return model


# ----------------------------------------------------------------------------- the marginalised cost (hand-written)


def _variables(d: _Data, with_twists: bool) -> Variables:
    """The lifting's blocks (the layer's, ``variables``), for the Schur complement's bookkeeping: x, and with
    ``with_twists`` [x; ϖ]."""
    blocks = [b for k in range(d.K) for b in declare_pose(pose_prefix(k))]
    blocks += [b for k in d.measured for b in declare_xi(meas_xi(int(k)))]
    blocks += [b for k in range(d.K - 1) for b in declare_xi(motion_xi(k))]
    if with_twists:
        blocks += [(twist_block(k), 6) for k in range(d.K)]
    return Variables(blocks)


def _full_cost(d: _Data, V: Variables) -> sp.csr_array:
    """The whole cost as a quadratic form in [x; ϖ] (V must hold the twist blocks)."""
    qf = QuadForm(V)
    for j, k in enumerate(d.measured):
        rho, phi = xi_blocks(meas_xi(int(k)))
        Wk = d.W[j]
        qf.add(rho, rho, Wk[:3, :3]).add(rho, phi, 2 * Wk[:3, 3:]).add(phi, phi, Wk[3:, 3:])
    u = const(d.w_prior) - var(twist_block(0), np.eye(6))
    sel_rho, sel_phi = np.zeros((12, 3)), np.zeros((12, 3))
    sel_rho[:3], sel_phi[3:6] = -np.eye(3), -np.eye(3)
    parts = [(u, u, np.linalg.inv(d.Q1))]
    for k, dt in enumerate(np.diff(d.times)):
        rho, phi = xi_blocks(motion_xi(k))
        e = Affine({twist_block(k): np.vstack([dt * np.eye(6), np.eye(6)]),
                    twist_block(k + 1): np.vstack([np.zeros((6, 6)), -np.eye(6)]), rho: sel_rho, phi: sel_phi})
        parts.append((e, e, wnoa_inverse_covariance(dt, d.Qc)))
    for a, b, L in parts:
        quad(V, a, b, L, into=qf)
    return qf.matrix()


@dataclass(frozen=True)
class Marginal:
    """The cost [x; ϖ]ᵀ Q_full [x; ϖ] split at ϖ: Q_xw (N×6K), the LU factor of Q_ww (6K×6K), and the
    Schur complement S = Q_xx − Q_xw Q_ww⁻¹ Q_wx (N×N, sparse; dense on h and the motion ξ blocks).
    Vx lifts x, Vfull lifts [x; ϖ] (ϖ blocks last)."""

    Vx: Variables
    Vfull: Variables
    Q_full: sp.csr_array
    Q_xw: sp.csr_array
    lu: spla.SuperLU
    S: sp.csr_array

    def twists(self, x: np.ndarray) -> np.ndarray:
        """ϖ* = −Q_ww⁻¹ Q_wx x for a lifted x (h = 1), as (K, 6)."""
        return -self.lu.solve(self.Q_xw.T @ x).reshape(-1, 6)


def marginal(inst: Instance) -> Marginal:
    """The Schur complement of the ϖ blocks in the full cost."""
    d = _data(inst)
    Vf, Vx = _variables(d, True), _variables(d, False)
    Q = _full_cost(d, Vf)
    ix = Vf.index(Vx.names)
    iw = Vf.index([twist_block(k) for k in range(d.K)])
    Qxx, Qxw, Qww = Q[ix][:, ix], Q[ix][:, iw], Q[iw][:, iw]
    lu = spla.splu(sp.csc_matrix(Qww))
    cols = np.unique(Qxw.tocoo().row)  # h and the motion ξ blocks
    Z = lu.solve(Qxw[cols].T.toarray())  # Q_ww⁻¹ Q_wx restricted to the coupled columns
    dense = Qxw[cols].toarray() @ Z
    r, c = np.meshgrid(cols, cols, indexing="ij")
    corr = sp.coo_array((dense.ravel(), (r.ravel(), c.ravel())), shape=Qxx.shape)
    S = sp.csr_array(Qxx - corr)
    S = sp.csr_array((S + S.T) / 2)
    return Marginal(Vx, Vf, Q, sp.csr_array(Qxw), lu, S)


def block_scale(inst: Instance) -> np.ndarray:
    """A diagonal congruence X = D X′ D for the SDP (sdp.solve(…, scale=D)), D per column from the
    typical magnitude of its block, read off the measurements and the noise parameters only: h, c: 1;
    r_k: the RMS measured translation entry; ξ_k: σ (its noise); ξ_{k+1,k}: Δt_k × the RMS prior
    twist entry (ρ and φ apart), at least the process-noise std √(Δt³/3 · q_c); ϖ_k: the RMS prior
    twist entry, at least the prior std.  Without it the ξ_k blocks are σ² smaller than the rest and
    the solver resolves them poorly at small σ."""
    d = _data(inst)
    V = _variables(d, not d.marginalize)
    D = np.ones(V.N)
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    q = float(np.mean(np.diag(d.Qc)))
    r_typ = max(rms(d.T_meas[:, :3, 3]), 1e-3)
    sig = float(np.sqrt(np.mean([1.0 / np.mean(np.diag(W)) for W in d.W])))
    w_lin, w_ang = rms(d.w_prior[:3]), rms(d.w_prior[3:])
    w_floor = float(np.sqrt(np.mean(np.diag(d.Q1))))
    for k in range(d.K):
        D[V.slice(trans_block(pose_prefix(k)))] = r_typ
    for k in d.measured:
        for b in xi_blocks(meas_xi(int(k))):
            D[V.slice(b)] = sig
    for k, dt in enumerate(np.diff(d.times)):
        floor = np.sqrt(dt**3 / 3 * q)
        rho, phi = xi_blocks(motion_xi(k))
        D[V.slice(rho)], D[V.slice(phi)] = max(dt * w_lin, floor), max(dt * w_ang, floor)
    if not d.marginalize:
        for k in range(d.K):
            D[V.slice(twist_block(k))] = max(rms(d.w_prior), w_floor)
    return D


def complete_psd(X: np.ndarray, cliques: Sequence[np.ndarray], rtol: float = 1e-12) -> np.ndarray:
    """The maximum-determinant PSD completion of X known on the union of the ``cliques``' blocks (a
    chordal pattern: the cover of a decomposed solve is a clique tree); entries off it are ignored.

    Vertices are taken in maximum-cardinality-search order; each new vertex v with earlier neighbours
    S (a clique, the pattern being chordal) and other earlier vertices R gets X[v, R] =
    X[v, S] X[S, S]⁺ X[S, R]: the conditional-independence (Gaussian) completion, which is PSD when
    every clique block is, and has rank 1 when every clique block has rank 1.  It is computed on the
    correlation matrix X_ij / √(X_ii X_jj), so the pseudo-inverse's cut-off (eigenvalues below rtol ×
    the largest) does not depend on the scale of the blocks.
    """
    X = (np.asarray(X, dtype=float) + np.asarray(X, dtype=float).T) / 2
    N = X.shape[0]
    known = np.eye(N, dtype=bool)
    for C in cliques:
        known[np.ix_(C, C)] = True
    if known.all():
        return X
    dg = np.sqrt(np.maximum(np.diag(X), 0.0))
    dg[dg == 0] = 1.0
    Y = X / np.outer(dg, dg)
    weight, done, order = np.zeros(N), np.zeros(N, bool), []
    for _ in range(N):  # maximum cardinality search
        v = int(np.argmax(np.where(done, -1.0, weight)))
        order.append(v)
        done[v] = True
        weight += known[v]
    for i in range(1, N):
        v, prev = order[i], np.array(order[:i])
        S, R = prev[known[v, prev]], prev[~known[v, prev]]
        if R.size == 0:
            continue
        if S.size == 0:
            Y[v, R] = Y[R, v] = 0.0
            continue
        w, U = np.linalg.eigh(Y[np.ix_(S, S)])
        keep = w > rtol * max(w[-1], 0.0)
        a = (Y[v, S] @ U[:, keep]) / w[keep]
        Y[v, R] = Y[R, v] = a @ (U[:, keep].T @ Y[np.ix_(S, R)])
    return Y * np.outer(dg, dg)


def marginal_X(inst: Instance, X: np.ndarray, cliques: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """The marginalised SDP's solution from X (N × N) of either formulation: X itself when ϖ was
    marginalised, else X's x-block.  ``cliques``: the cover (column indices) of a decomposed solve,
    whose X is known on the clique blocks only (``sdp.solve`` fills the rest from the blocks' rank-1
    factors, which would hide any higher rank): X is then first replaced by its maximum-determinant
    completion from those blocks (``complete_psd``), which is as rank-deficient as the data allows
    and no more.  Why the x-block: with Q_ww ≻ 0, min over the ϖ rows and columns of ⟨Q_full, X⟩
    s.t. X ⪰ 0 is ⟨S, X_xx⟩ (module docstring), so the x-block of an optimum of the ϖ-kept SDP is an
    optimum of the marginalised one, with the same constraints on it."""
    d = _data(inst)
    X = np.asarray(X, dtype=float) if cliques is None else complete_psd(X, cliques)
    if d.marginalize:
        return X
    Vf, Vx = _variables(d, True), _variables(d, False)
    if X.shape != (Vf.N, Vf.N):
        raise ProblemDefinitionError(f"X is {X.shape}, the ϖ-kept lifting has {Vf.N} columns")
    ix = Vf.index(Vx.names)
    return X[np.ix_(ix, ix)]


def marginal_log_svr(inst: Instance, X: np.ndarray, cliques: Sequence[np.ndarray] | None = None) -> float:
    """log10(λ₁/λ₂) of the marginalised X (``marginal_X``), the quantity the paper's Fig. 11 plots,
    whichever formulation was solved (``cliques``: the cover of a decomposed solve, else None)."""
    return log_svr(np.linalg.eigvalsh(marginal_X(inst, X, cliques))[::-1])


# ----------------------------------------------------------------------------- states and costs


def residuals(inst: Instance, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Measurement residuals ξ_k (M, 6) and motion residuals ξ_{k+1,k} (K−1, 6) of poses T (K, 4, 4)."""
    d = _data(inst)
    meas = np.array([lie.cay_inv_se3(T[k] @ lie.inv_se3(Tm)) for k, Tm in zip(d.measured, d.T_meas)]).reshape(-1, 6)
    motion = np.array([lie.cay_inv_se3(T[k + 1] @ lie.inv_se3(T[k])) for k in range(d.K - 1)]).reshape(-1, 6)
    return meas, motion


def optimal_twists(inst: Instance, T: np.ndarray) -> np.ndarray:
    """argmin over ϖ of the cost for fixed poses T, (K, 6): ϖ* = −Q_ww⁻¹ Q_wx x(T)."""
    mg = marginal(inst)
    x = _lift(inst, {"T": T, "w": np.zeros((len(T), 6))})[:mg.Vx.N]  # the twists' blocks come last
    return mg.twists(x)


def lift(inst: Instance, state: dict) -> np.ndarray:
    """x (N,) (the layer's): ϖ blocks are included (from state["w"]) only when the instance keeps ϖ in the lifting."""
    _data(inst)
    return _lift(inst, state)


def cost(inst: Instance, state: dict) -> float:
    """The cost (46) at poses state["T"] and twists state["w"] (the optimal twists if "w" is absent)."""
    T = np.asarray(state["T"], dtype=float)
    w = optimal_twists(inst, T) if "w" not in state else np.asarray(state["w"], dtype=float)
    e, _, W = linearize(inst, (T, w), jacobian=False)
    return float(e @ (W @ e))


# ----------------------------------------------------------------------------- local solver (App. A.5)


def linearize(inst: Instance, state: tuple[np.ndarray, np.ndarray], jacobian: bool = True
              ) -> tuple[np.ndarray, sp.csr_array | None, sp.csr_array]:
    """Stacked residual e, sparse Jacobian and weight for T_k = cay(ε_k^∧) T_k,op, ϖ_k = ϖ_k,op + η_k.

    Perturbation order [ε₀, η₀, ε₁, η₁, …] (12 per state).  Rows: ξ_k per measured k (weight W_k),
    ϖ₀ − ϖ̌₀ (Q₁⁻¹), e_{k+1,k} = [Δt ϖ_k − ξ_{k+1,k}; ϖ_k − ϖ_{k+1}] (Q_{k+1,k}⁻¹).  With the
    left Jacobians of ``lie``: ∂ξ_k/∂ε_k = 𝒥(ξ_k)⁻¹, ∂ξ_{k+1,k}/∂ε_k = −𝒥⁻¹ Ad(T_{k+1}T_k⁻¹),
    ∂ξ_{k+1,k}/∂ε_{k+1} = 𝒥⁻¹ (paper (84): F_k, E_{k+1}).
    """
    d = _data(inst)
    T, w = state
    es, Ws, blocks = [], [], []  # blocks: (row offset, column offset, matrix)
    row = 0

    def put(col_state: int, col_part: int, M: np.ndarray) -> None:
        blocks.append((row, 12 * col_state + 6 * col_part, M))

    for k, Tm, Wk in zip(d.measured, d.T_meas, d.W):
        xi, J = lie.residual_se3(T[k], Tm)
        es.append(xi); Ws.append(Wk); put(int(k), 0, J); row += 6
    es.append(w[0] - d.w_prior); Ws.append(np.linalg.inv(d.Q1)); put(0, 1, np.eye(6)); row += 6
    I6, Z6 = np.eye(6), np.zeros((6, 6))
    for k, dt in enumerate(np.diff(d.times)):
        xi, J1, J2 = lie.residual_se3_binary(T[k], T[k + 1])
        es.append(np.concatenate([dt * w[k] - xi, w[k] - w[k + 1]]))
        Ws.append(wnoa_inverse_covariance(dt, d.Qc))
        put(k, 0, np.vstack([-J1, Z6])); put(k + 1, 0, np.vstack([-J2, Z6]))
        put(k, 1, np.vstack([dt * I6, I6])); put(k + 1, 1, np.vstack([Z6, -I6]))
        row += 12
    e = np.concatenate(es)
    W = sp.csr_array(sp.block_diag(Ws))
    if not jacobian:
        return e, None, W
    r, c, v = [], [], []
    for r0, c0, M in blocks:
        rr, cc = np.nonzero(np.ones_like(M))
        r.append(rr + r0); c.append(cc + c0); v.append(M.ravel())
    J = sp.csr_array((np.concatenate(v), (np.concatenate(r), np.concatenate(c))), shape=(row, 12 * d.K))
    return e, J, W


def retract(state: tuple[np.ndarray, np.ndarray], delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T_k ← cay(ε_k^∧) T_k, ϖ_k ← ϖ_k + η_k (paper (82))."""
    T, w = state
    dl = np.asarray(delta, dtype=float).reshape(-1, 2, 6)
    return np.array([lie.cay_se3(e) @ Tk for e, Tk in zip(dl[:, 0], T)]), w + dl[:, 1]


def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
    """Gauss-Newton on the sparse stacked system (App. A.5, LM-damped), poses and twists jointly.

    Missing init["w"] is replaced by the optimal twists for init["T"].
    """
    T0 = np.asarray(init["T"], dtype=float)
    w0 = optimal_twists(inst, T0) if "w" not in init else np.asarray(init["w"], dtype=float)
    res = gauss_newton(lambda s: linearize(inst, s), retract, (T0, w0), max_iter=max_iter)
    res.state = {"T": res.state[0], "w": res.state[1]}
    return res


# ----------------------------------------------------------------------------- sampling, recovery, errors


def _valid(inst: Instance, T: np.ndarray) -> bool:
    try:
        residuals(inst, T)
        return True
    except lie.CayleySingularityError:
        return False


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """T_k = exp((spread·ν_k)^∧) T_k,nominal (det C = +1), ϖ_k = ϖ_k,nominal + spread·η_k; ν, η ~ N(0, I₆)."""
    Tn, wn = np.asarray(nominal["T"], dtype=float), np.asarray(nominal["w"], dtype=float)
    for _ in range(100):
        T = np.array([lie.exp_se3(spread * rng.standard_normal(6)) @ Tk for Tk in Tn])
        if _valid(inst, T):
            return {"T": T, "w": wn + spread * rng.standard_normal(wn.shape)}
    raise SolverError("could not draw a sample away from the Cayley singularity; reduce the spread")


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    """Independent uniform rotations, translations ~ N(0, L² I) with L half the nominal path length,
    and the optimal twists for those poses (a start that knows nothing of the measurements)."""
    d = _data(inst)
    L = max(0.5 * float(inst.params.get("motion", 1.0)) * (d.times[-1] - d.times[0]), 1.0)
    for _ in range(100):
        T = np.array([lie.make_pose(lie.random_rotation(rng), L * rng.standard_normal(3)) for _ in range(d.K)])
        if _valid(inst, T):
            return {"T": T, "w": optimal_twists(inst, T)}
    raise SolverError("could not draw a random state away from the Cayley singularity")


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """Poses from the rank-1 factor (the layer's: raw rotations projected to SO(3), dets reported) and the
    twists: read from x when kept, else ϖ* = −Q_ww⁻¹ Q_wx x."""
    d = _data(inst)
    x = np.asarray(Theta, dtype=float).reshape(-1)
    N = _variables(d, not d.marginalize).N
    if x.size != N:
        raise ProblemDefinitionError(f"Θ has {x.size} columns, the lifting has {N}")
    est = _recover(inst, x)
    T = np.array([lie.make_pose(C, r) for C, r in zip(est["C"], est["r"])])
    w = marginal(inst).twists(x / x[0]) if d.marginalize else est["w"]
    return {"T": T, "w": w, "det_raw": est["det_raw"]}


def errors(inst: Instance, state: dict) -> dict:
    """Largest rotation error (deg), RMS translation error and RMS twist error against the truth."""
    T, Tt = np.asarray(state["T"]), inst.truth["T"]
    out = {"rotation_deg_max": lie.rotation_error_deg(T[:, :3, :3], Tt[:, :3, :3]),
           "translation_rms": float(np.sqrt(np.mean(np.sum((T[:, :3, 3] - Tt[:, :3, 3]) ** 2, axis=1))))}
    if "w" in state:
        out["twist_rms"] = float(np.sqrt(np.mean(np.sum((np.asarray(state["w"]) - inst.truth["w"]) ** 2, axis=1))))
    return out
