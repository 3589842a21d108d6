"""Robust pose averaging: pose averaging (paper §3.2) with outliers and a truncated-least-squares cost.

Estimate T = [[C, r], [0ᵀ, 1]] ∈ SE(3) from M measurements T̃_m.  Inliers: T̃_m = cay(ν_m^∧) T,
ν_m ~ N(0, σ² I₆).  Outliers (round(outlier_rate·M) of them, at random indices): T̃_m = cay(ν_m^∧) T
with ρ and φ of ν_m each of norm ``outlier_size`` in a random direction.

Cost (TLS with binary w_m ∈ {±1}; w_m = 1 inlier, −1 outlier), with ξ_m = cay⁻¹(T T̃_m⁻¹)^∨:

    f(T, w) = Σ_m (1 + w_m)/β² · ξ_mᵀ W_m ξ_m + 1 − w_m        (W_m = I)

so min_w f = Σ_m 2·min(ξ_mᵀW_mξ_m/β², 1): a measurement counts as an inlier while its residual is
below β.

Lifting.  The cost term w_m ξ_mᵀW_mξ_m is cubic.  Lift z_m = w_m·ξ_m (6 entries: zrho_m = w_m ρ_m,
zphi_m = w_m φ_m), i.e. w_m times the factor's pose block ξ_m = [ρ_m; φ_m], the block the cost
is written in (AutoTight's rPPR lifts z_i = w_i·[t; vec R] because its residual is linear in
[t; vec R]; here the residual is the block ξ_m itself, and lifting w_m·[C, r] instead would leave
w_m ξ_m cubic).  Then

    x = [h, c₁, c₂, c₃, r, (ρ_m, φ_m, w_m, zρ_m, zφ_m)_{m=1..M}]      n = 13 + 13M,
    xᵀQx = Σ_m (ξ_mᵀW_mξ_m + ξ_mᵀW_m z_m)/β² + h² − w_m h          (the same f when h = 1).

Primary constraints (they make the lifting exact: with h = ±1, w_m = ±1 and z_m = w_m ξ_m, every
feasible x is ±(the lifting of some (T, w))):

- c_iᵀc_j = δ_ij h² (6);
- per m, the 12 Cayley rows of ξ_m = cay⁻¹(T T̃_m⁻¹) (as in pose averaging);
- per m, w_m² = h² (1);
- per m, z_m·h = w_m·ξ_m (6, bilinear).

Valid redundant relations include z_mᵀz_m = ξ_mᵀξ_m (more finely z_{m,k} z_{m,l} = ξ_{m,k} ξ_{m,l}),
z_m·w_m = ξ_m·h, z_{m,k} ξ_{m,l} = z_{m,l} ξ_{m,k}, and the Cayley rows multiplied by w_m written with
z_m (w_m c_i − w_m c̃_i h − ½ zφ_m × (c_i + c̃_i h) = 0).  With the primary constraints alone nothing
bounds the z blocks: the cross term ξ_mᵀW_m z_m is unbounded below and the SDP is unbounded
(discovery reports this and first adds the relations that bound z, e.g. z_mᵀz_m = ξ_mᵀξ_m).

Why per-measurement relations are not enough.  The cost monomials w_m ξ_{m,k} ξ_{m,l} appear only in
the entries z_m ξ_mᵀ of X, and no quadratic relation within one measurement ties them to anything but
z_mᵀz_m = ξ_mᵀξ_m and the symmetry of z_m ξ_mᵀ: ξ_m is a rational function of T (Cayley), so no
quadratic relation in (h, T, ξ_m) has ξ_m ξ_mᵀ terms that w_m could turn into z_m ξ_mᵀ.  The relaxation
then "reflects" z_m against ξ_m (z_m − E z_m = −(ξ_m − E ξ_m)), which removes the spread of ξ_m from
the inlier cost; a spread-out T then lowers the bound (5.4 % below the optimum with the per-measurement
relations alone, M = 6, seed 0).  Relations between two measurements tie those spreads: the relation
between ξ_m and ξ_l through the shared pose, (I − ½ξ_l^∧)(I + ½ξ_m^∧)T̃_m = (I + ½ξ_l^∧)(I − ½ξ_m^∧)T̃_l,
is quadratic, and so are its products with w_m, w_l and w_m w_l once written with z_m, z_l (terms
z_m ξ_l, ξ_m z_l, z_m z_l).

Factors: "so3" (h, c₁, c₂, c₃); per m "robust_meas" (h, C, r, ρ_m, φ_m, w_m, zρ_m, zφ_m; 26 columns);
per consecutive pair (m, m+1) "robust_pair" (h, ξ_m, w_m, z_m, ξ_{m+1}, w_{m+1}, z_{m+1}; 27 columns),
with no cost and no primary constraint: a learning group (so that ``factors`` learns the relations
between two measurements, and a learned set carries to any M) whose relations join cliques m and m+1.
The clique cover is the path {h, C, r, ξ_m, w_m, z_m, ξ_{m+1}, w_{m+1}, z_{m+1}}, m = 0 … M−2.
No paper families.  Rank 1 is generally not reached by quadratic constraints on this lifting
(as for AutoTight's rPPR, which is cost-tight, not rank-tight): use ``--accept cost``.

Discovery: ``DEFAULT_GROUPS`` ("factors": so3, robust_meas and robust_pair) is what ``autotight
discover`` uses for this problem unless ``--groups`` is given.  Pairs of consecutive measurements
suffice: all pairs (``adjacent:robust_meas+robust_meas/rho/phi/w/zrho/zphi``, 15 pairs at M = 6) are also
cost-tight, but they couple every measurement with every other, so the SDP has no sparsity left
(one 250 s solve at load 10, against about 40 s on the path cover).

Measured (M = 6, 1 outlier, σ = 0.05, seed 0; load 10-14 on 2 cores):
- per-measurement relations alone (so3, robust_meas: 111 candidate pairs, 596 constraints): bounded,
  5.4 % below the brute-force optimum: not cost-tight, as argued above;
- with the relations of consecutive pairs learned as separate groups (block lists, 609 more
  constraints), one Clarabel solve (scaled, third attempt with clique_graph merging) reached the
  brute-force optimum to a relative gap of 2.8e-7 (log SVR 2.0: cost-tight, not rank-tight);
- with ``DEFAULT_GROUPS`` (181 candidate pairs, 944 constraints; the robust_pair identities carried to
  all five pairs) the solve with every candidate ends AlmostSolved at best (|U − D| ≈ 2e-5 relative,
  accuracy 1e-4; which status depends on the constraint order) or stalls (InsufficientProgress /
  NumericalError, also at tol 1e-6, scaled, with the 8 exactly dependent rows removed, or with the
  IPM); the multipliers do not certify the optimum (λ_min(H) < 0 and no trace bound: nothing bounds
  ξ_m and r in the certificate's sense).  ``discover --accept cost`` therefore ends "undecided", with
  no reduction and no held-out check.  Greedy tightening instead (``DEFAULT_TIGHTEN = "greedy"``)
  reaches a bracket gap of 1.3e-10 with 167 pairs (AlmostSolved, certificate still failing) after
  32 solver calls, 558 s wall / 116 s CPU.  The likely cause of the stalls is a relaxation without
  a strictly feasible point (facial reduction would be needed); not resolved.


Sampling discrete variables: ``sample`` must cover every value of each discrete variable and their
combinations that the monomials can see.  Here w_m = ±1 independently with probability ½ each, so
every w_m, w_m w_l and w_m·(continuous) monomial takes both signs; a sampler that kept w_m = 1 would
teach the false relation w_m = h (and cut off every outlier labelling).

Local solver (brute force, small M): for each w ∈ {±1}^M, Gauss-Newton (LM-damped, as pose
averaging) on the inliers' residuals weighted 2/β² from the given start, plus 2 per outlier; the
best (T, w) is returned.  2^M solves: meant for M ≤ 10 (``MAX_BRUTE_FORCE``).

Comparison (no paper families): AutoTight's published robust point registration (rPPR) row:
1771 → 925 constraints, cost-tight (relative duality gap 1.1e-6, SVR 34), 148 s (137 s reducing).
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.errors import ParameterError
from autotight.gauss_newton import gauss_newton
from autotight.model import Constraint, Factor, Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Param

from ._cayley import draw_valid
from ._pose import (POSE_ROLES, XI_ROLES, pose_blocks, pose_from_x, pose_orthonormality, pose_values,
                    unary_cayley, unary_residuals, xi_blocks)

NAME = "robust_pose_averaging"
DESCRIPTION = "Pose averaging with outliers: TLS cost with binary w_m, lifted z_m = w_m·ξ_m (paper §3.2 + TLS)."
PARAMS = {
    "M": Param(6, "number of pose measurements", low=1),
    "sigma": Param(0.05, "inlier noise standard deviation of each ξ_m component", low=0.0),
    "outlier_rate": Param(1 / 6, "fraction of outlier measurements (round(rate·M) of them)", low=0.0, high=1.0),
    "outlier_size": Param(1.0, "norm of an outlier's ρ and of its φ at the true pose (Cayley units)", low=0.0),
    "beta": Param(0.5, "TLS threshold on ‖ξ_m‖_W (inlier while below)", low=0.0, low_open=True),
    "scale": Param(1.0, "standard deviation of each component of the true translation", low=0.0),
}

#: the learning groups discovery uses by default for this problem (see the module docstring)
DEFAULT_GROUPS = "factors"
#: discovery's tightening starts from every candidate once bounded (``discovery.tighten``): the violation
#: ranking is not selective here (the greedy rounds add every pair, one solve per doubling)
DEFAULT_TIGHTEN = "all"
#: the brute-force local solver enumerates 2^M labellings: refused above this M
MAX_BRUTE_FORCE = 12

MEAS_ROLES = ("h", *POSE_ROLES, *XI_ROLES, "w", "zrho", "zphi")
PAIR_ROLES = ("h", *(f"{k}.{r}" for k in (1, 2) for r in (*XI_ROLES, "w", "zrho", "zphi")))


def n_outliers(params: dict) -> int:
    return int(round(params["outlier_rate"] * params["M"]))


def generate(params: dict, rng: np.random.Generator) -> Instance:
    M, sigma = params["M"], params["sigma"]
    T = lie.make_pose(lie.random_rotation(rng), params["scale"] * rng.standard_normal(3))
    out = np.zeros(M, bool)
    out[rng.choice(M, size=n_outliers(params), replace=False)] = True
    T_meas = []
    for m in range(M):
        if out[m]:
            d = rng.standard_normal((2, 3))
            nu = params["outlier_size"] * (d / np.linalg.norm(d, axis=1, keepdims=True)).ravel()
        else:
            nu = sigma * rng.standard_normal(6)
        T_meas.append(lie.cay_se3(nu) @ T)
    W = np.repeat(np.eye(6)[None], M, axis=0)
    w = np.where(out, -1.0, 1.0)
    return Instance(NAME, dict(params), {"T_meas": np.array(T_meas), "W": W, "beta": float(params["beta"])},
                    {"C": T[:3, :3], "r": T[:3, 3], "w": w})


def z_blocks(m: int | str) -> list[str]:
    return [f"zrho_{m}", f"zphi_{m}"]


def w_block(m: int | str) -> str:
    return f"w_{m}"


def meas_blocks(m: int) -> list[str]:
    """The blocks of measurement m's factor after h: C, r, ξ_m, w_m, z_m."""
    return [*pose_blocks(), *xi_blocks(str(m)), w_block(m), *z_blocks(m)]


