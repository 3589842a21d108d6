"""The matrices of many factors of one type at once, interpolated from a few builds on the factor's columns.

A factor type's constraint (or cost) matrices, written on the factor's own n columns (h first), are
polynomials of low degree in the factor's data vector (e.g. the 12 entries [C̃ r̃] of a measured pose:
the Cayley rows are affine in them, the paper's R1 and R3 quadratic).  ``FactorBatch`` builds them at a
few probe data points (1 + p builds for degree 1, 1 + p(p + 3)/2 for degree 2: 0, ±e_j and e_i + e_j),
takes the polynomial's coefficients entry by entry from exact differences of the probe values, evaluates
it for all F factors in one matrix product, and maps each factor's local columns to its columns of the
model.  One direct build (of the factor with the largest data) checks the interpolation: a builder that
is not such a polynomial raises ``ProblemDefinitionError``.

This replaces F calls of a Python builder (≈ 1 ms per constraint in ``QuadForm``/``Affine`` and scipy's
constructors) by one product and F·m light ``coo_array`` constructions (``model.fast_coo``).
Entries are the builder's up to rounding (≈ 1e-16 relative); entries that evaluate to exactly zero are
dropped, as ``canonical_coo`` drops them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .errors import ProblemDefinitionError
from .model import Constraint, as_coo, fast_coo

#: the direct build of one factor must match the interpolation to this relative accuracy (of its largest entry)
CHECK_RTOL = 1e-12


def probe_points(p: int, degree: int) -> np.ndarray:
    """The data points a polynomial of ``degree`` (1 or 2) in p variables is built at: 0, e_j (degree 1);
    0, e_j, −e_j, e_i + e_j (i < j) (degree 2).  (n_probes, p)."""
    if degree not in (1, 2):
        raise ValueError(f"degree must be 1 or 2, got {degree}")
    E = np.eye(p)
    if degree == 1:
        return np.vstack([np.zeros((1, p)), E])
    i, j = np.triu_indices(p, 1)
    return np.vstack([np.zeros((1, p)), E, -E, E[i] + E[j]])


def features(D: np.ndarray, degree: int) -> np.ndarray:
    """The monomials [1, d_j, (d_j², d_i d_j (i < j))] of each row of D (F, p), in the order of
    ``coefficients``."""
    D = np.asarray(D, float)
    parts = [np.ones((D.shape[0], 1)), D]
    if degree == 2:
        i, j = np.triu_indices(D.shape[1], 1)
        parts += [D ** 2, D[:, i] * D[:, j]]
    return np.hstack(parts)


def coefficients(values: np.ndarray, p: int, degree: int) -> np.ndarray:
    """Coefficients of the monomials of ``features`` from the values at ``probe_points`` (n_probes, …), by
    exact differences (no linear solve: an entry that is zero for every datum stays exactly zero)."""
    v0 = values[0]
    if degree == 1:
        return np.concatenate([v0[None], values[1:p + 1] - v0])
    plus, minus, pair = values[1:p + 1], values[p + 1:2 * p + 1], values[2 * p + 1:]
    lin = (plus - minus) / 2
    sq = (plus + minus) / 2 - v0
    i, j = np.triu_indices(p, 1)
    cross = pair - v0 - lin[i] - lin[j] - sq[i] - sq[j]
    return np.concatenate([v0[None], lin, sq, cross])


def relocated(r: np.ndarray, c: np.ndarray, v: np.ndarray, N: int) -> list[sp.coo_array]:
    """One N×N canonical COO array per factor from its entries at rows r, columns c, values v (F, E each; a
    factor's (row, col) pairs distinct): sorted by (row, col), its zero values dropped."""
    order = np.argsort(r.astype(np.int64) * N + c, axis=1, kind="stable")
    r, c, v = (np.take_along_axis(a, order, axis=1) for a in (r, c, v))
    nz = v != 0
    if nz.all():
        return [fast_coo(v[f], r[f], c[f], N) for f in range(len(v))]
    return [fast_coo(v[f][nz[f]], r[f][nz[f]], c[f][nz[f]], N) for f in range(len(v))]


@dataclass
class _Pattern:
    """The union of one matrix's local entries (upper and lower) over the probes."""

    rows: np.ndarray
    cols: np.ndarray
    start: int  # its first entry in the concatenated value vector


class FactorBatch:
    """The matrices ``build(data)`` (a list of n×n sparse symmetric matrices on the factor's columns,
    the same length for every datum) interpolated for a batch of data (F, p); see the module docstring."""

    def __init__(self, build: Callable[[np.ndarray], Sequence[sp.sparray | Constraint]], n: int, p: int,
                 degree: int = 1):
        self.build, self.n, self.p, self.degree = build, n, p, degree
        probes = probe_points(p, degree)
        first = list(build(probes[0]))
        #: the constraints of the first probe (names, families, right-hand sides), when ``build`` gives constraints
        self.templates = [c for c in first if isinstance(c, Constraint)]
        built = [[_matrix(A) for A in first]] + [[_matrix(A) for A in build(d)] for d in probes[1:]]
        if len({len(b) for b in built}) != 1:
            raise ProblemDefinitionError("a factor builder returned different numbers of matrices for different data")
        self.patterns: list[_Pattern] = []
        vals, start = [], 0
        for k in range(len(built[0])):
            keys = np.unique(np.concatenate([b[k].row.astype(np.int64) * n + b[k].col for b in built]))
            rows, cols = np.divmod(keys, n)
            self.patterns.append(_Pattern(rows, cols, start))
            vals.append(np.array([_values_on(b[k], keys, n) for b in built]))
            start += keys.size
        self.size = start
        values = np.hstack(vals) if vals else np.zeros((probes.shape[0], 0))
        self.coef = coefficients(values, p, degree)

    def values(self, D: np.ndarray) -> np.ndarray:
        """(F, size): every matrix's entries on its pattern for each datum, checked against a direct build."""
        D = np.asarray(D, float).reshape(len(D), self.p)
        V = features(D, self.degree) @ self.coef
        if D.shape[0]:
            f = int(np.argmax(np.abs(D).sum(axis=1)))
            made = list(self.build(D[f]))
            if any(isinstance(c, Constraint) and c.b != t.b for c, t in zip(made, self.templates)):
                raise ProblemDefinitionError("a factor builder's right-hand sides depend on its data")
            for pat, A in zip(self.patterns, (_matrix(A) for A in made)):
                keys = pat.rows * self.n + pat.cols
                held = np.isin(A.row.astype(np.int64) * self.n + A.col, keys)
                want = _values_on(A, keys, self.n)
                got = V[f, pat.start:pat.start + keys.size]
                scale = max(float(np.abs(A.data).max(initial=0.0)), 1e-300)
                if not held.all() or np.abs(got - want).max(initial=0.0) > CHECK_RTOL * scale:
                    raise ProblemDefinitionError(
                        f"a factor builder is not a polynomial of degree {self.degree} in its data "
                        "(its interpolation differs from a direct build)")
        return V

    def matrices(self, D: np.ndarray, columns: np.ndarray, N: int) -> list[list[sp.coo_array]]:
        """[factor][matrix]: N×N canonical COO arrays, local column u of factor f at column columns[f, u]."""
        columns = np.asarray(columns, np.int64 if N >= 2 ** 31 else np.int32)
        V = self.values(D)
        F = V.shape[0]
        out: list[list[sp.coo_array]] = [[] for _ in range(F)]
        for pat in self.patterns:
            v = V[:, pat.start:pat.start + pat.rows.size]
            for f, A in enumerate(relocated(columns[:, pat.rows], columns[:, pat.cols], v, N)):
                out[f].append(A)
        return out


    def constraints(self, D: np.ndarray, columns: np.ndarray, N: int, factors: Sequence[str],
                    rename: Callable[[str, int], str]) -> list[list[Constraint]]:
        """[factor][constraint]: the templates' constraints on each factor (``matrices``), named
        ``rename(template name, f)`` and belonging to ``factors[f]``."""
        out = []
        for f, mats in enumerate(self.matrices(D, columns, N)):
            out.append([Constraint(A, t.b, name=rename(t.name, f), family=t.family, factor=factors[f])
                        for A, t in zip(mats, self.templates)])
        return out


def _matrix(A: sp.sparray | Constraint) -> sp.coo_array:
    return as_coo(A.A if isinstance(A, Constraint) else A)


def _values_on(A: sp.coo_array, keys: np.ndarray, n: int) -> np.ndarray:
    """A's entries at the sorted local keys (row·n + col); zero where A has none."""
    out = np.zeros(keys.size)
    k = A.row.astype(np.int64) * n + A.col
    pos = np.searchsorted(keys, k)
    ok = (pos < keys.size) & (keys[np.minimum(pos, keys.size - 1)] == k)
    np.add.at(out, pos[ok], A.data[ok])
    return out
