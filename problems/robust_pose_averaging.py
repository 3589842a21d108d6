"""Robust pose averaging: pose averaging (paper §3.2) with outliers and a truncated-least-squares cost.

Estimate T = [[C, r], [0ᵀ, 1]] ∈ SE(3) from M measurements T̃_m.  Inliers: T̃_m = cay(ν_m^∧) T,
ν_m ~ N(0, σ² I₆).  Outliers (round(outlier_rate·M) of them, at random indices): T̃_m = cay(ν_m^∧) T
with ρ and φ of ν_m each of norm ``outlier_size`` in a random direction.

Cost (TLS with binary w_m ∈ {±1}; w_m = 1 inlier, −1 outlier), with ξ_m = cay⁻¹(T T̃_m⁻¹)^∨:

    f(T, w) = Σ_m (1 + w_m)/β² · ξ_mᵀ W_m ξ_m + 1 − w_m        (W_m = I)

so min_w f = Σ_m 2·min(ξ_mᵀW_mξ_m/β², 1): a measurement counts as an inlier while its residual is
below β.

Lifting.  The cost term w_m ξ_mᵀW_mξ_m is cubic.  Two liftings (parameter ``lifting``):

- **gated** (default): u_m = ½(1 + w_m)·ξ_m, the residual of an inlier and 0 for an outlier (6 entries:
  urho_m, uphi_m).  Since (1 + w_m)² = 2(1 + w_m), (1 + w_m)ξ_mᵀWξ_m = 2 u_mᵀWu_m:

      x = [h, c₁, c₂, c₃, r, (w_m, uρ_m, uφ_m)_{m=1..M}]      n = 13 + 7M,
      xᵀQx = Σ_m 2 u_mᵀW_m u_m/β² + h² − w_m h.

  Primary constraints: c_iᵀc_j = δ_ij h² (6); per m, w_m² = h² (1), u_m·h = u_m·w_m (6: u_m = 0 for an
  outlier), and the 12 Cayley rows of ξ_m multiplied by ½(h + w_m), written with u_m ("gated" rows,
  ``affine.cayley_rows(gate=…)``): ½(h + w_m)(c_i − c̃_i h) − ½ uφ_m × (c_i + c̃_i h) = 0 and
  ½(h + w_m)(r − r̃ h) − ½ uφ_m × (r + r̃ h) − uρ_m h = 0.  Exact: w_m = 1 makes them ξ_m's Cayley rows,
  w_m = −1 makes u_m = 0 and the rows vanish.
- **product** (the first form, AutoTight's rPPR style): z_m = w_m·ξ_m beside ξ_m,
  x = [h, C, r, (ρ_m, φ_m, w_m, zρ_m, zφ_m)_m] (n = 13 + 13M), xᵀQx = Σ_m (ξ_mᵀWξ_m + ξ_mᵀWz_m)/β² + h² − w_m h;
  primary: orthonormality, ξ_m's Cayley rows, w_m² = h², z_m·h = w_m·ξ_m.

Why gated.  In the product lifting every direction v = e_ξ − e_z of one measurement (ξ_m growing with
z_m = −ξ_m: an outlier's residual) has vᵀQv = 0 and vᵀAv = 0 for every valid quadratic relation (no
quadratic relation has ξ_mξ_mᵀ terms: ξ_m is a rational function of T).  Measured on all 944 learned
candidates at M = 6: max |vᵀAv| = 5e-15.  So X + t·vvᵀ stays optimal for all t: the relaxation's optimal set
is unbounded, its dual has no interior point (every dual feasible H has Hv = 0), and the solvers stall
(AlmostSolved at best, NumericalError / InsufficientProgress otherwise, with Clarabel and our IPM alike).
The gated lifting is that lifting with the directions v projected out: it keeps u_m = ½(ξ_m + z_m) and
drops ½(ξ_m − z_m), which neither the cost nor any relation sees.  One recession direction is left: the
translation r (no quadratic relation in the gated lifting has rᵀr terms; the product lifting's rᵀr
relations, R2, need ξ_m of every measurement).  It is a coordinate direction, which the certificate
handles exactly (``certificate`` docstring, "recession columns": H must vanish on r, and the trace is
bounded on the other columns).  Rank 1 is out of reach on either lifting (X_rr grows at no cost): use
``--accept cost``.  The primary relaxation of the gated lifting is bounded (the cost bounds u_m); that of
the product lifting is unbounded in the z blocks, which ``solve --set primary -p lifting=product``
reports.

Relations between measurements.  Per-measurement relations alone leave the bound percent below the
optimum (product lifting: 5.4 %, M = 6, seed 0).  The relation between ξ_m and ξ_l through the shared
pose, (I − ½ξ_l^∧)(I + ½ξ_m^∧)T̃_m = (I + ½ξ_l^∧)(I − ½ξ_m^∧)T̃_l, is quadratic, and so is its product with
½(h + w_m)·½(h + w_l) written with u_m, u_l.  Gated: relations of consecutive pairs only certify 2 of 10
held-out instances (M = 6, σ = 0.05, every candidate); those of every pair, with the pose, all 10.

Written on the factor-graph layer (``autotight.graph``), as above:

- variables: C ∈ SO(3) (blocks c₁, c₂, c₃; its factor "rotation" of type "so3" holds c_iᵀc_j = δ_ij h²,
  named orth(c_i,c_j)), r ∈ R³ (no factor of its own) and the labels w ∈ {±1}^M (``Binary(equation=False)``,
  blocks w_m: each measurement factor declares its w_m² = h², where saved sets know it);
- factors: per m "meas_m" of type "robust_meas" on (C, r, w_m), owning the measurement's lifted blocks
  (``OWN``: u_m gated, ξ_m and z_m product), whose value is ``own_values``; its lifted TLS term
  (``tls_cost``) and primary constraints (``meas_constraints``: the 12 Cayley rows, gated or not, w_m² = h²
  and the 6 rows u_m·h = u_m·w_m or z_m·h = w_m·ξ_m); 20 columns gated, 26 product;
- groups: per pair "pair_m_l" of type "robust_pair", no cost and no primary constraint: a learning group (so
  that ``factors`` learns the relations between two measurements, and a learned set carries to any M).
  Gated: every pair (m, l), with the pose (h, C, r, w_m, u_m, w_l, u_l; 27 columns).  Product: consecutive
  pairs without the pose (h, ξ_m, w_m, z_m, ξ_{m+1}, w_{m+1}, z_{m+1}; 27 columns);
- the lifted vector in the order written above (``lifted_blocks``, ``derive(blocks=…)``), each measurement
  factor's blocks in that order.  No paper families.

The layer derives the model (``build``, which adds the cliques), ``lift`` (the labels checked first, as (1, n))
and ``recover``.  Hand-written, so that the committed reports and saved sets stand to the last bit:

- each measurement's lifted cost and primary constraints, as matrices on its local columns built with
  ``autotight.affine`` as before (``tls_cost``: h² − w_m h is no eᵀWe of an affine residual;
  ``meas_constraints``: the same 19 rows given to the layer as the auxiliary's equations are fitted to
  matrices up to 4e-16 relative apart, the fit evaluating at h = 1, and named aux[k]);
- the cliques (product lifting: the path cover {h, C, r, m's blocks, m+1's}, which no factor holds; gated:
  none, its pairs couple every measurement with every other);
- ``cost`` (the TLS formula, by which the local solver compares labellings), ``sample`` (T = exp(ν^∧) T̄ on
  SE(3), then uniform labels: the layer's sampler retracts C and r apart and leaves labels fixed),
  ``random_state``, ``errors`` and ``local_solve`` (below: the layer's solver moves continuous variables only).

Discovery: ``DEFAULT_GROUPS`` ("factors"); one instance's irreducible set is too small for others, so
``discover``'s held-out rounds take failing instances in until a fresh batch passes.  Measured before that
loop, with three training instances (M = 6, 1 outlier, σ = 0.05, seed 0, quiet 2-core machine):
``autotight discover robust_pose_averaging --accept cost``: 45 candidate pairs, 2 pairs kept (30
constraints), 27 SDP solves, certified cost-tight on 10 of 10 held-out instances, 54 s; with one
training instance 2 pairs, 7 of 10.  The product lifting's discovery ends "undecided"
(AlmostSolved with all 944 candidates, nothing certified), 8 s.

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
from typing import Iterator

import numpy as np
import scipy.sparse as sp
from scipy.linalg import block_diag

from autotight import lie
from autotight.affine import Affine
from autotight.errors import ParameterError
from autotight.gauss_newton import block_weight, gauss_newton
from autotight.graph import Auxiliary, Binary, Euclidean, Factor, Group, Rotation, Variable, View, derive
from autotight.model import Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Meta, Param

from . import _pose_vector as pv
from ._cayley import draw_valid
from ._pose import POSE_ROLES, XI_ROLES, pose_blocks, unary_cayley, unary_residuals, xi_blocks

NAME = "robust_pose_averaging"
DESCRIPTION = "Pose averaging with outliers: TLS cost with binary w_m, lifted u_m = ½(1 + w_m)·ξ_m (paper §3.2 + TLS)."
#: the two liftings (module docstring): their per-measurement blocks' roles after h and the pose
LABEL_ROLES = {"gated": ("w", "urho", "uphi"), "product": (*XI_ROLES, "w", "zrho", "zphi")}
LIFTINGS = tuple(LABEL_ROLES)
#: the blocks a measurement factor owns (its auxiliary blocks), by lifting: u_m = ½(1 + w_m)·ξ_m, or ξ_m and
#: z_m = w_m·ξ_m
OWN = {"gated": {"urho": 3, "uphi": 3}, "product": {"rho": 3, "phi": 3, "zrho": 3, "zphi": 3}}


def pair_roles(lifting: str) -> tuple[str, ...]:
    """Roles of a consecutive pair's learning group: with the pose in the gated lifting (module docstring)."""
    pose = POSE_ROLES if lifting == "gated" else ()
    return ("h", *pose, *(f"{k}.{r}" for k in (1, 2) for r in LABEL_ROLES[lifting]))


