"""Transport templates: the relations of a factor type move with its measurement by a change of variables.

A problem module may declare ``TRANSPORTS[type](δ) -> M`` (n × n, n the factor's local columns, h first):
a factor's columns θ satisfy the relations of measurement δ exactly when θ' = Mθ satisfies those of the
reference measurement (pose measurements: T ↦ T T̃⁻¹, so the reference is T̃ = I).  Then the relation spaces
of any two factors of the type are congruent: with the basic solutions A₀ learned on one factor (data δ₀),

    A(δ) = Rᵀ A₀ R,   R = M(δ₀)⁻¹ M(δ),

spans the relations of a factor with data δ, and its basic solutions (``nullspace.basic_solutions``:
coefficient 1 on its own free monomial, 0 on the other free ones) are

    P(δ) = B (B_F)⁻¹,   B = the learned basis carried by R (m × k),   F the free monomials.

(The learned factor, not δ = reference, anchors the basis: at T̃ = I itself the free monomials of a
generic factor can be singular.)

That is exact for every δ, although P(δ) is a rational function of high degree in δ (which is why no
polynomial template of degree ≤ 2 fits such a type).  Applying it costs one congruence and one k × k
solve per factor, batched over the type's factors: no sampling and no nullspace.

Layout as in ``templates``: coefficient vectors over the local monomials θ_iᵀθ_j, i ≤ j, in svec order
(column-major upper triangle, no √2); the reference basis is stored as (monomial, relation, value)
triplets of its nonzeros.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from ..errors import AutotightError
from ..problem import Problem
from ..svec import polys_to_syms, sym_to_poly, triu_indices
from .nullspace import CLEAN, MAX_FREE_COND

#: factors carried at once (bounds the (chunk, k, n, n) congruence array)
CHUNK = 256


def carry(P: np.ndarray, Ms: np.ndarray) -> np.ndarray:
    """Coefficients of θ ↦ p(Mθ) for each relation p (columns of P, (m, k)) and each M of Ms (c, n, n)
    → (c, k, m): the congruence Mᵀ A M of each relation's symmetric matrix A."""
    c, n = Ms.shape[0], Ms.shape[1]
    k = P.shape[1]
    S = polys_to_syms(P.T, n)
    AM = (S.reshape(k * n, n) @ Ms).reshape(c, k, n, n)  # A M, one product per factor
    return sym_to_poly((np.swapaxes(AM, 2, 3).reshape(c, k * n, n) @ Ms).reshape(c, k, n, n))  # Mᵀ A M


def carry_each(P: np.ndarray, Ms: np.ndarray) -> np.ndarray:
    """As ``carry`` with relations of their own per factor: P (c, w, m), Ms (c, n, n) → (c, w, m)."""
    S = polys_to_syms(P, Ms.shape[1])
    return sym_to_poly(np.swapaxes(S @ Ms[:, None], 2, 3) @ Ms[:, None])


