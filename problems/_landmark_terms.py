"""Measurement terms of the lifting appendix (Korotkine, Cohen, Forbes, arXiv 2504.08547, App. A–D).

Poses (C_k, r_k) and landmarks ℓ_j in d = 2 or 3 dimensions, lifted in one of two ways:

- ``matrix``: Θ = [I_d, C_0, r_0, …, ℓ_0, …] (d×N), X = ΘᵀΘ; blocks C_k have d columns, r_k and
  ℓ_j one.  Only dot products of columns of Θ are expressible (so CᵀC = I, not det C = 1).
- ``vector``: x = [1, vec C_0, r_0, …, ℓ_0, …] (N,), X = xxᵀ, vec stacks columns.

Every term is a residual linear in the blocks, E = Σ_b Θ_b M_b (d×p), with Θ_h = I_d carrying the
data, and costs ‖E‖_F² = Σ_ab ⟨M_a M_bᵀ, Θ_aᵀ Θ_b⟩.  All quadratic forms here are written once in
this *Gram form* (coefficients of the column dot products θ_{a,i}·θ_{b,j}) and translated to the
lifting by ``Lifting.add``: in the vector lifting θ_{b,j} = x_b[jd:(j+1)d] and θ_{h,i} = e_i·h.
The same residuals give the direct cost and the Gauss-Newton Jacobians of the local solver.

The problem modules (landmark_localization, landmark_slam, pose_graph) are written on the factor-graph layer:
``pose_variables`` declares C_k ∈ SO(d) (type "pose", constraints ``orth(C_k:i,j)``), r_k and ℓ_j; ``factor``
makes a term a model factor of its own with its Gram-form cost declared; ``width`` and ``block_order`` fix the
lifting (Θ of width d, or x) and its blocks [C_0, r_0, …, ℓ_0, …].  What the layer would not give to the bit stays
here: the terms' costs (``Term.cost_matrix``), the direct cost and the pose-by-pose Gauss-Newton (``PoseTerms``),
``random_state``, ``state_errors``, and ``pose_state`` (``recover``'s entries in the order C, r, det_raw, l).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.errors import ParameterError, ProblemDefinitionError
from autotight.gauss_newton import gauss_newton
from autotight.graph import Euclidean, Rotation, Variable, View, derive
from autotight.graph import Factor as GraphFactor
from autotight.model import HOMOGENISING as H, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Param

LIFTINGS = ("matrix", "vector")
Residual = list[tuple[str, np.ndarray]]  # [(block, M_b)]: E = Σ_b Θ_b M_b


def common_params(dim: int = 3) -> dict[str, Param]:
    return {
        "dim": Param(dim, "dimension d of the poses: 2 or 3"),
        "lifting": Param("matrix", "'matrix' (Θ = [I C r ℓ], rank d) or 'vector' (x = [1 vec C r ℓ], rank 1)",
                         choices=LIFTINGS),
    }


def check_dim(dim: int) -> int:
    if dim not in (2, 3):
        raise ParameterError(f"dim must be 2 or 3, got {dim!r}")
    return int(dim)


# ----------------------------------------------------------------------------- rotations in d = 2, 3


def rot_dof(d: int) -> int:
    """Degrees of freedom of SO(d): 1 or 3."""
    return 1 if d == 2 else 3


def exp_rot(psi: np.ndarray, d: int) -> np.ndarray:
    """(dof,) → (d, d) rotation exp(ψ^∧); in 2D the rotation by angle ψ₀."""
    psi = np.asarray(psi, dtype=float).reshape(-1)
    if d == 2:
        c, s = np.cos(psi[0]), np.sin(psi[0])
        return np.array([[c, -s], [s, c]])
    return lie.exp_so3(psi)


def rot_jacobian(w: np.ndarray, d: int) -> np.ndarray:
    """(d,) → (d, dof): ∂/∂ψ exp(ψ^∧) w at ψ = 0 (left perturbation)."""
    if d == 2:
        return np.array([[-w[1]], [w[0]]])
    return -lie.hat(w)


def random_rotation(rng: np.random.Generator, d: int) -> np.ndarray:
    """Uniformly distributed rotation in SO(d)."""
    return exp_rot([rng.uniform(-np.pi, np.pi)], 2) if d == 2 else lie.random_rotation(rng)


def project_rotation(M: np.ndarray) -> np.ndarray:
    """Nearest (Frobenius) rotation to a d×d matrix, det +1."""
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[0])
    D[-1] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return (U * D) @ Vt


# ----------------------------------------------------------------------------- liftings


@dataclass(frozen=True)
class Lifting:
    """How block columns become the lifted variable (see module docstring)."""

    kind: str
    dim: int

    def __post_init__(self) -> None:
        check_dim(self.dim)
        if self.kind not in LIFTINGS:
            raise ParameterError(f"lifting must be one of {list(LIFTINGS)}, got {self.kind!r}")

    @property
    def d(self) -> int:
        """Width of Θ: dim for the matrix lifting, 1 for the vector lifting."""
        return self.dim if self.kind == "matrix" else 1

    def variables(self, blocks: list[tuple[str, int]]) -> Variables:
        """Blocks given as (name, number of d-vector columns)."""
        k = 1 if self.kind == "matrix" else self.dim
        return Variables([(n, k * c) for n, c in blocks], d=self.d)

    def add(self, qf: QuadForm, a: str, b: str, M: np.ndarray) -> QuadForm:
        """Add Σ_ij M_ij θ_{a,i}·θ_{b,j} (Gram form; θ_{h,i} = e_i, M is cols_a × cols_b)."""
        M = np.atleast_2d(np.asarray(M, dtype=float))
        if self.kind == "matrix":
            return qf.add(a, b, M)
        if a == H and b == H:
            return qf.add(H, H, np.trace(M))
        if a == H:
            return qf.add(H, b, M.ravel(order="F")[None, :])
        if b == H:
            return qf.add(a, H, M.ravel(order="C")[:, None])
        return qf.add(a, b, np.kron(M, np.eye(self.dim)))


# ----------------------------------------------------------------------------- terms


@dataclass
class Term:
    """One measurement term: E = Σ_b Θ_b M_b (d×p), cost ‖E‖_F².

    type: factor type (the learning group); roles: names of ``blocks`` within the type.
    """

    name: str
    type: str
    blocks: tuple[str, ...]
    roles: tuple[str, ...]
    residual: Residual

    def cost_matrix(self, lifting: Lifting) -> sp.coo_array:
        """The lifted cost on the term's local columns [h, its blocks] (``autotight.graph.Factor(cost=…)``):
        ⟨Q, ΘᵀΘ⟩ = ‖E‖_F², each Gram-form product M_a M_bᵀ translated by ``Lifting.add`` (constants on h)."""
        d = self.dim
        qf = QuadForm(lifting.variables([(b, d if b.startswith("C") else 1) for b in self.blocks]))
        for a, Ma in self.residual:
            for b, Mb in self.residual:
                lifting.add(qf, a, b, Ma @ Mb.T)
        return qf.matrix()

    @property
    def dim(self) -> int:
        """d: the rows of a rotation block's coefficient (every term has one)."""
        return next(int(M.shape[0]) for b, M in self.residual if b.startswith("C"))

    def evaluate(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """E (d×p) from block values (d, cols); values[h] = I_d."""
        return sum(np.asarray(values[b], float).reshape(len(values[H]), -1) @ M for b, M in self.residual)


def _col(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, dtype=float).reshape(-1, 1)


def landmark_term(name: str, C: str, r: str, l: str, y: np.ndarray) -> Term:
    """Pose to unknown landmark (A, eq. 20): ‖(ℓ − r) − C y‖², y measured in the body frame."""
    return Term(name, "landmark", (C, r, l), ("C", "r", "l"),
                [(l, np.ones((1, 1))), (r, -np.ones((1, 1))), (C, -_col(y))])


def known_landmark_term(name: str, C: str, r: str, ell: np.ndarray, y: np.ndarray) -> Term:
    """Pose to known landmark (B, eq. 28): ‖(ℓ − r) − C y‖² with ℓ data."""
    return Term(name, "known_landmark", (C, r), ("C", "r"), [(H, _col(ell)), (r, -np.ones((1, 1))), (C, -_col(y))])


def relative_pose_term(name: str, Ci: str, ri: str, Cj: str, rj: str, dC: np.ndarray, dr: np.ndarray) -> Term:
    """Relative pose T_j = T_i ΔT (C, eqs. 39, 46): J_r + J_c = ‖r_j − r_i − C_i Δr‖² + ‖C_j − C_i ΔC‖_F².

    E = [r_j − r_i − C_i Δr, C_j − C_i ΔC]  (d × (1 + d)).
    """
    dC, d = np.asarray(dC, float), len(dr)
    e0, rest = np.eye(1, d + 1), np.eye(d + 1)[1:]  # (1, d+1) and (d, d+1) column selectors
    return Term(name, "relative_pose", (Ci, ri, Cj, rj), ("C_i", "r_i", "C_j", "r_j"),
                [(rj, e0), (ri, -e0), (Ci, -np.hstack([_col(dr), dC])), (Cj, rest)])


def relative_terms(stem: str, pairs: Iterable[tuple], K: int, d: int, what: str) -> list[Term]:
    """One relative-pose term "{stem}_n" per (i, j, ΔC, Δr) of ``pairs``: ‖r_j − r_i − C_i Δr‖² + ‖C_j − C_i ΔC‖_F²
    (``relative_pose_term``), its poses checked against the K poses and its data against d (``what`` names the
    measurement in an error)."""
    out = []
    for n, (i, j, dC, dr) in enumerate(pairs):
        Ci, ri = check_pose(i, K, what)
        Cj, rj = check_pose(j, K, what)
        out.append(check_term(relative_pose_term(f"{stem}_{n}", Ci, ri, Cj, rj, dC, dr), d))
    return out


def prior_term(name: str, C: str, r: str, C_prior: np.ndarray, r_prior: np.ndarray) -> Term:
    """Prior (D, eq. 56) on a pose: ‖C − Č‖_F² + ‖r − ř‖²;  E = [C − Č, r − ř]."""
    d = len(r_prior)
    return Term(name, "prior", (C, r), ("C", "r"),
                [(C, np.eye(d, d + 1)), (r, np.eye(1, d + 1, d)),
                 (H, -np.hstack([np.asarray(C_prior, float), _col(r_prior)]))])


# ----------------------------------------------------------------------------- a graph of terms


def check_landmark(j: int, n: int) -> int:
    """j itself if 0 ≤ j < n, else a clear error (a landmark index out of range)."""
    if not 0 <= int(j) < n:
        raise ProblemDefinitionError(f"measurement refers to landmark {j}, but there are only {n} landmarks "
                                     f"(0…{n - 1})")
    return int(j)


def pose_blocks(k: int) -> tuple[str, str]:
    return f"C{k}", f"r{k}"


def landmark_block(j: int) -> str:
    return f"l{j}"


def check_term(term: Term, d: int) -> Term:
    """The term after checking its data have dimension d (e.g. no 2D measurement in 3D)."""
    for b, M in term.residual:
        rows = d if b == H or b.startswith("C") else 1
        if M.shape != (rows, term.residual[0][1].shape[1]):
            raise ProblemDefinitionError(f"term {term.name}: its data do not fit d = {d} "
                                         f"(coefficient of {b} has shape {M.shape})")
    return term


def check_pose(k: int, K: int, what: str = "measurement") -> tuple[str, str]:
    """Block names (C_k, r_k); a clear error for a pose that does not exist."""
    if not 0 <= int(k) < K:
        raise ProblemDefinitionError(f"{what} on pose {k}, but there are only {K} poses (0…{K - 1})")
    return pose_blocks(int(k))


def block_order(K: int, L: int = 0) -> list[str]:
    """The lifted blocks after h: C_0, r_0, …, C_{K−1}, r_{K−1}, ℓ_0, …, ℓ_{L−1}."""
    return [b for k in range(K) for b in pose_blocks(k)] + [landmark_block(j) for j in range(L)]


@dataclass
class PoseTerms:
    """The terms of K poses and L unknown landmarks at states, for the module's cost and Gauss-Newton.

    A state is {"C": (K, d, d), "r": (K, d)} plus "l": (L, d) when L > 0.
    The local perturbation is [ψ_0, δr_0, …, ψ_{K−1}, δr_{K−1}, δℓ_0, …] with C ← exp(ψ^∧) C.
    """

    terms: list[Term]
    K: int
    L: int
    dim: int

    def values(self, state: dict) -> dict[str, np.ndarray]:
        C, r = np.asarray(state["C"], float), np.asarray(state["r"], float)
        if C.shape != (self.K, self.dim, self.dim) or r.shape != (self.K, self.dim):
            raise ProblemDefinitionError(f"state has C {C.shape}, r {r.shape}; expected "
                                         f"{(self.K, self.dim, self.dim)}, {(self.K, self.dim)}")
        vals = {H: np.eye(self.dim)}
        for k in range(self.K):
            vals |= dict(zip(pose_blocks(k), (C[k], r[k][:, None])))
        if self.L:
            ls = np.asarray(state["l"], float).reshape(self.L, self.dim)
            vals |= {landmark_block(j): ls[j][:, None] for j in range(self.L)}
        return vals

    def cost(self, state: dict) -> float:
        """Σ ‖E‖_F² over the terms."""
        vals = self.values(state)
        return float(sum(np.sum(t.evaluate(vals) ** 2) for t in self.terms))

    # --- local solver
    def _offset(self, block: str) -> tuple[int, bool]:
        """Offset of a block's perturbation and whether it is a rotation."""
        dof, d = rot_dof(self.dim), self.dim
        kind, idx = block[0], int(block[1:])
        if kind == "l":
            return self.K * (dof + d) + idx * d, False
        return idx * (dof + d) + (0 if kind == "C" else dof), kind == "C"

    def linearize(self, state: dict) -> tuple[np.ndarray, np.ndarray, sp.dia_array]:
        """Stacked vec(E) of all terms, its Jacobian w.r.t. the perturbation, and W = I."""
        vals, d, dof = self.values(state), self.dim, rot_dof(self.dim)
        n = self.K * (dof + d) + self.L * d
        es, Js = [], []
        for t in self.terms:
            E = t.evaluate(vals)
            J = np.zeros((E.size, n))
            for b, M in t.residual:
                if b == H:
                    continue
                o, is_rot = self._offset(b)
                if is_rot:
                    W = vals[b] @ M
                    J[:, o:o + dof] += np.vstack([rot_jacobian(W[:, c], d) for c in range(W.shape[1])])
                else:
                    J[:, o:o + d] += np.kron(M.T, np.eye(d))
            es.append(E.ravel(order="F"))
            Js.append(J)
        e = np.concatenate(es)
        return e, np.vstack(Js), sp.eye_array(e.size, format="dia")

    def retract(self, state: dict, eps: np.ndarray) -> dict:
        d, dof = self.dim, rot_dof(self.dim)
        C, r = np.array(state["C"], float), np.array(state["r"], float)
        for k in range(self.K):
            o = k * (dof + d)
            C[k] = exp_rot(eps[o:o + dof], d) @ C[k]
            r[k] = r[k] + eps[o + dof:o + dof + d]
        out = {"C": C, "r": r}
        if self.L:
            out["l"] = np.asarray(state["l"], float) + eps[self.K * (dof + d):].reshape(self.L, d)
        return out

    def local_solve(self, init: dict, max_iter: int = 200) -> LocalResult:
        """Gauss-Newton (LM-damped) on SO(d)^K × R^…, from ``init``."""
        start = {k: np.asarray(v, float) for k, v in init.items() if k in ("C", "r", "l")}
        return gauss_newton(self.linearize, self.retract, start, max_iter=max_iter)


# ----------------------------------------------------------------------------- states near and far


def random_state(rng: np.random.Generator, truth: dict, scale: float) -> dict:
    """Uniform rotations; positions ~ N(0, scale²) (shapes as in ``truth``)."""
    C = np.asarray(truth["C"])
    K, d = C.shape[:2]
    out = {"C": np.array([random_rotation(rng, d) for _ in range(K)]), "r": scale * rng.standard_normal((K, d))}
    if "l" in truth:
        out["l"] = scale * rng.standard_normal(np.asarray(truth["l"]).shape)
    return out


def state_errors(state: dict, truth: dict) -> dict[str, float]:
    """Largest rotation error (deg), RMS position error, RMS landmark error (when present)."""
    C, Ct = np.asarray(state["C"]), np.asarray(truth["C"])
    out = {"rotation_deg": lie.rotation_error_deg(C, Ct),
           "position": float(np.sqrt(np.mean(np.sum((np.asarray(state["r"]) - truth["r"]) ** 2, axis=1))))}
    if "l" in truth:
        out["landmark"] = float(np.sqrt(np.mean(np.sum((np.asarray(state["l"]) - truth["l"]) ** 2, axis=1))))
    return out


def noisy_rotation(rng: np.random.Generator, C: np.ndarray, sigma: float) -> np.ndarray:
    """exp(σν^∧) C with ν ~ N(0, I)."""
    d = C.shape[0]
    return exp_rot(sigma * rng.standard_normal(rot_dof(d)), d) @ C


# ----------------------------------------------------------------------------- on the factor-graph layer


def _orth_name(variable: str, equation: str, **_: object) -> str:
    """orth(C3:0,1): the model names of pose 3's orthonormality c_0ᵀc_1 = 0, as the saved sets carry them."""
    return f"orth({variable}:{equation[len('orth('):]}"


def pose_variables(d: int, n_landmarks: int = 0) -> list[Variable]:
    """C_k ∈ SO(d) (its own factor "pose_k": c_iᵀc_j = δ_ij), r_k ∈ R^d and, when there are landmarks, ℓ_j ∈ R^d."""
    out = [Variable("C", Rotation(d), type="pose", constraint_names=_orth_name), Variable("r", Euclidean(d))]
    return out + ([Variable("l", Euclidean(d))] if n_landmarks else [])


def factor(term: Term, lifting: Lifting) -> GraphFactor:
    """The term as a model factor of its own (name, type, roles of the term): residual vec E, and its lifted cost
    declared in the Gram form (``Term.cost_matrix``; the layer's Mᵀ M of the read-off residual sums the same
    products in another order, and in the matrix lifting it derives none)."""
    d = term.dim

    def residual(*views: View) -> np.ndarray:
        vals = {H: np.eye(d)} | {b: np.asarray(v.x, float).reshape(d, -1) for b, v in zip(term.blocks, views)}
        return term.evaluate(vals).ravel(order="F")

    return GraphFactor(term.blocks, residual, type=term.type, cost=term.cost_matrix(lifting), name=term.name, own=True,
                       roles=term.roles)


def lifting_of(inst: Instance) -> Lifting:
    return Lifting(inst.params["lifting"], check_dim(inst.params["dim"]))


def width(inst: Instance) -> int:
    """The lifted matrix's width: d for the matrix lifting Θ = [I_d, C_0, r_0, …], 1 for x = [1, vec C_0, r_0, …]."""
    return lifting_of(inst).d


def pose_state(state: dict) -> dict:
    """A state's entries in the order C, r, det_raw, l (the layer's ``recover`` puts det_raw last)."""
    return {k: state[k] for k in ("C", "r", "det_raw", "l") if k in state}


def module_parts(terms: Callable[[Instance], list[Term]], variables: Callable[[Instance], list[Variable]],
                 counts: Callable[[Instance], tuple[int, int]], spread: str) -> tuple[Callable, ...]:
    """(build, lift, cost, sample, local_solve, recover, random_state, errors) of a module of pose (and landmark)
    terms: ``terms(inst)`` its terms, each a factor of its own with its lifted cost in the instance's lifting;
    ``variables(inst)`` its variables; ``counts(inst) -> (K, L)`` its poses and landmarks, the lifted blocks
    [C_0, r_0, …, ℓ_0, …] in that order (``block_order``); ``spread``, the parameter that scales the random
    starts.  The layer derives the model, lift, sample and recover (Θ of width d or x, ``width``); the cost and
    the Gauss-Newton solver are the terms' own (``PoseTerms``)."""

    def factors(inst: Instance) -> list[GraphFactor]:
        lifting = lifting_of(inst)
        return [factor(t, lifting) for t in terms(inst)]

    build, lift, _, sample, _, derived_recover = derive(variables, factors, width=width,
                                                        blocks=lambda inst: block_order(*counts(inst)))

    def pose_terms(inst: Instance) -> PoseTerms:
        return PoseTerms(terms(inst), *counts(inst), check_dim(inst.params["dim"]))

    def cost(inst: Instance, state: dict) -> float:
        return pose_terms(inst).cost(state)

    def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
        return pose_terms(inst).local_solve(init, max_iter)

    def recover(inst: Instance, Theta: np.ndarray) -> dict:
        return pose_state(derived_recover(inst, Theta))

    def start(inst: Instance, rng: np.random.Generator) -> dict:
        return random_state(rng, inst.truth, inst.params[spread])

    def errors(inst: Instance, state: dict) -> dict:
        return state_errors(state, inst.truth)

    return build, lift, cost, sample, local_solve, recover, start, errors