def pair_blocks(m: int, l: int, lifting: str) -> list[str]:
    """Blocks of the pair (m, l)'s learning group after h (with the pose in the gated lifting)."""
    pose = pose_blocks() if lifting == "gated" else []
    return [*pose, *label_blocks(m, lifting), *label_blocks(l, lifting)]


PARAMS = {
    "M": Param(6, "number of pose measurements", low=1),
    "sigma": Param(0.05, "inlier noise standard deviation of each ξ_m component", low=0.0),
    "outlier_rate": Param(1 / 6, "fraction of outlier measurements (round(rate·M) of them)", low=0.0, high=1.0),
    "outlier_size": Param(1.0, "norm of an outlier's ρ and of its φ at the true pose (Cayley units)", low=0.0),
    "beta": Param(0.5, "TLS threshold on ‖ξ_m‖_W (inlier while below)", low=0.0, low_open=True),
    "scale": Param(1.0, "standard deviation of each component of the true translation", low=0.0),
    "lifting": Param("gated", "gated: u_m = ½(1 + w_m)·ξ_m (the default; a bounded relaxation); product: ξ_m and "
                     "z_m = w_m·ξ_m (its relaxation has unbounded optimal sets)", choices=LIFTINGS),
}

#: discovery learns on factors (see the module docstring).  No paper families: the report's comparison row is
#: AutoTight's published rPPR result, beside our discovered set
META = Meta(default_groups="factors",
            paper_claim={"source": "AutoTight's published robust point registration (rPPR) row, not this problem's "
                                   "paper",
                         "set": "discovered",
                         "default": "rPPR: cost-tight (relative duality gap 1.1e-6, SVR 34), 925 of 1771 learned "
                                    "constraints, 148 s"})
