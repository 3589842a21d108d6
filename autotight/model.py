"""A problem as a factor graph over a lifted variable.

The lifted variable is Θ = [h, x₁, x₂, …] of width d: a vector x (d = 1, h a scalar with
h² = 1) or a matrix Θ (d = 2, 3, h = I_d).  Each named block is a set of N_b columns of Θ;
the SDP variable is X = ΘᵀΘ (N×N).  Every quadratic form is a sparse symmetric N×N
matrix A, meaning ⟨A, X⟩ = Σ_ab tr(Θ_a A_ab Θ_bᵀ) (for d = 1: xᵀAx).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import ProblemDefinitionError

HOMOGENISING = "h"


class Variables:
    """Ordered named blocks of the lifted variable; the first block is h of size d."""

    def __init__(self, blocks: Sequence[tuple[str, int]], d: int = 1):
        if d not in (1, 2, 3):
            raise ProblemDefinitionError(f"lifting width d must be 1, 2 or 3, got {d}")
        self.d = d
        names = [HOMOGENISING] + [str(n) for n, _ in blocks]
        sizes = [d] + [int(s) for _, s in blocks]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ProblemDefinitionError(f"duplicate block names: {dup} ('h' is reserved)")
        if any(s < 1 for s in sizes):
            raise ProblemDefinitionError(f"every block needs a positive size: {dict(zip(names, sizes))}")
        self.names: list[str] = names
        self.sizes: dict[str, int] = dict(zip(names, sizes))
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.offsets: dict[str, int] = {n: int(o) for n, o in zip(names, offsets[:-1])}
        self.N = int(offsets[-1])

    def __contains__(self, name: str) -> bool:
        return name in self.sizes

    def __repr__(self) -> str:
        return f"Variables(d={self.d}, N={self.N}, blocks={[(n, self.sizes[n]) for n in self.names]})"

    def slice(self, name: str) -> slice:
        self._check(name)
        o = self.offsets[name]
        return slice(o, o + self.sizes[name])

    def index(self, names: Iterable[str]) -> np.ndarray:
        """Column indices of the given blocks, in the given order."""
        return np.concatenate([np.arange(self.slice(n).start, self.slice(n).stop) for n in names])

    def block_of(self, column: int) -> tuple[str, int]:
        """(block name, position inside the block) of a column of Θ."""
        for n in self.names:
            o = self.offsets[n]
            if o <= column < o + self.sizes[n]:
                return n, column - o
        raise IndexError(column)

    def _check(self, name: str) -> None:
        if name not in self.sizes:
            raise ProblemDefinitionError(f"unknown block {name!r}; blocks are {self.names}")

    def assemble(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Θ (d×N) from block values (each (d, N_b), or (N_b,) when d = 1); h is filled in."""
        Theta = np.zeros((self.d, self.N))
        Theta[:, self.slice(HOMOGENISING)] = np.eye(self.d)
        missing = [n for n in self.names[1:] if n not in values]
        if missing:
            raise ProblemDefinitionError(f"lift is missing blocks {missing}")
        for n in self.names[1:]:
            v = np.asarray(values[n], dtype=float)
            v = v.reshape(self.d, -1) if self.d > 1 or v.ndim == 2 else v[None, :]
            if v.shape != (self.d, self.sizes[n]):
                raise ProblemDefinitionError(
                    f"block {n!r} has shape {v.shape}, expected {(self.d, self.sizes[n])}")
            Theta[:, self.slice(n)] = v
        return Theta


