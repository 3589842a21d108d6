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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from autotight import lie
from autotight.errors import ParameterError, ProblemDefinitionError
from autotight.gauss_newton import gauss_newton
from autotight.model import HOMOGENISING as H, Constraint, Factor, Model, QuadForm, Variables
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

    def theta(self, V: Variables, values: dict[str, np.ndarray]) -> np.ndarray:
        """Θ (d, N) from block values (d, cols) (h is filled in)."""
        vals = {n: v for n, v in values.items() if n != H}
        if self.kind == "vector":
            vals = {n: np.asarray(v, float).reshape(self.dim, -1).ravel(order="F") for n, v in vals.items()}
        return V.assemble(vals)

    def block(self, V: Variables, Theta: np.ndarray, name: str) -> np.ndarray:
        """The (dim, cols) value of a block in a lifted point Θ."""
        T = np.atleast_2d(Theta)
        if self.kind == "matrix":
            return T[:, V.slice(name)]
        return T[0, V.slice(name)].reshape(self.dim, -1, order="F")


def normalise_theta(Theta: np.ndarray, d: int) -> np.ndarray:
    """Θ ← Θ_h⁻¹ Θ so that its h block is I_d (a rank-d factor is defined up to a left factor)."""
    T = np.atleast_2d(np.asarray(Theta, dtype=float))
    return np.linalg.solve(T[:, :d], T)


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

    def cost_matrix(self, lifting: Lifting, V: Variables) -> sp.csr_array:
        """Q with ⟨Q, ΘᵀΘ⟩ = ‖E‖_F² (constants on the h block)."""
        qf = QuadForm(V)
        for a, Ma in self.residual:
            for b, Mb in self.residual:
                lifting.add(qf, a, b, Ma @ Mb.T)
        return qf.matrix()

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


def prior_term(name: str, C: str, r: str, C_prior: np.ndarray, r_prior: np.ndarray) -> Term:
    """Prior (D, eq. 56) on a pose: ‖C − Č‖_F² + ‖r − ř‖²;  E = [C − Č, r − ř]."""
    d = len(r_prior)
    return Term(name, "prior", (C, r), ("C", "r"),
                [(C, np.eye(d, d + 1)), (r, np.eye(1, d + 1, d)),
                 (H, -np.hstack([np.asarray(C_prior, float), _col(r_prior)]))])


def orthonormality(lifting: Lifting, V: Variables, C: str, factor: str) -> list[Constraint]:
    """c_iᵀ c_j = δ_ij (i ≤ j): the (C, C) block of X equals I_d."""
    d, out = lifting.dim, []
    for i in range(d):
        for j in range(i, d):
            qf = QuadForm(V)
            lifting.add(qf, C, C, np.outer(np.eye(d)[i], np.eye(d)[j]))
            if i == j:
                lifting.add(qf, H, H, -np.eye(d) / d)
            out.append(Constraint(qf.matrix(), 0.0, name=f"orth({C}:{i},{j})", factor=factor))
    return out


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