#: the brute-force local solver enumerates 2^M labellings: refused above this M
MAX_BRUTE_FORCE = 12

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
    """z_m = w_m ξ_m (product lifting)."""
    return [f"zrho_{m}", f"zphi_{m}"]


def u_blocks(m: int | str) -> list[str]:
    """u_m = ½(1 + w_m) ξ_m (gated lifting)."""
    return [f"urho_{m}", f"uphi_{m}"]


def w_block(m: int | str) -> str:
    return f"w_{m}"


def label_blocks(m: int, lifting: str) -> list[str]:
    """Measurement m's blocks without the pose: w_m, u_m (gated) or ξ_m, w_m, z_m (product)."""
    if lifting == "gated":
        return [w_block(m), *u_blocks(m)]
    return [*xi_blocks(str(m)), w_block(m), *z_blocks(m)]


def meas_blocks(m: int, lifting: str) -> list[str]:
    """The blocks of measurement m's factor after h: the pose C, r, then its label blocks."""
    return [*pose_blocks(), *label_blocks(m, lifting)]


def lifted_blocks(inst: Instance) -> list[str]:
    """The lifted vector after h: x = [h, c₁, c₂, c₃, r, (measurement m's label blocks)_m]."""
    lifting = lifting_of(inst)
    return [*pose_blocks(), *(b for m in range(len(inst.measurements["T_meas"])) for b in label_blocks(m, lifting))]


# ----------------------------------------------------------------------------- variables


def orth_name(equation: str, **_: object) -> str:
    """C's constraint c_iᵀc_j = δ_ij h² as saved sets name it: orth(c1,c2) for the manifold's orth(0,1)."""
    i, j = (int(k) for k in equation[len("orth("):-1].split(","))
    return f"orth(c{i + 1},c{j + 1})"