class QuadForm:
    """Builds a sparse symmetric N×N matrix by block name.

    ``add(a, b, M)`` adds Σ_ij M_ij θ_{a,i}ᵀ θ_{b,j}  (for d = 1: x_aᵀ M x_b);
    ``linear(b, v)`` adds vᵀ x_b · h (d = 1) and ``const(c)`` adds c (= c h² for d = 1).
    """

    def __init__(self, variables: Variables):
        self.v = variables
        self._rows: list[np.ndarray] = []
        self._cols: list[np.ndarray] = []
        self._vals: list[np.ndarray] = []

    def add(self, a: str, b: str, M: np.ndarray | float) -> "QuadForm":
        sa, sb = self.v.slice(a), self.v.slice(b)
        na, nb = sa.stop - sa.start, sb.stop - sb.start
        M = np.asarray(M, dtype=float)
        if M.ndim == 0:
            if na != nb:
                raise ProblemDefinitionError(f"scalar coefficient between blocks of sizes {na}, {nb}")
            M = M * np.eye(na)
        if M.ndim == 1 and (na == 1 or nb == 1):
            M = M.reshape(na, nb)
        if M.shape != (na, nb):
            raise ProblemDefinitionError(f"coefficient for ({a}, {b}) has shape {M.shape}, expected {(na, nb)}")
        r, c = np.nonzero(M)
        vals = M[r, c] / 2.0
        r, c = r + sa.start, c + sb.start
        self._rows += [r, c]
        self._cols += [c, r]
        self._vals += [vals, vals]
        return self

    def linear(self, b: str, v: np.ndarray) -> "QuadForm":
        if self.v.d != 1:
            raise ProblemDefinitionError("linear() is for vector liftings; use add('h', block, M) for d > 1")
        return self.add(HOMOGENISING, b, np.asarray(v, dtype=float).reshape(1, -1))

    def const(self, c: float) -> "QuadForm":
        return self.add(HOMOGENISING, HOMOGENISING, (float(c) / self.v.d) * np.eye(self.v.d))

    def matrix(self) -> sp.coo_array:
        """The form as a canonical COO array (see ``coo``)."""
        return self.coo()

    def coo(self) -> sp.coo_array:
        """The form as a canonical COO array: storage proportional to its nonzeros (no n + 1 index array)."""
        N = self.v.N
        if not self._vals:
            return sp.coo_array((N, N))
        return canonical_coo(np.concatenate(self._rows), np.concatenate(self._cols), np.concatenate(self._vals), N)


def canonical_coo(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, N: int) -> sp.coo_array:
    """An N×N COO array with duplicates summed and zeros dropped, sorted by (row, col), in O(nnz log nnz)
    time and O(nnz) memory (no CSR index array of length N + 1)."""
    rows, cols, vals = (np.asarray(rows, np.int64), np.asarray(cols, np.int64), np.asarray(vals, float))
    if rows.size:
        key = rows * N + cols
        order = np.argsort(key, kind="stable")
        skey = key[order]
        if skey.size > 1 and not (skey[1:] != skey[:-1]).all():  # duplicates: sum them
            uniq, inv = np.unique(key, return_inverse=True)
            summed = np.bincount(inv.ravel(), weights=vals, minlength=uniq.size)
        else:  # the common case (e.g. a template's entries): sorting is all it takes
            uniq, summed = skey, vals[order]
        keep = summed != 0
        uniq, summed = uniq[keep], summed[keep]
        rows, cols, vals = uniq // N, uniq % N, summed
    return fast_coo(vals, rows, cols, N)