def carried_free(P: np.ndarray, Ms: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The entries on the monomials ``free`` of ``carry(P, Ms)`` → (c, k, len(free)), without the others.

    Entry (i, j) of Mᵀ A M is M[:, i]ᵀ (A M[:, j]): one product A M[:, j] per distinct column j of the free
    monomials, instead of the whole A M (k·n²·|j| multiplications per factor, not 2·k·n³)."""
    c, n = Ms.shape[0], Ms.shape[1]
    k = P.shape[1]
    ii, jj = triu_indices(n)
    fi, fj = ii[free], jj[free]
    S = polys_to_syms(P.T, n).reshape(k * n, n)
    out = np.empty((c, k, len(free)))
    for j in np.unique(fj):
        at = np.nonzero(fj == j)[0]
        AMj = (Ms[:, :, j] @ S.T).reshape(c, k, n)  # A M[:, j] for every relation and factor
        out[:, :, at] = AMj @ Ms[:, :, fi[at]]
    return np.where(fi != fj, 2.0, 1.0) * out


def _free_inverse(BF: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Columns ``rows`` of B_F⁻¹ for each factor, BF (c, k free, k relations) → (c, k, |rows|); NaN where B_F is
    exactly singular."""
    E = np.eye(BF.shape[1])[:, rows]
    try:
        return np.linalg.solve(BF, E)
    except np.linalg.LinAlgError:  # some B_F exactly singular: one factor at a time
        G = np.full((BF.shape[0], BF.shape[1], len(rows)), np.nan)
        for i in range(BF.shape[0]):
            try:
                G[i] = np.linalg.solve(BF[i], E)
            except np.linalg.LinAlgError:
                pass
        return G


def _cleaned(V: np.ndarray, free: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Basic solutions V (c, |rows|, m): NaN where too large, exact 0/1 on the free monomials, and entries below
    ``CLEAN`` of a solution's largest set to 0 (see ``basic``) → (V, Frobenius norms)."""
    size = np.linalg.norm(V, axis=(1, 2))
    ok = np.isfinite(size) & (size <= MAX_FREE_COND)
    V[~ok] = np.nan
    W = V[ok]
    W[:, :, free] = np.eye(len(free))[rows]
    mx = np.max(np.abs(W), axis=2, keepdims=True)
    W[np.abs(W) < CLEAN * mx] = 0.0
    V[ok] = W
    return V, size


def basic(B: np.ndarray, free: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Basic solutions ``rows`` (default all) of the spans of B (c, k, m) with respect to ``free`` (k
    monomials) → ((c, len(rows), m), their Frobenius norms).  Entries below ``CLEAN`` of a solution's largest
    are 0, as in learning (``nullspace.basic_solutions``).

    The solutions V = B B_F⁻¹ do not depend on the basis B of the span; for its orthonormal basis Q they are
    Q Q_F⁻¹, so for all rows ‖V‖_F ≥ ‖Q_F⁻¹‖₂ ≥ cond(Q_F), the measure learning bounds by ``MAX_FREE_COND``
    (for a subset of rows, the size of those solutions only).  Solutions with a norm above it (or a singular
    B_F) are NaN: the free monomials do not write the relations accurately there."""
    rows = np.arange(len(free)) if rows is None else np.asarray(rows)
    G = _free_inverse(np.swapaxes(B[:, :, free], 1, 2), rows)
    return _cleaned(np.swapaxes(G, 1, 2) @ B, free, rows)


def carried_basic(P: np.ndarray, Ms: np.ndarray, free: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``basic(carry(P, Ms), free, rows)`` with less work: carrying is linear in the relations, so the solutions
    (B B_F⁻¹)ᵀ = carry(P G) with G = B_F⁻¹[:, rows]; only B_F is needed of every relation (``carried_free``),
    and only |rows| combinations are carried whole."""
    G = _free_inverse(np.swapaxes(carried_free(P, Ms, free), 1, 2), rows)
    return _cleaned(carry_each(np.swapaxes(P @ G, 1, 2), Ms), free, rows)


class Layout:
    """Sizes of a factor type's local columns and monomials, from its ``block_sizes`` (h first)."""

    block_sizes: list[int]

    @property
    def n_cols(self) -> int:
        return int(sum(self.block_sizes))

    @property
    def n_monomials(self) -> int:
        return self.n_cols * (self.n_cols + 1) // 2


@dataclass
class TransportTemplate(Layout):
    """The relations of one factor type, carried from one learned factor to any other by ``TRANSPORTS[type]``.

    basis: (m, k) basic solutions learned on one factor, whose data is ``data``; ``free`` their free
    monomials; ``want`` the rows of the identities kept (``identities``).  Same interface as ``TypeTemplate``:
    ``coefficients(D, problem)`` on ``support`` (positions in the stacked k_wanted · m vector)."""

    factor_type: str
    identities: list[str]
    roles: list[str]
    block_sizes: list[int]
    n_data: int
    data: np.ndarray
    free: np.ndarray
    want: np.ndarray
    basis: np.ndarray
    support: np.ndarray
    check: dict[str, Any] = field(default_factory=dict)
    kind: str = "transport"

    def solutions(self, D: np.ndarray, problem: Problem | None) -> np.ndarray:
        """The wanted basic solutions for factors with data D (n_f, n_data) → (n_f, k_wanted, m); NaN rows for
        a factor whose free monomials do not write its relations accurately (see ``basic``)."""
        if problem is None:
            raise AutotightError(f"the transport template of {self.factor_type!r} needs its problem module")
        D = np.asarray(D, dtype=float).reshape(-1, self.n_data)
        out = np.empty((D.shape[0], len(self.want), self.n_monomials))
        M0inv = np.linalg.inv(problem.transport(self.factor_type, self.data, self.n_cols))
        for s in range(0, D.shape[0], CHUNK):
            Ms = M0inv @ np.array([problem.transport(self.factor_type, d, self.n_cols) for d in D[s:s + CHUNK]])
            out[s:s + CHUNK], _ = carried_basic(self.basis, Ms, self.free, self.want)
        return out

    def coefficients(self, D: np.ndarray, problem: Problem | None = None) -> np.ndarray:
        """Coefficients on ``support`` (every position: which are zero depends on the factor) → (n_f, k_wanted·m);
        NaN rows for a factor without basic solutions."""
        return self.solutions(D, problem).reshape(len(np.atleast_2d(D)), -1)

    def dense(self, D: np.ndarray, problem: Problem | None = None) -> np.ndarray:
        """Full coefficient vectors (n_f, k_wanted, m), as learning returns them."""
        return self.solutions(D, problem)

    def restricted(self, identities: Sequence[str]) -> "TransportTemplate":
        """The template of ``identities`` only (a subset of its own, in that order)."""
        idx = [self.identities.index(i) for i in identities]
        return replace(self, identities=list(identities), want=self.want[idx],
                       support=np.arange(len(idx) * self.n_monomials, dtype=np.int64))

    def record(self) -> dict[str, Any]:
        r, c = np.nonzero(self.basis)
        return {"kind": self.kind, "factor_type": self.factor_type, "identities": self.identities,
                "roles": self.roles, "block_sizes": self.block_sizes, "n_data": self.n_data,
                "transport": f"TRANSPORTS[{self.factor_type!r}] of the problem module", "data": self.data.tolist(),
                "free": self.free.tolist(), "want": self.want.tolist(), "n_relations": int(self.basis.shape[1]),
                "basis_triplets": [[int(i), int(j), float(self.basis[i, j])] for i, j in zip(r, c)],
                "support": self.support.tolist(), "check": self.check}

    @classmethod
    def from_record(cls, r: dict[str, Any]) -> "TransportTemplate":
        sizes = [int(s) for s in r["block_sizes"]]
        n = sum(sizes)
        basis = np.zeros((n * (n + 1) // 2, int(r["n_relations"])))
        for i, j, v in r["basis_triplets"]:
            basis[int(i), int(j)] = float(v)
        ints = {k: np.asarray(r[k], dtype=np.int64) for k in ("free", "want", "support")}
        return cls(r["factor_type"], list(r["identities"]), list(r["roles"]), sizes, int(r["n_data"]),
                   np.asarray(r["data"], dtype=float), ints["free"], ints["want"], basis, ints["support"],
                   dict(r.get("check", {})))


def reference_template(problem: Problem, factor_type: str, wanted: list[str], roles: list[str],
                       block_sizes: list[int], data: np.ndarray, coeffs: np.ndarray, free: np.ndarray,
                       identities: list[str]) -> TransportTemplate:
    """The template from one learned factor: its basic solutions ``coeffs`` (m, k) at measurement ``data``
    (its support: every position).  AutotightError when a wanted identity is not among them or
    the module's transport is singular there."""
    missing = [i for i in wanted if i not in identities]
    if missing:
        raise AutotightError(f"identity {factor_type}:{missing[0]} is not a basic solution of the learned factor")
    data = np.asarray(data, dtype=float).ravel()
    M = problem.transport(factor_type, data, int(sum(block_sizes)))
    if not np.linalg.cond(M) <= MAX_FREE_COND:
        raise AutotightError(f"factor type {factor_type!r}: TRANSPORTS gives a singular map at the learned factor")
    want = np.array([identities.index(i) for i in wanted], dtype=np.int64)
    m = coeffs.shape[0]
    return TransportTemplate(factor_type, list(wanted), roles, block_sizes, data.size, data,
                             np.asarray(free, dtype=np.int64), want, np.asarray(coeffs, dtype=float).copy(),
                             np.arange(len(wanted) * m, dtype=np.int64))