def _variables(M: int) -> Variables:
    blocks = [(b, 3) for b in pose_blocks()]
    for m in range(M):
        blocks += [(b, 3) for b in xi_blocks(str(m))] + [(w_block(m), 1)] + [(b, 3) for b in z_blocks(m)]
    return Variables(blocks)


def _pair_form(V: Variables, a: list[str], b: list[str], W: np.ndarray) -> QuadForm:
    """uᵀ W v for u = [a₀; a₁], v = [b₀; b₁] (3-blocks), W (6, 6)."""
    qf = QuadForm(V)
    for i in range(2):
        for j in range(2):
            blk = W[3 * i:3 * i + 3, 3 * j:3 * j + 3]
            if np.any(blk):
                qf.add(a[i], b[j], blk)
    return qf


def meas_cost(V: Variables, m: int, W: np.ndarray, beta: float) -> sp.csr_array:
    """(ξᵀWξ + ξᵀWz)/β² + h² − w·h for measurement m."""
    xi = xi_blocks(str(m))
    A = (_pair_form(V, xi, xi, W).matrix() + _pair_form(V, xi, z_blocks(m), W).matrix()) / beta ** 2
    return sp.csr_array(A + QuadForm(V).const(1.0).add("h", w_block(m), -1.0).matrix())