#: the pose T = [[C, r], [0ᵀ, 1]] (C as its columns c₁, c₂, c₃, its factor "rotation") and the labels w_m ∈ {±1}
#: (blocks w_m; their equation w_m² = h² is the measurement factor's)
VARIABLES = [Variable("C", Rotation(3), type="so3", block=("c1", "c2", "c3"), factor="rotation",
                      constraint_names=orth_name),
             Variable("r", Euclidean(3)),
             Variable("w", Binary(equation=False), element="{block}_{i}")]


# ----------------------------------------------------------------------------- the measurement factor


def local_columns(lifting: str) -> Variables:
    """A measurement factor's local columns: h, C, r, w_m, then its own blocks (``OWN``)."""
    return Variables([(b, 3) for b in POSE_ROLES] + [("w", 1)] + list(OWN[lifting].items()))


def _pair_form(V: Variables, a: list[str], b: list[str], W: np.ndarray) -> QuadForm:
    """uᵀ W v for u = [a₀; a₁], v = [b₀; b₁] (3-blocks), W (6, 6)."""
    qf = QuadForm(V)
    for i in range(2):
        for j in range(2):
            blk = W[3 * i:3 * i + 3, 3 * j:3 * j + 3]
            if np.any(blk):
                qf.add(a[i], b[j], blk)
    return qf


def tls_cost(W: np.ndarray, beta: float, lifting: str) -> sp.csr_array:
    """The TLS term (1 + w_m)/β² ξ_mᵀWξ_m + 1 − w_m lifted on the local columns: 2 u_mᵀW u_m/β² + h² − w_m h
    (gated), (ξ_mᵀWξ_m + ξ_mᵀW z_m)/β² + h² − w_m h (product)."""
    L = local_columns(lifting)
    if lifting == "gated":
        u = ["urho", "uphi"]
        A = 2.0 * _pair_form(L, u, u, W).matrix() / beta ** 2
    else:
        xi = ["rho", "phi"]
        A = (_pair_form(L, xi, xi, W).matrix() + _pair_form(L, xi, ["zrho", "zphi"], W).matrix()) / beta ** 2
    return sp.csr_array(A + QuadForm(L).const(1.0).add("h", "w", -1.0).matrix())


def meas_constraints(T_meas: np.ndarray, m: int, lifting: str) -> list[tuple[str, sp.coo_array]]:
    """Measurement m's primary constraints on the local columns, named as saved sets know them: the 12 Cayley
    rows of ξ_m = cay⁻¹(T T̃_m⁻¹) (gated: multiplied by ½(h + w_m), written with u_m; ``affine.cayley_rows``),
    w_m² = h², then u_m·h = u_m·w_m (gated: u_m = 0 for an outlier) or z_m·h = w_m·ξ_m (product)."""
    L, name = local_columns(lifting), f"meas_{m}"
    if lifting == "gated":
        gate = Affine({"h": np.array([[0.5]]), "w": np.array([[0.5]])})
        rows = unary_cayley(L, "", T_meas, ["urho", "uphi"], name, gate=gate)
        pairs = [("urho", "urho"), ("uphi", "uphi")]
    else:
        rows = unary_cayley(L, "", T_meas, ["rho", "phi"], name)
        pairs = [("zrho", "rho"), ("zphi", "phi")]
    out = [(c.name, c.A) for c in rows]
    out.append((f"{name}:w²=h²", QuadForm(L).add("w", "w", 1.0).const(-1.0).matrix()))
    for zb, xb in pairs:
        for k in range(3):
            e = np.zeros((1, 3))
            e[0, k] = 1.0
            A = QuadForm(L).add("h", zb, e).add("w", xb, -e).matrix()
            out.append((f"{name}:{zb}_{m}[{k}]h=w·{xb}_{m}[{k}]", A))
    return out


def own_values(xi: np.ndarray, w: float, lifting: str) -> np.ndarray:
    """Measurement m's own blocks from its residual ξ_m and label w_m: u_m = ½(1 + w_m)·ξ_m (gated) or
    [ξ_m, w_m·ξ_m] (product)."""
    if lifting == "gated":
        g = 0.5 * (1.0 + w)
        return np.concatenate([g * xi[:3], g * xi[3:]])
    return np.concatenate([xi[:3], xi[3:], w * xi[:3], w * xi[3:]])


