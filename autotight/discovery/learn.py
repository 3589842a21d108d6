"""Learning the valid quadratic constraints of one variable group from feasible samples."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import LearningError, ProblemDefinitionError
from ..model import HOMOGENISING, Constraint, Factor, Model, canonical_coo
from ..svec import sym_to_poly, triu_indices
from .nullspace import (CLEAN, Spectrum, basic_solutions, free_monomials, nullspace, refit_on_support, spectrum,
                        svd)
from .samples import SampleBank


@dataclass(frozen=True)
class LearnOptions:
    """Settings of learning.

    sample_factor: samples per monomial (≥ 1.2).  min_gap_decades: the spectral gap that
    decides the rank (log10 units).  spread: how far samples stray from the nominal state (None: the
    problem's ``SPREAD``, 0.5 unless the module sets it).
    heldout: held-out samples per instance; heldout_tol: the largest relative violation
    |Σ p_ij θ_iᵀθ_j| / Σ|p_ij|‖θ_i‖‖θ_j‖ a learned constraint may show on them.  span_tol: relative
    residual below which a candidate counts as in the span of the primary constraints.
    """

    sample_factor: float = 1.2
    min_gap_decades: float = 6.0
    spread: float | None = None
    heldout: int = 60
    heldout_tol: float = 1e-8
    span_tol: float = 1e-6
    free_tol: float = 1e-7


@dataclass(frozen=True)
class Group:
    """A learning group: blocks (h first) with role names that are the same for every group of ``type``."""

    name: str
    type: str
    blocks: tuple[str, ...]
    roles: tuple[str, ...]

    @staticmethod
    def of(f: Factor) -> "Group":
        return Group(f.name, f.type, tuple(f.blocks), tuple(f.roles or f.blocks))


def adjacent_groups(model: Model, type_a: str, type_b: str, keep: Sequence[str] | None = None) -> list[Group]:
    """Unions of a factor of type_a with each later factor of type_b that shares a block with it.

    Roles: the first factor's roles prefixed "1.", the second's new blocks prefixed "2.", so that
    the union has the same roles wherever it sits (e.g. two consecutive motion factors).
    keep: only the blocks of these roles (and h) enter the union; its type then ends in "/role/…".
    """
    fs = model.factors
    out = []
    if keep is not None:
        for f in fs:
            if f.type in (type_a, type_b) and not set(keep) <= set(f.roles or f.blocks):
                missing = sorted(set(keep) - set(f.roles or f.blocks))
                raise ProblemDefinitionError(f"factor type {f.type!r} has no role(s) {missing}; "
                                             f"roles are {list(f.roles or f.blocks)}")
    for i, fa in enumerate(fs):
        if fa.type != type_a:
            continue
        for fb in fs[i + 1:]:
            if fb.type != type_b or not (set(fa.blocks) & set(fb.blocks)) - {HOMOGENISING}:
                continue
            blocks, roles = [], []
            for b, r in zip(fa.blocks, fa.roles or fa.blocks):
                if b == HOMOGENISING or keep is None or r in keep:
                    blocks.append(b)
                    roles.append(r if b == HOMOGENISING else f"1.{r}")
            for b, r in zip(fb.blocks, fb.roles or fb.blocks):
                if b not in blocks and (keep is None or r in keep) and b not in fa.blocks:
                    blocks.append(b)
                    roles.append(f"2.{r}")
            suffix = "" if keep is None else "/" + "/".join(keep)
            out.append(Group(f"{fa.name}+{fb.name}{suffix}", f"{type_a}+{type_b}{suffix}", tuple(blocks),
                             tuple(roles)))
    return out


def groups_of(model: Model, how: str | Sequence[Sequence[str]] = "factors") -> list[Group]:
    """Learning groups.

    how: "factors" (default: one group per factor), "whole" (all blocks), "adjacent:A+B" (unions of
    neighbouring factors of types A and B; "adjacent:A+B/r1/r2" keeps only the blocks of roles r1, r2 and
    h), several of these joined by commas, or explicit block lists.
    """
    if isinstance(how, str):
        out: list[Group] = []
        for part in [p.strip() for p in how.split(",") if p.strip()]:
            if part == "factors":
                out += [Group.of(f) for f in model.factors]
            elif part == "whole":
                names = tuple(model.variables.names)
                out.append(Group("whole", "whole", names, names))
            elif part.startswith("adjacent:") and "+" in part:
                spec, *keep = part.split(":", 1)[1].split("/")
                ta, tb = spec.split("+", 1)
                types = {f.type for f in model.factors}
                for t in (ta, tb):
                    if t not in types:
                        raise ProblemDefinitionError(f"no factor type {t!r}; types are {sorted(types)}")
                out += adjacent_groups(model, ta, tb, keep or None)
            else:
                raise ProblemDefinitionError(
                    f"unknown group spec {part!r}; use factors, whole, adjacent:TYPE+TYPE or block lists")
        return out
    out = []
    for i, blocks in enumerate(how):
        b = (HOMOGENISING,) + tuple(x for x in blocks if x != HOMOGENISING)
        for x in b:
            model.variables.slice(x)  # validates
        out.append(Group(f"group{i}", f"group{i}", b, b))
    return out


def scan_order(n: int, d: int) -> np.ndarray:
    """Monomial order for the scan: constants (h·h), then linear (h·x), then quadratic, each in svec order."""
    i, j = triu_indices(n)
    degree = (i >= d).astype(int) + (j >= d).astype(int)
    return np.argsort(degree, kind="stable")


#: a group whose smallest kept singular value is below this fraction of its largest is near-degenerate
#: (``LearnedGroup.near_degenerate``); generic robust pose averaging pairs at σ = 0.05: ≥ 6.7e-5, those that
#: lose identities at σ ≤ 0.01: ≤ 1.2e-5 (near-degenerate groups matter only where an identity is missing)
NEAR_DEGENERATE = 1e-4


@dataclass
class LearnedGroup:
    """The constraints learned on one group.

    ``coeffs`` (m × k): polynomial coefficients (svec order, no √2) of the k basic
    solutions, coefficient 1 on its free monomial.  ``identities[j]`` names solution j within the
    group type.  ``in_primary_span[j]``: already spanned by the primary constraints (with the
    solutions before it).  ``heldout_violation[j]``: the largest relative violation on held-out samples.
    """

    group: Group
    columns: np.ndarray
    n_samples: int
    spectrum_rel: np.ndarray
    rank: int
    gap_decades: float
    identities: list[str]
    coeffs: np.ndarray
    in_primary_span: np.ndarray
    heldout_violation: np.ndarray
    heldout_tol: float
    times: dict[str, float] = field(default_factory=dict)
    ignored_gap_decades: float | None = None  # a larger gap below the roundoff floor (nullspace.RANK_FLOOR)
    ignored_gap_rank: int | None = None
    degenerate: str | None = None  # why the free monomials gave no basic solutions (``learn_group``)
    whole: "LearnedGroup | None" = None  # with whole_nullspace: the orthonormal basis of the same nullspace
    free: np.ndarray | None = None  # svec index of each solution's free monomial (None: ``degenerate``)

    @property
    def near_degenerate(self) -> bool:
        """A nonempty nullspace with a larger one close by: the smallest singular value kept is below
        ``NEAR_DEGENERATE`` of the largest (e.g. two measurements that nearly coincide), so the free
        monomials, and with them the identities' names, may differ from a generic instance's."""
        return self.coeffs.shape[1] > 0 and self.rank > 0 and float(self.spectrum_rel[self.rank - 1]) < NEAR_DEGENERATE

    def gaps(self) -> dict[str, Any]:
        """The chosen spectral gap (decades, rank) and any ignored one below the roundoff floor."""
        return Spectrum(self.spectrum_rel, self.rank, self.gap_decades, self.ignored_gap_decades,
                        self.ignored_gap_rank).gaps()

    @property
    def n_monomials(self) -> int:
        return self.coeffs.shape[0]

    def passed(self) -> np.ndarray:
        return self.heldout_violation <= self.heldout_tol

    def candidate_index(self) -> np.ndarray:
        """Solutions that are new (not in the primary span) and passed the held-out check."""
        return np.flatnonzero(~self.in_primary_span & self.passed())

    def rejected(self) -> list[tuple[str, float]]:
        return [(self.identities[j], float(self.heldout_violation[j])) for j in np.flatnonzero(~self.passed())]

    def constraint(self, j: int, N: int) -> Constraint:
        """Basic solution j as a Constraint on the full N×N lifting."""
        n = len(self.columns)
        i, jj = triu_indices(n)
        p = self.coeffs[:, j]
        nz = np.flatnonzero(p)
        gi, gj = self.columns[i[nz]], self.columns[jj[nz]]
        off = gi != gj
        rows = np.concatenate([gi, gj[off]])
        cols = np.concatenate([gj, gi[off]])
        vals = np.concatenate([np.where(off, p[nz] / 2, p[nz]), p[nz][off] / 2])
        A = canonical_coo(rows, cols, vals, N)  # no CSR index array of length N + 1 per constraint
        ident = self.identities[j]
        return Constraint(A, 0.0, name=f"{self.group.name}:{ident}", family="learned", factor=self.group.name,
                          identity=f"{self.group.type}:{ident}")


def _monomial_names(group: Group, sizes: dict[str, int], d: int) -> list[str]:
    names = []
    for b, role in zip(group.blocks, group.roles):
        n = sizes[b]
        names += [role if (n == 1 or b == HOMOGENISING and d == 1) else f"{role}[{k}]" for k in range(n)]
    return names


class SpanningIndex:
    """COO matrices of the constraints that count as spanned, bucketed by the largest column they
    touch: a group finds those supported inside its columns by looking at the buckets of its own
    columns only (scanning every matrix for every group grew with the square of the trajectory)."""

    def __init__(self, matrices: Sequence[sp.coo_array] = ()):
        self.buckets: dict[int, list[tuple[np.ndarray, sp.coo_array]]] = {}
        for U in matrices:
            self.add(U)

    def add(self, U: sp.coo_array) -> None:
        if U.nnz:
            cols = np.unique(np.concatenate([U.row, U.col]))
            self.buckets.setdefault(int(cols[-1]), []).append((cols, U))

    def within(self, cols: np.ndarray) -> list[sp.coo_array]:
        """The matrices whose every row and column is one of ``cols`` (membership by a mask over the columns up
        to the largest of ``cols``, which bounds every column of the buckets looked at)."""
        cols = np.asarray(cols, dtype=np.int64)
        if not cols.size:
            return []
        inside = np.zeros(int(cols.max()) + 1, dtype=bool)
        inside[cols] = True
        return [U for c in cols.tolist() for ucols, U in self.buckets.get(c, ()) if inside[ucols].all()]


def learn_group(model: Model, group: Group, bank: SampleBank, heldout: SampleBank, opts: LearnOptions,
                spanning: SpanningIndex | None = None, whole_nullspace: bool = False,
                checked: bool = True) -> LearnedGroup:
    """Nullspace of the group's monomial data → basic solutions, primary-span flags, held-out check.

    ``spanning``: the constraints that count as spanned (default: the homogeneous primary
    constraints, ``spanning_matrices``); ``learn`` adds each group's new relations, so those
    supported inside a later group are not proposed twice.

    whole_nullspace: when the free monomials give no accurate basic solutions (LearningError of
    ``nullspace.free_monomials`` / ``basic_solutions``: a near-degenerate instance, e.g. two measurements
    that nearly coincide, where a larger nullspace is close), keep the orthonormal nullspace basis
    instead: each column scaled to max |coefficient| 1, entries below ``nullspace.CLEAN`` zeroed; valid
    relations spanning the whole nullspace, named ``nullspace[q]``, not identities; why is recorded in
    ``degenerate``.  Otherwise such a group raises.  With whole_nullspace, a group whose basic solutions
    exist but some fail the held-out check, or that is ``near_degenerate``, also gets that basis as
    ``whole`` (what ``catalog.carry_over`` uses when a wanted identity is inaccurate or named otherwise).

    checked=False: the basic solutions only (what a template fit needs): no primary-span test and no
    held-out check, so every relation reads as unchecked (held-out violation NaN: none passes).
    """
    t0 = time.perf_counter()
    V = model.variables
    cols = V.index(group.blocks)
    n, d = len(cols), V.d
    order = scan_order(n, d)
    ii, jj = triu_indices(n)
    m = ii.size
    need = int(np.ceil(opts.sample_factor * m))
    if bank.size < need:
        raise ValueError(f"group {group.name} needs {need} samples, the bank has {bank.size}")
    T = bank.thetas[:need][:, :, cols]
    Y = np.einsum("sdk,sdk->sk", T[:, :, ii[order]], T[:, :, jj[order]])
    D = np.linalg.norm(Y, axis=0)
    D[D == 0] = 1.0
    Yn = Y / D
    sv, Vt = svd(Yn)
    spec = spectrum(Yn, opts.min_gap_decades, where=f" in group {group.name} ({m} monomials)", values=sv)
    t1 = time.perf_counter()
    k = m - spec.rank
    degenerate = None
    names = _monomial_names(group, V.sizes, d)
    whole: np.ndarray | None = None
    if k == 0:
        coeffs = np.zeros((m, 0))
        free = np.zeros(0, int)
    else:
        Nn = nullspace(Yn, spec.rank, Vt)
        if whole_nullspace:
            whole = np.zeros((m, k))
            whole[order] = _orthonormal_relations(Nn, D)  # checked below only where it is needed
        try:
            free = free_monomials(Nn, opts.free_tol)
            Vn = refit_on_support(Yn, basic_solutions(Nn, free), free, float(sv[0]))
            P = Vn / D[:, None]  # back to polynomial coefficients (scan order); P[free] = diag(1/D[free])
            P = P * D[free][None, :]
            coeffs = np.zeros((m, k))
            coeffs[order] = P
        except LearningError as e:
            if whole is None:
                raise
            degenerate, free, coeffs, whole = str(e), np.zeros(0, int), whole, None
    idents = ([f"{names[ii[order[f]]]}·{names[jj[order[f]]]}" for f in free] if degenerate is None
              else [f"nullspace[{q}]" for q in range(k)])
    if not checked:
        in_span, viol = np.zeros(coeffs.shape[1], bool), np.full(coeffs.shape[1], np.nan)
    else:
        if spanning is None:
            spanning = SpanningIndex(spanning_matrices(model))
        in_span, viol = _span_and_heldout(coeffs, cols, order, D, spanning, heldout, opts)
    t2 = time.perf_counter()
    lg = LearnedGroup(group, cols, need, spec.rel, spec.rank, spec.gap_decades, idents, coeffs, in_span, viol,
                      opts.heldout_tol, {"nullspace_s": t1 - t0, "basis_s": t2 - t1},
                      spec.ignored_gap_decades, spec.ignored_gap_rank, degenerate,
                      free=order[free] if degenerate is None else None)
    if whole is not None and (not lg.passed().all() or lg.near_degenerate):  # the same nullspace, orthonormal:
        # what carry-over uses where an identity is inaccurate (held-out failure) or named otherwise (near-degenerate)
        if spanning is None:
            spanning = SpanningIndex(spanning_matrices(model))
        w_span, w_viol = _span_and_heldout(whole, cols, order, D, spanning, heldout, opts)
        lg.whole = replace(lg, identities=[f"nullspace[{q}]" for q in range(k)], coeffs=whole, in_primary_span=w_span,
                           heldout_violation=w_viol, degenerate="the orthonormal basis of the nullspace", free=None)
    return lg


def _orthonormal_relations(Nn: np.ndarray, D: np.ndarray) -> np.ndarray:
    """The orthonormal nullspace basis Nn (normalised monomials, scan order) as polynomial coefficients:
    each column scaled to max |coefficient| 1, entries below ``nullspace.CLEAN`` zeroed (roundoff)."""
    P = Nn / D[:, None]
    P = P / np.max(np.abs(P), axis=0, keepdims=True)
    P[np.abs(P) < CLEAN] = 0.0
    return P


def _span_and_heldout(coeffs: np.ndarray, cols: np.ndarray, order: np.ndarray, D: np.ndarray,
                      spanning: SpanningIndex, heldout: SampleBank,
                      opts: LearnOptions) -> tuple[np.ndarray, np.ndarray]:
    """Per relation (column of ``coeffs``, svec order): in the span of ``spanning`` and the relations before
    it (in the normalised space), and its largest relative violation on the held-out samples."""
    n, (m, k) = len(cols), coeffs.shape
    ii, jj = triu_indices(n)
    prim = []
    sorter = np.argsort(cols)
    for U in spanning.within(cols):
        r, c = (sorter[np.searchsorted(cols, x, sorter=sorter)] for x in (U.row, U.col))  # local indices
        loc = np.zeros((n, n))
        np.add.at(loc, (r, c), U.data)  # repeated entries summed in order, as its CSR form sums them
        prim.append(sym_to_poly(loc)[order] * D)
    basis = np.zeros((m, 0))
    if prim:
        Qp, Rp = np.linalg.qr(np.array(prim).T)
        keep = np.abs(np.diag(Rp)) > 1e-10 * np.max(np.abs(np.diag(Rp)))
        basis = Qp[:, keep]
    in_span = np.zeros(k, bool)
    for q in range(k):
        v = coeffs[order, q] * D
        r = v - basis @ (basis.T @ v)
        if np.linalg.norm(r) <= opts.span_tol * np.linalg.norm(v):
            in_span[q] = True
        else:
            basis = np.column_stack([basis, r / np.linalg.norm(r)])
    Th = heldout.thetas[:, :, cols]
    Mh = np.einsum("sdk,sdk->sk", Th[:, :, ii], Th[:, :, jj])
    nh = np.linalg.norm(Th, axis=1)
    mag = nh[:, ii] * nh[:, jj]  # ‖θ_i‖‖θ_j‖ ≥ |θ_iᵀθ_j|: the size of each monomial's factors
    viol = np.max(np.abs(Mh @ coeffs) / np.maximum(mag @ np.abs(coeffs), 1e-300), axis=0) if k else np.zeros(0)
    return in_span, viol


def spanning_matrices(model: Model) -> list[sp.coo_array]:
    """The homogeneous (b = 0) primary constraints as COO arrays."""
    return [sp.coo_array(c.A) for c in model.primary() if c.b == 0]


def monomials_needed(model: Model, groups: Sequence[Group], opts: LearnOptions) -> int:
    n = max(len(model.variables.index(g.blocks)) for g in groups)
    return int(np.ceil(opts.sample_factor * n * (n + 1) / 2))
