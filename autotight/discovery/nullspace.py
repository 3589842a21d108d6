"""The nullspace of lifted monomial data, as a sparse basis with canonical names.

Data: Y (S×m), row s = the monomials of sample s in svec order without √2 (see ``svec``);
this equals the svec(ΘᵀΘ) rows up to a fixed column scaling, and every column is scaled to
unit norm before the SVD, so the √2 makes no difference to ranks or nullspaces.

Rank: from the relative spectrum σ_i/σ_1 at its largest gap in log10 (decades), among the gaps
whose upper end lies at or above ``RANK_FLOOR`` (relative); no absolute threshold.  Relations that
hold exactly in floating point (binary variables: w² = h², z·h = w·u) put singular values at
roundoff and below, where a second, larger gap may open (1e-17 → 1e-31); such gaps are ignored
and reported (``Spectrum.ignored_*``).  Basis: the basic solutions of the reduced echelon form.
Monomials are scanned
backwards; the "free" ones F are those whose nullspace rows are independent of the rows
already kept, and constraint f reads  m_f = Σ_{p ∉ F} c_p m_p.  F depends only on which
monomials are related, not on the measurements, so "the constraint of free monomial f"
names the same relation on every factor of a type.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from ..errors import LearningError


#: Relative level below which the spectrum is roundoff: the data Y are products of computed
#: quantities, each with a relative error of a few ε (ε = 2.2e-16), accumulated in the lifting to
#: at most κ ≈ 100 ε per entry; with unit-norm columns ‖E‖₂ ≤ ‖E‖_F ≤ κ ε √m ‖Y‖₂, so every
#: singular value of an exact relation lies below κ ε √m σ_1.  For m ≤ 2000 monomials that is
#: 100 · 2.2e-16 · √2000 ≈ 1e-12.  A gap whose upper end is below RANK_FLOOR · σ_1 separates
#: roundoff from roundoff and never decides the rank.
RANK_FLOOR = 100 * float(np.finfo(float).eps) * float(np.sqrt(2000.0))


@dataclass
class Spectrum:
    """Relative singular values, the rank read off the largest gap above the floor, and the largest
    gap that was ignored because its upper end lies below ``RANK_FLOOR`` (None when there was none
    larger than the chosen one)."""

    rel: np.ndarray
    rank: int
    gap_decades: float
    ignored_gap_decades: float | None = None
    ignored_gap_rank: int | None = None  # the rank a cut at the ignored gap would have given

    def gaps(self) -> dict[str, Any]:
        """The chosen gap and the ignored one, as JSON-able numbers."""
        out: dict[str, Any] = {"decades": float(self.gap_decades), "rank": int(self.rank)}
        if self.ignored_gap_decades is not None and self.ignored_gap_rank is not None:
            out["ignored"] = {"decades": float(self.ignored_gap_decades), "rank": int(self.ignored_gap_rank)}
        return out

    @property
    def nullity(self) -> int:
        return self.rel.size - self.rank


def spectrum(Yn: np.ndarray, min_gap_decades: float, where: str = "", floor: float = RANK_FLOOR,
             values: np.ndarray | None = None) -> Spectrum:
    """Rank of column-normalised data from its largest relative spectral gap above the floor.

    Full rank (no relation) when the whole spectrum spans fewer than min_gap_decades/2
    decades.  Otherwise the largest gap whose upper end is ≥ floor (relative to σ_1) must span at
    least ``min_gap_decades``, else LearningError: near-relations that are neither exact nor absent
    cannot be read off.  A gap whose lower end is itself below the floor needs only min_gap_decades/2:
    every value below it is consistent with an exact relation (see ``RANK_FLOOR``) and every value above
    is at least that far from one, so the cut cannot take a near-relation for an exact one.  (Ill-conditioned
    data, e.g. a stereo group of two landmarks, can keep true values down to 1e-11 above an exact nullspace at
    1e-16.)  A larger gap below the floor is reported in ``ignored_gap_decades``.
    ``values``: Yn's singular values when already known (``svd``).
    """
    s = sla.svdvals(Yn) if values is None else np.asarray(values)
    m = Yn.shape[1]
    if s.size < m:
        s = np.concatenate([s, np.zeros(m - s.size)])
    rel = s / s[0]
    logs = np.log10(np.maximum(rel, 1e-300))
    gaps = logs[:-1] - logs[1:]
    allowed = logs[:-1] >= np.log10(max(floor, 1e-300))  # the gap's upper end is above the roundoff floor
    if rel[-1] > 10.0 ** (-min_gap_decades / 2):
        return Spectrum(rel, m, float(-logs[-1]))
    k = int(np.argmax(np.where(allowed, gaps, -np.inf))) if allowed.any() else 0
    gap = float(gaps[k]) if allowed.any() else 0.0
    ignored, ignored_rank = None, None
    below = np.flatnonzero(~allowed)
    if below.size:
        j = int(below[np.argmax(gaps[below])])
        if gaps[j] > gap:
            ignored, ignored_rank = float(gaps[j]), j + 1
    need = min_gap_decades / 2 if allowed.any() and rel[k + 1] <= floor else min_gap_decades
    if gap < need:
        extra = (f"; a {ignored:.1f}-decade gap at rank {ignored_rank} lies below the roundoff floor "
                 f"{floor:.0e} and was ignored") if ignored is not None else ""
        raise LearningError(
            f"no clear spectral gap{where}: the largest gap is {gap:.1f} decades at rank {k + 1} of {m} "
            f"(need ≥ {need:g}){extra}; learn on smaller variable groups (e.g. the problem's factors)")
    return Spectrum(rel, k + 1, gap, ignored, ignored_rank)


def svd(Yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(singular values, Vᵀ (m × m)) of Yn: one decomposition for ``spectrum`` and ``nullspace``."""
    _, s, Vt = sla.svd(Yn, full_matrices=Yn.shape[0] < Yn.shape[1])  # Vt is m × m either way; U only as needed
    return s, Vt