def tls_residual(w: View, own: View, lifting: str) -> np.ndarray:
    """e_m = [(1 + w_m)·ξ_m; 1 − w_m] (2u_m, or ξ_m + z_m), so that eᵀ diag(W_m/(2β²), ½) e is the TLS term."""
    v = 2.0 * np.r_[own.urho, own.uphi] if lifting == "gated" else np.r_[own.rho + own.zrho, own.phi + own.zphi]
    return np.r_[v, 1.0 - w.x]


def factors(inst: Instance) -> Iterator[Factor | Group]:
    """Per measurement its TLS term and primary constraints, owning its lifted blocks; per pair its learning group."""
    T_meas, Ws, beta = inst.measurements["T_meas"], inst.measurements["W"], float(inst.measurements["beta"])
    lifting = lifting_of(inst)
    M = len(T_meas)
    # ξ_m = cay⁻¹(T T̃_m⁻¹)^∨ of every measurement at once (``residuals``), once per pose for all M factors
    xi = pv.last_pose(lambda C, r: unary_residuals(lie.make_pose(C, r), T_meas))
    for m in range(M):
        own = Auxiliary(OWN[lifting], value=lambda C, r, w, m=m: own_values(xi(C.x, r.x)[m], float(w.x), lifting))
        weight = block_diag(Ws[m] / (2 * beta ** 2), 0.5)
        yield Factor(("C", "r", w_block(m)), lambda C, r, w, own: tls_residual(w, own, lifting), type="robust_meas",
                     weight=weight, cost=tls_cost(Ws[m], beta, lifting),
                     constraints=meas_constraints(T_meas[m], m, lifting), constraint_names="{constraint}",
                     auxiliary=own, name=f"meas_{m}")
    for m, l in pairs_of(M, lifting):
        yield Group(pair_blocks(m, l, lifting), "robust_pair", roles=pair_roles(lifting)[1:], name=f"pair_{m}_{l}")


_parts = derive(VARIABLES, factors, blocks=lifted_blocks)


def build(inst: Instance) -> Model:
    """The layer's model with the module's clique cover (``cliques``)."""
    model = _parts.build(inst)
    model.cliques = cliques(len(inst.measurements["T_meas"]), lifting_of(inst))
    return model


def pairs_of(M: int, lifting: str) -> list[tuple[int, int]]:
    """The measurement pairs (m, l) with a learning group: every pair (gated), consecutive ones (product)."""
    if lifting == "gated":
        return list(itertools.combinations(range(M), 2))
    return [(m, m + 1) for m in range(M - 1)]


def cliques(M: int, lifting: str = "gated") -> list[tuple[str, ...]] | None:
    """Product lifting: {h, C, r, measurement m's label blocks, m+1's} for m = 0 … M−2 (a path: the
    intersection of cliques m and m+2, {h, C, r}, lies in clique m+1); {h, C, r, measurement 0's} when
    M = 1.  Gated lifting: None (its pairs couple every measurement with every other: one clique)."""
    if lifting == "gated":
        return None
    if M == 1:
        return [("h", *meas_blocks(0, lifting))]
    return [("h", *meas_blocks(m, lifting), *label_blocks(m + 1, lifting)) for m in range(M - 1)]


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


def lifting_of(inst: Instance) -> str:
    return inst.params.get("lifting", "gated")


def lift(inst: Instance, state: dict) -> np.ndarray:
    """The layer's lift with the labels checked (M entries ±1; absent: every measurement an inlier), as (1, n)."""
    return _parts.lift(inst, state | {"w": _labels(inst, state)})[None, :]


def recover(inst: Instance, Theta: np.ndarray) -> dict:
    """The layer's recover: T from the rank-1 factor x (raw rotation projected to SO(3), its det reported) and
    w_m = sign(x_w) (+1 at 0)."""
    return _parts.recover(inst, Theta)


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
    Tm = np.asarray(inst.measurements["T_meas"])[idx]
    xi, J = lie.residuals_se3(np.broadcast_to(T, Tm.shape), Tm)
    return xi.ravel(), J.reshape(-1, 6), block_weight(2.0 / beta ** 2 * np.asarray(inst.measurements["W"])[idx])


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


def errors(inst: Instance, state: dict) -> dict:
    """Rotation error (deg), translation error, and labels that differ from the generated ones."""
    out = {"rotation_deg": lie.rotation_error_deg(state["C"], inst.truth["C"]),
           "translation": float(np.linalg.norm(state["r"] - inst.truth["r"]))}
    if "w" in state:
        out["labels_wrong"] = float(np.sum(np.asarray(state["w"]) != inst.truth["w"]))
    return out