def binary_constraints(V: Variables, m: int, name: str) -> list[Constraint]:
    """w_m² = h² and z_m·h = w_m·ξ_m (7 rows)."""
    w = w_block(m)
    out = [Constraint(QuadForm(V).add(w, w, 1.0).const(-1.0).matrix(), 0.0, name=f"{name}:w²=h²")]
    for zb, xb in zip(z_blocks(m), xi_blocks(str(m))):
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            A = QuadForm(V).add("h", zb, e.reshape(1, 3)).add(w, xb, -e.reshape(1, 3)).matrix()
            out.append(Constraint(A, 0.0, name=f"{name}:{zb}[{k}]h=w·{xb}[{k}]"))
    return out


def build(inst: Instance) -> Model:
    T_meas, Ws, beta = inst.measurements["T_meas"], inst.measurements["W"], float(inst.measurements["beta"])
    M = len(T_meas)
    V = _variables(M)
    pose = pose_blocks()
    factors = [Factor("rotation", "so3", ("h", *pose[:3]), constraints=pose_orthonormality(V, factor="rotation"))]
    for m in range(M):
        name, s = f"meas_{m}", str(m)
        cons = unary_cayley(V, "", T_meas[m], s, name) + binary_constraints(V, m, name)
        factors.append(Factor(name, "robust_meas", ("h", *meas_blocks(m)), cost=meas_cost(V, m, Ws[m], beta),
                              constraints=cons, roles=MEAS_ROLES))
    for m in range(M - 1):  # learning groups only: no cost, no primary constraints
        factors.append(Factor(f"pair_{m}_{m + 1}", "robust_pair", ("h", *label_blocks(m), *label_blocks(m + 1)),
                              roles=PAIR_ROLES))
    return Model(V, factors, paper={}, cliques=cliques(M))