class PoseLandmarkGraph:
    """K poses, L unknown landmarks and their terms; builds the Model and solves locally.

    A state is {"C": (K, d, d), "r": (K, d)} plus "l": (L, d) when L > 0.
    The local perturbation is [ψ_0, δr_0, …, ψ_{K−1}, δr_{K−1}, δℓ_0, …] with C ← exp(ψ^∧) C.
    """

    def __init__(self, lifting: Lifting, n_poses: int, n_landmarks: int = 0):
        self.lifting, self.K, self.L, self.dim = lifting, int(n_poses), int(n_landmarks), lifting.dim
        self.terms: list[Term] = []
        blocks = [(b, c) for k in range(self.K) for b, c in zip(pose_blocks(k), (self.dim, 1))]
        self.V = lifting.variables(blocks + [(landmark_block(j), 1) for j in range(self.L)])

    def pose(self, k: int, what: str = "measurement") -> tuple[str, str]:
        """Block names (C_k, r_k); a clear error for a pose that does not exist."""
        if not 0 <= int(k) < self.K:
            raise ProblemDefinitionError(f"{what} on pose {k}, but there are only {self.K} poses (0…{self.K - 1})")
        return pose_blocks(int(k))

    def landmark(self, j: int) -> str:
        """Block name of unknown landmark j; a clear error when it does not exist."""
        return landmark_block(check_landmark(j, self.L))

    def add(self, term: Term) -> None:
        """Add a term after checking its data have dimension d (e.g. no 2D measurement in 3D)."""
        for b, M in term.residual:
            rows = self.dim if b == H or b.startswith("C") else 1
            if M.shape != (rows, term.residual[0][1].shape[1]):
                raise ProblemDefinitionError(f"term {term.name}: its data do not fit d = {self.dim} "
                                             f"(coefficient of {b} has shape {M.shape})")
        self.terms.append(term)

    # --- the QCQP
    def model(self) -> Model:
        factors = []
        for k in range(self.K):
            C, _ = pose_blocks(k)
            factors.append(Factor(f"pose_{k}", "pose", (H, C), roles=(H, "C"),
                                  constraints=orthonormality(self.lifting, self.V, C, f"pose_{k}")))
        for t in self.terms:
            factors.append(Factor(t.name, t.type, (H, *t.blocks), cost=t.cost_matrix(self.lifting, self.V),
                                  roles=(H, *t.roles)))
        return Model(self.V, factors, paper={})

    # --- states
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

    def lift(self, state: dict) -> np.ndarray:
        return self.lifting.theta(self.V, self.values(state))

    def recover(self, Theta: np.ndarray) -> dict:
        """State from a rank-d factor; rotations projected to SO(d), raw dets in "det_raw"."""
        T = normalise_theta(Theta, self.lifting.d)
        get = lambda n: self.lifting.block(self.V, T, n)  # noqa: E731
        C_raw = np.array([get(pose_blocks(k)[0]) for k in range(self.K)])
        out = {"C": np.array([project_rotation(c) for c in C_raw]),
               "r": np.array([get(pose_blocks(k)[1])[:, 0] for k in range(self.K)]),
               "det_raw": np.array([np.linalg.det(c) for c in C_raw])}
        if self.L:
            out["l"] = np.array([get(landmark_block(j))[:, 0] for j in range(self.L)])
        return out

    def cost(self, state: dict) -> float:
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


def sample_state(rng: np.random.Generator, nominal: dict, spread: float) -> dict:
    """C_k = exp(spread·ν^∧) C̄_k, r_k = r̄_k + spread·n, ℓ_j = ℓ̄_j + spread·n (ν, n ~ N(0, I))."""
    C = np.asarray(nominal["C"], float)
    K, d = C.shape[:2]
    out = {"C": np.array([exp_rot(spread * rng.standard_normal(rot_dof(d)), d) @ c for c in C]),
           "r": np.asarray(nominal["r"], float) + spread * rng.standard_normal((K, d))}
    if "l" in nominal:
        ls = np.asarray(nominal["l"], float)
        out["l"] = ls + spread * rng.standard_normal(ls.shape)
    return out


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


def graph_problem(graph: Callable[[Instance], "PoseLandmarkGraph"], extent_param: str) -> tuple[Callable, ...]:
    """The parts of a pose-landmark problem module that only delegate to its graph:
    (build, lift, cost, sample, random_state, local_solve, recover, errors).
    ``extent_param`` names the parameter that scales random starts."""

    def build(inst: Instance) -> Model:
        return graph(inst).model()

    def lift(inst: Instance, state: dict) -> np.ndarray:
        return graph(inst).lift(state)

    def cost(inst: Instance, state: dict) -> float:
        return graph(inst).cost(state)

    def sample(inst: Instance, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
        return sample_state(rng, nominal, spread)

    def random_start(inst: Instance, rng: np.random.Generator) -> dict:
        return random_state(rng, inst.truth, inst.params[extent_param])

    def local_solve(inst: Instance, init: dict, max_iter: int = 200) -> LocalResult:
        return graph(inst).local_solve(init, max_iter)

    def recover(inst: Instance, Theta: np.ndarray) -> dict:
        return graph(inst).recover(Theta)

    def errors(inst: Instance, state: dict) -> dict:
        return state_errors(state, inst.truth)

    return build, lift, cost, sample, random_start, local_solve, recover, errors