def nullspace(Yn: np.ndarray, rank: int, Vt: np.ndarray | None = None) -> np.ndarray:
    """Orthonormal nullspace basis (m × (m − rank)) of column-normalised data (``Vt``: from ``svd``)."""
    if Vt is None:
        Vt = svd(Yn)[1]
    return Vt[rank:].T


#: a row of an orthonormal nullspace basis with a residual below this is noise, not a monomial of
#: the relations: taking it as free makes N_F nearly singular and the basic solutions blow up
FREE_ABS_TOL = 1e-6

#: largest condition number of N_F accepted for the basic solutions N · N_F⁻¹
MAX_FREE_COND = 1e8


def free_monomials(N: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """Indices F (ascending) of the free monomials: rows of N (orthonormal columns) scanned from the
    last, kept when independent of the kept rows: residual > tol relative to the row's norm and
    > FREE_ABS_TOL absolute.  |F| = N.shape[1]."""
    m, k = N.shape
    Q = np.zeros((k, k))
    r = 0
    free: list[int] = []
    for i in range(m - 1, -1, -1):
        if r == k:
            break
        row = N[i]
        nrm = np.linalg.norm(row)
        if nrm < 1e-12:
            continue
        res = row - Q[:, :r] @ (Q[:, :r].T @ row)
        res -= Q[:, :r] @ (Q[:, :r].T @ res)  # re-orthogonalise once
        rn = np.linalg.norm(res)
        if rn > tol * nrm and rn > FREE_ABS_TOL:
            Q[:, r] = res / rn
            r += 1
            free.append(i)
    if len(free) != k:
        raise LearningError(f"could not find {k} independent free monomials (found {len(free)})")
    return np.array(sorted(free))


#: coefficients below this fraction of a relation's largest are roundoff and set to 0
CLEAN = 1e-10


def basic_solutions(N: np.ndarray, free: np.ndarray, clean: float = CLEAN) -> np.ndarray:
    """Basis V (m × k) of range(N) with V[free] = I; entries below clean·max|column| set to 0.
    LearningError when N_F is too ill-conditioned for V to be accurate (cond > MAX_FREE_COND)."""
    cond = np.linalg.cond(N[free]) if len(free) else 1.0
    if not cond <= MAX_FREE_COND:
        raise LearningError(f"the free monomials give an ill-conditioned basis (cond {cond:.1e}); "
                            "the relations cannot be written with them accurately")
    V = np.linalg.solve(N[free].T, N.T).T  # N · N_F⁻¹
    V[free] = np.eye(len(free))
    mx = np.max(np.abs(V), axis=0, keepdims=True)
    V[np.abs(V) < clean * mx] = 0.0
    return V


#: a basic solution's entries below this fraction of its largest are roundoff of the nullspace, not terms of the
#: relation: ``refit_on_support`` refits the relation without them
SUPPORT_RTOL = 1e-8


def refit_on_support(Yn: np.ndarray, V: np.ndarray, free: np.ndarray, sigma_max: float,
                     rtol: float = SUPPORT_RTOL) -> np.ndarray:
    """Each basic solution v (column q of V, v[free] = I) refitted on its own support S = {i : |vᵢ| > rtol·max|v|}:
    the least-squares v_S with Yn v ≈ 0, v[free[q]] = 1 and every entry off S exactly 0.

    The nullspace's roundoff (about ε·cond of the data, 1e-12 to 1e-9 of a relation's largest coefficient) sits on
    every monomial.  Near the samples it is harmless; at a feasible point far from them a monomial can grow by
    many orders more than the relation's own terms, and the roundoff then decides its residual.  On S alone the
    data are far better conditioned and the other entries are exact zeros.  A refit is kept only where its
    residual ‖Yn v‖ is at most twice the original's plus the roundoff floor (``RANK_FLOOR``·σ_max·‖v‖): a support
    that misses a true term fits worse and leaves the column as it was.
    Yn: the column-normalised data (samples × m) whose nullspace gave V; sigma_max: its largest singular value."""
    out = V.copy()
    for q, f in enumerate(free):
        v = V[:, q]
        S = np.flatnonzero(np.abs(v) > rtol * np.max(np.abs(v)))
        dep = S[S != f]
        if dep.size == 0 or dep.size == np.count_nonzero(v) - 1:
            continue  # nothing to drop
        sol = np.linalg.lstsq(Yn[:, dep], -Yn[:, f], rcond=None)[0]
        w = np.zeros_like(v)
        w[f], w[dep] = 1.0, sol
        if np.linalg.norm(Yn @ w) <= 2.0 * np.linalg.norm(Yn @ v) + RANK_FLOOR * sigma_max * np.linalg.norm(w):
            out[:, q] = w
    return out