def label_blocks(m: int) -> list[str]:
    """ξ_m, w_m, z_m: measurement m's blocks without the pose."""
    return [*xi_blocks(str(m)), w_block(m), *z_blocks(m)]


def cliques(M: int) -> list[tuple[str, ...]]:
    """{h, C, r, ξ_m, w_m, z_m, ξ_{m+1}, w_{m+1}, z_{m+1}} for m = 0 … M−2 (a path: the intersection of
    cliques m and m+2, {h, C, r}, lies in clique m+1); {h, C, r, ξ_0, w_0, z_0} when M = 1."""
    if M == 1:
        return [("h", *meas_blocks(0))]
    return [("h", *meas_blocks(m), *label_blocks(m + 1)) for m in range(M - 1)]


def _pose(state: dict) -> np.ndarray:
    return lie.make_pose(state["C"], state["r"])


def residuals(inst: Instance, state: dict) -> np.ndarray:
    """ξ_m = cay⁻¹(T T̃_m⁻¹)^∨, (M, 6)."""
    return unary_residuals(_pose(state), inst.measurements["T_meas"])


def _labels(inst: Instance, state: dict) -> np.ndarray:
    M = len(inst.measurements["T_meas"])
    w = np.asarray(state.get("w", np.ones(M)), dtype=float).reshape(-1)
    if w.shape != (M,) or not np.all(np.abs(w) == 1.0):
        raise ParameterError(f"state w must hold {M} entries ±1, got {w}")
    return w


def lift(inst: Instance, state: dict) -> np.ndarray:
    w = _labels(inst, state)
    vals = pose_values(state["C"], state["r"])
    for m, xi in enumerate(residuals(inst, state)):
        rho, phi = xi_blocks(str(m))
        zr, zp = z_blocks(m)
        vals |= {rho: xi[:3], phi: xi[3:], w_block(m): np.array([w[m]]), zr: w[m] * xi[:3], zp: w[m] * xi[3:]}
    return _variables(len(w)).assemble(vals)


def cost(inst: Instance, state: dict) -> float:
    w, beta = _labels(inst, state), float(inst.measurements["beta"])
    return float(sum((1 + wm) / beta ** 2 * (xi @ W @ xi) + 1 - wm
                     for wm, xi, W in zip(w, residuals(inst, state), inst.measurements["W"])))