def canonical_coos(owner: np.ndarray, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, N: int,
                   n: int) -> list[sp.coo_array]:
    """``canonical_coo`` of each of n N×N matrices given as one stack of entries, entry k of matrix owner[k]
    (nondecreasing): one sort for all of them; a matrix whose entries repeat a position goes through
    ``canonical_coo`` itself (its sums)."""
    key = np.asarray(rows, np.int64) * N + cols
    order = np.lexsort((key, owner))
    skey, sown, svals = key[order], owner[order], vals[order]
    repeats = np.zeros(n, dtype=bool)
    repeats[sown[1:][(skey[1:] == skey[:-1]) & (sown[1:] == sown[:-1])]] = True
    nz = svals != 0
    skey, sown, svals = skey[nz], sown[nz], svals[nz]
    ends = np.searchsorted(sown, np.arange(1, n))  # each matrix's sorted nonzero entries
    bounds = np.concatenate([[0], np.searchsorted(owner, np.arange(1, n)), [owner.size]]).tolist()
    return [canonical_coo(rows[lo:hi], cols[lo:hi], vals[lo:hi], N) if rep else fast_coo(v, k // N, k % N, N)
            for rep, lo, hi, k, v in zip(repeats.tolist(), bounds[:-1], bounds[1:], np.split(skey, ends),
                                         np.split(svals, ends))]


def _coo_by_attributes(vals: np.ndarray, rows: np.ndarray, cols: np.ndarray, N: int) -> sp.coo_array:
    A = sp.coo_array.__new__(sp.coo_array)
    A._shape, A.coords, A.data, A.has_canonical_format = (N, N), (rows, cols), vals, True
    return A


def _attributes_work() -> bool:
    """Whether a ``coo_array`` set up by its attributes equals one from scipy's constructor (scipy's
    internals: checked once, else ``fast_coo`` uses the constructor)."""
    try:
        r, c, v = np.array([0, 1], np.int32), np.array([1, 2], np.int32), np.array([1.0, -2.0])
        A, B = _coo_by_attributes(v, r, c, 3), sp.coo_array((v, (r, c)), shape=(3, 3))
        return (A.nnz == 2 and A.shape == (3, 3) and (A.tocsr() != B.tocsr()).nnz == 0
                and np.array_equal(A.row, r) and np.array_equal(A.col, c)
                and np.array_equal(A @ np.ones(3), B @ np.ones(3)))
    except Exception:  # noqa: BLE001 - any failure means: use the constructor
        return False


_BY_ATTRIBUTES = _attributes_work()


def fast_coo(vals: np.ndarray, rows: np.ndarray, cols: np.ndarray, N: int) -> sp.coo_array:
    """An N×N ``coo_array`` of entries already canonical (sorted by (row, col), no duplicates, no zeros),
    without scipy's checks: ~1 µs instead of ~100 µs, which is most of the cost of a model of 10⁵
    constraints.  Indices are stored as int32 when N < 2³¹ (the type scipy picks)."""
    if N < 2 ** 31 and (rows.dtype != np.int32 or cols.dtype != np.int32):  # the index type scipy picks
        rows, cols = rows.astype(np.int32), cols.astype(np.int32)
    if vals.dtype != np.float64:
        vals = vals.astype(float)
    if _BY_ATTRIBUTES:
        return _coo_by_attributes(vals, rows, cols, N)
    A = sp.coo_array((vals, (rows, cols)), shape=(N, N))
    A.has_canonical_format = True
    return A


def as_coo(A) -> sp.coo_array:
    """A sparse (or dense) square matrix as a canonical COO array without going through CSR."""
    if isinstance(A, sp.coo_array) and getattr(A, "has_canonical_format", False):
        return A
    if sp.issparse(A):
        C = A.tocoo() if not isinstance(A, (sp.coo_array, sp.coo_matrix)) else A
        return canonical_coo(C.row, C.col, C.data, A.shape[0]) if A.shape[0] == A.shape[1] else sp.coo_array(C)
    return sp.coo_array(np.asarray(A, dtype=float))


@dataclass
class Constraint:
    """⟨A, X⟩ = b with A sparse symmetric N×N.

    A is stored as a canonical ``scipy.sparse.coo_array`` (duplicates summed, zeros dropped): its size is
    proportional to its nonzeros, whatever N (a CSR array would hold an index array of N + 1 entries per
    constraint, quadratic memory over a model).  Any sparse or dense matrix given is converted.
    family: "homogenisation", "primary", a paper family ("R1", …) or "learned".
    factor: the factor it belongs to (None for model-wide constraints).
    identity: for learned constraints, its canonical name within the factor type.
    """

    A: sp.coo_array
    b: float = 0.0
    name: str = ""
    family: str = "primary"
    factor: str | None = None
    identity: str | None = None

    def __post_init__(self) -> None:
        self.A = as_coo(self.A)

    def value(self, X: np.ndarray | sp.csr_array) -> float:
        """⟨A, X⟩ − b; X dense, or sparse holding at least A's entries (a large decomposed solve keeps X on
        its cliques' pattern, ``sdp.result.DENSE_X_MAX``, and a factor's constraint lies inside a clique)."""
        A = self.A
        vals = np.asarray(X[A.row, A.col]).ravel() if sp.issparse(X) else np.asarray(X)[A.row, A.col]
        return float(np.dot(A.data, vals) - self.b)


def constraint_values(As: Sequence[sp.coo_array], X: np.ndarray | sp.sparray) -> np.ndarray:
    """⟨A_i, X⟩ for COO matrices A_i, in one gather of X's entries (X dense, or sparse holding at least
    the A_i's entries)."""
    if not len(As):
        return np.zeros(0)
    rows = np.concatenate([A.row for A in As])
    cols = np.concatenate([A.col for A in As])
    data = np.concatenate([A.data for A in As])
    owner = np.repeat(np.arange(len(As)), [A.data.size for A in As])
    vals = np.asarray(sp.csr_array(X)[rows, cols]).ravel() if sp.issparse(X) else np.asarray(X)[rows, cols]
    return np.bincount(owner, weights=data * vals, minlength=len(As))


def frobenius(X: np.ndarray | sp.csr_array) -> float:
    """‖X‖_F of a dense X, or of the entries a sparse X holds (its cliques' pattern)."""
    return float(spla.norm(X)) if sp.issparse(X) else float(np.linalg.norm(X))


@dataclass
class Factor:
    """A named group of blocks with its cost term and its primary constraints.

    blocks: the blocks the factor touches, h first; factors of the same ``type`` list
    corresponding blocks in the same order (this order fixes learned identities).
    roles: names of those blocks within the factor type (default: the block names).
    data: the factor's measurement entries (a fixed-length float vector per factor type, e.g. the 12
    entries of a measured pose [C̃ r̃]); None for a factor without measurements.  Learned templates
    (``autotight.discovery.templates``) express a constraint's coefficients as a polynomial in them.
    """

    name: str
    type: str
    blocks: tuple[str, ...]
    cost: sp.csr_array | None = None
    constraints: list[Constraint] = field(default_factory=list)
    roles: tuple[str, ...] | None = None
    data: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.data is not None:
            self.data = np.asarray(self.data, dtype=float).ravel()
        self.blocks = tuple(self.blocks)
        if not self.blocks or self.blocks[0] != HOMOGENISING:
            self.blocks = (HOMOGENISING,) + tuple(b for b in self.blocks if b != HOMOGENISING)
        if self.roles is None:
            self.roles = self.blocks
        self.roles = tuple(self.roles)
        if len(self.roles) != len(self.blocks):
            raise ProblemDefinitionError(f"factor {self.name}: {len(self.roles)} roles for {len(self.blocks)} blocks")
        for c in self.constraints:
            c.factor = c.factor or self.name


@dataclass
class Model:
    """The QCQP of one instance: min ⟨Q, X⟩ s.t. primary constraints, X = ΘᵀΘ.

    ``paper`` holds the hand-derived redundant constraints as named families.
    ``Q`` is the sum of factor costs unless ``cost`` is given (e.g. a Schur complement);
    ``cost_offset`` is a constant added to ⟨Q, X⟩ to give the original cost.
    ``cliques``: block-name tuples of a chordal cover of the aggregate sparsity (each with h);
    when given, SDP solvers may decompose X ⪰ 0 into these clique blocks.
    ``decompose``: the module's advice for a ``SolverConfig`` whose ``decompose`` is None (the user
    did not choose): True solves on the SDP layer's clique cover where the backend takes one.  None:
    the backend's default.
    """

    variables: Variables
    factors: list[Factor]
    constraints: list[Constraint] = field(default_factory=list)
    paper: dict[str, list[Constraint]] = field(default_factory=dict)
    cost: sp.csr_array | None = None
    cost_offset: float = 0.0
    cliques: list[tuple[str, ...]] | None = None
    decompose: bool | None = None

    def __post_init__(self) -> None:
        names = [f.name for f in self.factors]
        if len(set(names)) != len(names):
            raise ProblemDefinitionError("factor names must be unique")
        for f in self.factors:
            for b in f.blocks:
                if b not in self.variables:
                    raise ProblemDefinitionError(f"factor {f.name} uses unknown block {b!r}")
        sizes: dict[str, tuple[int, ...]] = {}
        for f in self.factors:
            shape = tuple(self.variables.sizes[b] for b in f.blocks)
            if sizes.setdefault(f.type, shape) != shape:
                raise ProblemDefinitionError(
                    f"factors of type {f.type!r} have inconsistent block sizes: {sizes[f.type]} vs {shape} ({f.name})")
        N = self.variables.N
        for c in self.all_constraints():
            if c.A.shape != (N, N):
                raise ProblemDefinitionError(f"constraint {c.name} has shape {c.A.shape}, expected {(N, N)}")

    @property
    def d(self) -> int:
        return self.variables.d

    @property
    def Q(self) -> sp.csr_array:
        """The cost matrix, assembled once (one COO concatenation of the factor costs: linear time; the
        sum of csr arrays one by one was quadratic in the number of factors)."""
        key = (id(self.cost), len(self.factors))
        cached = self.__dict__.get("_Q")
        if cached is not None and cached[0] == key:
            return cached[1]
        if self.cost is not None:
            Q = sp.csr_array(self.cost)
        else:
            N = self.variables.N
            parts = [f.cost if isinstance(f.cost, sp.coo_array) else sp.coo_array(f.cost) for f in self.factors
                     if f.cost is not None]
            if parts:
                Q = sp.csr_array(sp.coo_array((np.concatenate([p.data for p in parts]),
                                               (np.concatenate([p.row for p in parts]),
                                                np.concatenate([p.col for p in parts]))), shape=(N, N)))
                Q.sum_duplicates()
            else:
                Q = sp.csr_array((N, N))
        self.__dict__["_Q"] = (key, Q)
        return Q

    def homogenisation(self) -> list[Constraint]:
        """h² = 1 (d = 1) or X_hh = I_d (d > 1)."""
        d, out = self.d, []
        for i in range(d):
            for j in range(i, d):
                E = canonical_coo(np.array([i] if i == j else [i, j]), np.array([j] if i == j else [j, i]),
                                  np.array([1.0] if i == j else [0.5, 0.5]), self.variables.N)
                out.append(Constraint(E, 1.0 if i == j else 0.0, name=f"h{i}{j}", family="homogenisation"))
        return out

    def primary(self) -> list[Constraint]:
        """Homogenisation, model-wide and per-factor primary constraints."""
        return self.homogenisation() + list(self.constraints) + [c for f in self.factors for c in f.constraints]

    def paper_constraints(self, families: Iterable[str] | None = None) -> list[Constraint]:
        fams = list(self.paper) if families is None else list(families)
        unknown = [f for f in fams if f not in self.paper]
        if unknown:
            raise ProblemDefinitionError(f"unknown paper families {unknown}; known: {list(self.paper)}")
        return [c for f in fams for c in self.paper[f]]

    def all_constraints(self) -> list[Constraint]:
        return self.primary() + [c for fam in self.paper.values() for c in fam]

    def clique_indices(self) -> list[np.ndarray] | None:
        """Column indices of each clique (None when the model gives no cliques)."""
        if self.cliques is None:
            return None
        return [self.variables.index(("h",) + tuple(b for b in c if b != "h")) for c in self.cliques]

    def factor(self, name: str) -> Factor:
        for f in self.factors:
            if f.name == name:
                return f
        raise ProblemDefinitionError(f"no factor named {name!r}")

    def factor_types(self) -> dict[str, list[Factor]]:
        out: dict[str, list[Factor]] = {}
        for f in self.factors:
            out.setdefault(f.type, []).append(f)
        return out