def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """T = exp((spread·ν)^∧) T_nominal, ν ~ N(0, I₆); each w_m = ±1 with probability ½ (independent of the
    nominal w), so the samples cover both values of every w_m and of every product w_m w_l."""
    T0 = _pose(nominal)
    M = len(inst.measurements["T_meas"])

    def draw() -> dict:
        T = lie.exp_se3(spread * rng.standard_normal(6)) @ T0
        return {"C": T[:3, :3], "r": T[:3, 3], "w": rng.choice([-1.0, 1.0], size=M)}

    return draw_valid(draw, lambda state: residuals(inst, state))


def random_state(inst: Instance, rng: np.random.Generator) -> dict:
    """Uniform rotation, translation ~ N(0, max(scale, 1)² I), random labels."""
    s = max(float(inst.params.get("scale", 1.0)), 1.0)
    return sample(inst, rng, {"C": lie.random_rotation(rng), "r": s * rng.standard_normal(3)}, 0.0)


def _linearize(inst: Instance, T: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacked ξ_m of the inliers, their Jacobians w.r.t. ε (T = cay(ε^∧) T_op), weights 2 W_m/β²."""
    beta = float(inst.measurements["beta"])
    idx = np.flatnonzero(inliers)
    es, Js = [], []
    W = np.zeros((6 * idx.size, 6 * idx.size))
    for k, m in enumerate(idx):
        xi, J = lie.residual_se3(T, inst.measurements["T_meas"][m])
        es.append(xi)
        Js.append(J)
        W[6 * k:6 * k + 6, 6 * k:6 * k + 6] = 2.0 / beta ** 2 * inst.measurements["W"][m]
    return np.concatenate(es), np.vstack(Js), W


def _gn(inst: Instance, T0: np.ndarray, inliers: np.ndarray, max_iter: int) -> LocalResult:
    res = gauss_newton(lambda T: _linearize(inst, T, inliers), lambda T, e: lie.cay_se3(e) @ T, T0,
                       max_iter=max_iter)
    res.state = {"C": res.state[:3, :3], "r": res.state[:3, 3]}
    return res


def local_solve(inst: Instance, init: dict, max_iter: int = 100) -> LocalResult:
    """Brute force over w ∈ {±1}^M (``init``'s w is ignored): Gauss-Newton on all measurements from
    ``init``'s pose gives T_a; then for every labelling, Gauss-Newton on its inliers from T_a (a start
    near every labelling's average, so each run takes a few iterations); the best (T, w).
    ``converged`` is that of the winning run; ``iterations`` counts all of them."""
    M = len(inst.measurements["T_meas"])
    if M > MAX_BRUTE_FORCE:
        raise ParameterError(f"the brute-force local solver enumerates 2^M labellings; M = {M} > {MAX_BRUTE_FORCE}")
    first = _gn(inst, _pose(init), np.ones(M, bool), max_iter)
    T0 = _pose(first.state)
    best: LocalResult | None = None
    iters = first.iterations
    for bits in itertools.product([True, False], repeat=M):
        inl = np.array(bits)
        if not inl.any():
            res = LocalResult({"C": T0[:3, :3], "r": T0[:3, 3]}, 0.0, 0, True)
        else:
            res = _gn(inst, T0, inl, max_iter)
        iters += res.iterations
        res.state["w"] = np.where(inl, 1.0, -1.0)
        res.cost = cost(inst, res.state)  # the TLS cost (the GN cost plus 2 per outlier)
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    best.iterations = iters
    best.message = f"best of 2^{M} labellings; {best.message}"
    return best


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """T from the rank-1 factor x (raw rotation projected to SO(3), its det reported) and w_m = sign(x_w)."""
    x = np.asarray(Theta, dtype=float).reshape(-1)
    x = x / x[0]
    M = len(inst.measurements["T_meas"])
    V = _variables(M)
    C_raw, r = pose_from_x(V, x)
    w = np.array([1.0 if x[V.slice(w_block(m))][0] >= 0 else -1.0 for m in range(M)])
    return {"C": lie.project_to_so3(C_raw), "r": r, "w": w, "det_raw": np.array(np.linalg.det(C_raw))}


def errors(inst: Instance, state: dict) -> dict:
    """Rotation error (deg), translation error, and labels that differ from the generated ones."""
    R = state["C"] @ inst.truth["C"].T
    out = {"rotation_deg": float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))),
           "translation": float(np.linalg.norm(state["r"] - inst.truth["r"]))}
    if "w" in state:
        out["labels_wrong"] = float(np.sum(np.asarray(state["w"]) != inst.truth["w"]))
    return out
