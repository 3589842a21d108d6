"""Recession directions of a relaxation that are combinations of columns, made columns by a change of frame.

A relaxation min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0 can have an unbounded optimal set along directions that
are combinations of columns rather than single columns (those are ``certificate.recession_columns``).
Robust Wahba's lifting x = [h, t, vec C, (wᵢ, zᵢ)ᵢ] with zᵢ = wᵢ[t; vec C] grows at no cost along
v_a = e_{t_a} − Σᵢ e_{zᵢ,a}: with every point an outlier the translation is free, the lifted points x(λ)
of that path satisfy every valid relation, and so does their limit x(λ)x(λ)ᵀ/λ² → v_a v_aᵀ.  No redundant
constraint removes such a direction; no dual point is strictly feasible along it and no trace bound
exists, so no certificate in the given frame can succeed.

Directions (``recession_directions``).  The zero-cost recession cone is
R = {D ⪰ 0 : ⟨Aᵢ,D⟩ = 0 for all i, ⟨Q,D⟩ = 0}.  For D ∈ R and any y, ⟨H(y),D⟩ = ⟨Q,D⟩ − Σᵢ yᵢ⟨Aᵢ,D⟩ = 0,
so every dual feasible H ⪰ 0 has range(D) in its null space.  Given multipliers y near the dual optimum,
the near-null space Nₕ of H(y) (the eigenvectors of the smallest |eigenvalues| up to the largest gap
among those at most ``NULL_RTOL`` of the largest, ``null_dimension``: x̂ and the recession directions)
holds them, and D = Nₕ M Nₕᵀ with M from the small SDP
    min tr M / r  s.t.  ⟨NₕᵀAᵢNₕ, M⟩ = 0, ⟨NₕᵀQNₕ, M⟩ = 0, tr M = 1, M ⪰ 0
(its relations an orthonormal basis of the span of the reduced ones, singular values above
``RELATION_RTOL`` of the largest, then the counts at the largest gaps, ``gap_counts``: H(y) is dual
optimal only to the solve's accuracy, so its null space is near the directions, not on them, and the
reduced relations that vanish on them are small, not zero;
the cost is constant on the feasible set, so an interior-point method ends near the analytic centre, in
the relative interior, and range(D) spans every direction of R in Nₕ).  The range (eigenvalues above
``RANGE_RTOL`` of the largest, then at the largest gaps) is put in reduced row-echelon form and its
entries are snapped to fractions of denominator at most ``SNAP_DENOMINATOR`` within ``SNAP_ATOL``: the
directions of a lifting are exact, simple vectors, and only exact ones pass the check below (a wrong
snap costs nothing).

Frame (``Frame``).  Row v_a with pivot p_a (v_a[p_a] = 1, 0 at the other pivots) gives
T = I + Σ_a (v_a − e_{p_a}) e_{p_a}ᵀ and x = T x′: column p_a of the new frame is v_a.  The off-identity
part N of T has N² = 0 (it is zero on the pivot rows), so T⁻¹ = I − N.  X = T X′ Tᵀ maps X′ ⪰ 0 onto X ⪰ 0
and ⟨A, X⟩ = ⟨TᵀAT, X′⟩: the relaxation in the new frame has the same feasible costs and the same
multipliers y, so a certificate there (same y, same bᵀy) is one of the given relaxation.
  Proof: the congruence by an invertible T is a bijection of the PSD cone that preserves every ⟨A,·⟩.
Entries of TᵀAT that cancel to roundoff (below ``CANCEL_ULPS``·ε times |T|ᵀ|A||T|, the sum of the
magnitudes of their terms) are set to 0: exact cancellation is what the directions' isotropy means, and
the certificate then checks that H vanishes on those columns (``certificate.FREE_ATOL``), as for any
recession column.  Directions whose pivot column is not a recession column of the new frame (a
direction that the snapping did not make exact) are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from fractions import Fraction
from typing import Iterator, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .certificate import entries, recession_columns, stack
from .model import Constraint
from .svec import smat, svec

#: H(y) is decomposed densely: tried up to this many columns
RECESSION_MAX_N = 2000
#: H(y)'s null space ends at a gap of at least this ratio between consecutive eigenvalue magnitudes
NULL_GAP = 100.0
#: … and holds only eigenvalues of |wᵢ| at most this fraction of the largest (a dual point accurate to a solve's
#: tolerance has its null eigenvalues near that tolerance, far below this)
NULL_RTOL = 1e-4
#: a reduced relation counts above this fraction of the largest singular value (below: Nₕ's own error)
RELATION_RTOL = 1e-3
#: … or at a gap of at least MIN_GAP between consecutive singular values; at most MAX_TRIES counts are tried
MIN_GAP = 5.0
MAX_TRIES = 3
#: range(D): eigenvalues above this fraction of the largest
RANGE_RTOL = 1e-3
#: entries of the echelon basis are snapped to fractions p/q, q ≤ SNAP_DENOMINATOR, within SNAP_ATOL
SNAP_DENOMINATOR = 12
SNAP_ATOL = 1e-2
#: an entry of TᵀAT is roundoff when below this many ε times the magnitudes of its terms
CANCEL_ULPS = 16


def _snap(B: np.ndarray, atol: float = SNAP_ATOL) -> np.ndarray:
    out = np.array(B, dtype=float)
    for idx in zip(*np.nonzero(out)):
        f = Fraction(float(out[idx])).limit_denominator(SNAP_DENOMINATOR)
        if abs(float(f) - out[idx]) <= atol:
            out[idx] = float(f)
    return out


def echelon(V: np.ndarray, atol: float = SNAP_ATOL) -> tuple[np.ndarray, np.ndarray]:
    """(rows, pivots): a basis of the span of V's columns (n × r) in reduced row-echelon form with
    column pivoting (rows[a, pivots[a]] = 1, rows[a, pivots[b]] = 0 for b ≠ a), snapped within ``atol``
    (module docstring)."""
    r = V.shape[1]
    _, _, perm = sla.qr(V.T, pivoting=True, mode="economic")
    piv = np.sort(perm[:r])
    rows = np.linalg.solve(V[piv].T, V.T)
    rows = _snap(rows, atol)
    rows[:, piv] = np.eye(r)
    return rows, piv


@dataclass
class Frame:
    """x = T x′ with T = I + Σ_a (v_a − e_{p_a}) e_{p_a}ᵀ (module docstring).  directions: the rows v_a
    (r, N); pivots: p_a (r,), sorted; T and its inverse, sparse."""

    directions: np.ndarray
    pivots: np.ndarray
    T: sp.csc_array
    T_inv: sp.csc_array

    @classmethod
    def of(cls, directions: np.ndarray, pivots: np.ndarray) -> "Frame":
        n = directions.shape[1]
        pivots = np.asarray(pivots, dtype=np.int64)
        off = sp.coo_array(directions.T)  # (n, r): column a is v_a …
        keep = off.row != pivots[off.col]  # … minus e_{p_a} (v_a[p_a] = 1)
        off = sp.csc_array((off.data[keep], (off.row[keep], pivots[off.col[keep]])), shape=(n, n))
        eye = sp.eye_array(n, format="csc")
        return cls(directions, pivots, sp.csc_array(eye + off), sp.csc_array(eye - off))

    def congruent(self, A: sp.sparray) -> sp.coo_array:
        """TᵀAT with the entries that cancel to roundoff set to 0 (module docstring)."""
        return self.constraints([Constraint(sp.coo_array(A), 0.0)])[0].A

    def relaxation(self, Q: sp.sparray, constraints: Sequence[Constraint]) -> tuple[sp.coo_array, list[Constraint]]:
        """(TᵀQT, the constraints with TᵀAᵢT), in one ``constraints`` pass."""
        out = self.constraints([Constraint(sp.coo_array(Q), 0.0), *constraints])
        return out[0].A, out[1:]

    def constraints(self, constraints: Sequence[Constraint]) -> list[Constraint]:
        """Each constraint with A replaced by TᵀAT (``congruent``), all in one sparse product:
        vec(TᵀAT) = (T ⊗ T)ᵀ vec(A) row by row of the stacked vec(Aᵢ)ᵀ."""
        n = self.T.shape[0]
        As, _ = stack(constraints)
        r, c, v, owner = entries(As)
        m = len(As)
        stacked = sp.csr_array((v, (owner, r * n + c)), shape=(m, n * n))
        K = sp.csr_array(sp.kron(self.T, self.T, format="csr"))
        out = sp.csr_array(stacked @ K)
        size = sp.csr_array(abs(stacked) @ abs(K))
        size.sort_indices()
        out.sort_indices()
        # out's pattern lies within size's (same products, magnitudes summed): align by (row, column)
        key_out = np.repeat(np.arange(m), np.diff(out.indptr)) * (n * n) + out.indices
        key_size = np.repeat(np.arange(m), np.diff(size.indptr)) * (n * n) + size.indices
        mag = size.data[np.searchsorted(key_size, key_out)]
        keep = np.abs(out.data) > CANCEL_ULPS * np.finfo(float).eps * mag
        rows = np.repeat(np.arange(m), np.diff(out.indptr))[keep]
        cols, vals = out.indices[keep], out.data[keep]
        cuts = np.searchsorted(rows, np.arange(m + 1))
        return [replace(con, A=sp.coo_array((vals[a:b], (cols[a:b] // n, cols[a:b] % n)), shape=(n, n)))
                for con, a, b in zip(constraints, cuts[:-1], cuts[1:])]

    def point(self, theta: np.ndarray) -> np.ndarray:
        """Θ′ with x′ = T⁻¹x for each row x of Θ ((d, N) or (N,))."""
        Th = np.atleast_2d(np.asarray(theta, dtype=float))
        return np.asarray(self.T_inv @ Th.T).T.reshape(np.shape(theta))

    def describe(self, names: Sequence[str] | None = None) -> str:
        """The directions as combinations of columns, e.g. 't.x − z0.x − z1.x'."""
        def name(j: int) -> str:
            return names[j] if names is not None else f"x[{j}]"

        def term(j: int, c: float, first: bool) -> str:
            mag = "" if abs(abs(c) - 1) < 1e-12 else f"{Fraction(abs(c)).limit_denominator(SNAP_DENOMINATOR)}·"
            sign = ("−" if c < 0 else "") if first else (" − " if c < 0 else " + ")
            return f"{sign}{mag}{name(j)}"

        out = []
        for v in self.directions:
            nz = np.flatnonzero(v)
            out.append("".join(term(int(j), float(v[j]), k == 0) for k, j in enumerate(nz)))
        return "; ".join(out)


def _reduced(Nh: np.ndarray, As: Sequence[sp.sparray]) -> np.ndarray:
    """(m, r, r): NₕᵀAᵢNₕ for every Aᵢ, from their stacked entries in one pass."""
    r, c, v, owner = entries(As)
    k = Nh.shape[1]
    W = (v[:, None, None] * Nh[r][:, :, None] * Nh[c][:, None, :]).reshape(-1, k * k)
    S = sp.csr_array((np.ones(owner.size), (owner, np.arange(owner.size))), shape=(len(As), owner.size))
    return np.asarray(S @ W).reshape(len(As), k, k)


def null_dimension(w: np.ndarray) -> int:
    """The dimension of H's near-null space from its eigenvalues w: the count r < N of smallest |wᵢ| at
    the largest ratio |w|₍r₎/|w|₍r−1₎ (sorted ascending, both raised to the roundoff floor N·ε·max|w|), when
    that ratio is at least ``NULL_GAP``, among the counts whose |wᵢ| are all at most ``NULL_RTOL``·max|w|
    (a gap between larger ones separates two parts of H's range, not its null space); else 0."""
    a = np.sort(np.abs(w))
    if a.size < 2:
        return 0
    floor = a.size * np.finfo(float).eps * max(a[-1], 1e-300)  # roundoff: gaps below it are not gaps
    ratio = np.maximum(a[1:], floor) / np.maximum(a[:-1], floor)
    ratio[a[:-1] > NULL_RTOL * a[-1]] = 0.0
    i = int(np.argmax(ratio))
    return i + 1 if ratio[i] >= NULL_GAP else 0


def gap_counts(S: np.ndarray, rtol: float) -> list[int]:
    """Candidate counts k of significant values S (descending, ≥ 0): the count above ``rtol`` of the
    largest, then the counts at the largest gaps S[k−1]/S[k] ≥ ``MIN_GAP``, largest first, without repeats,
    ``MAX_TRIES`` in all."""
    if not S.size or S[0] <= 0:
        return [0]
    out = [int(np.sum(S > rtol * S[0]))]
    ratio = S[:-1] / np.maximum(S[1:], 1e-300 * S[0])
    for i in np.argsort(-ratio):
        if ratio[i] < MIN_GAP or len(out) >= MAX_TRIES:
            break
        if i + 1 not in out:
            out.append(int(i + 1))
    return out


def recession_directions(Q: sp.sparray, constraints: Sequence[Constraint], y: np.ndarray, *,
                         max_n: int = RECESSION_MAX_N) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Candidates (rows, pivots): a basis (r, N) of the span of the zero-cost recession cone inside the null
    space of H(y) (module docstring), in reduced row-echelon form and snapped, and its pivot columns (sorted),
    one per candidate count of reduced relations (``gap_counts``) and rank of D; none when N > max_n, H(y) has no
    null space beyond x̂, or the small SDP fails."""
    from . import sdp
    from .certificate import dual_matrix
    from .sdp.config import SolverConfig
    from .sdp.options import ClarabelOptions

    n = Q.shape[0]
    if n > max_n:
        return
    As, _ = stack(constraints)
    w, U = np.linalg.eigh(dual_matrix(Q, As, y).toarray())
    r = null_dimension(w)
    if r < 2:  # x̂ alone, or no gap
        return
    Nh = U[:, np.argsort(np.abs(w))[:r]]
    rows = np.array([svec(B) for B in _reduced(Nh, [*As, sp.coo_array(Q)])])  # (m + 1, r(r + 1)/2)
    _, S, Vt = np.linalg.svd(rows, full_matrices=False)
    eye = sp.eye_array(r, format="coo")
    config = SolverConfig(backend="clarabel", decompose=False, clarabel=ClarabelOptions(chordal=False))
    for k in gap_counts(S, RELATION_RTOL):
        reduced = [Constraint(sp.coo_array(smat(Vt[j], r)), 0.0, name=f"reduced relation {j}") for j in range(k)]
        res = sdp.solve(eye / r, reduced + [Constraint(eye, 1.0, name="trace")], d=1, config=config)
        if res.X is None or not res.usable:
            continue
        X = res.X
        M = X.toarray() if isinstance(X, sp.sparray) else np.asarray(X, dtype=float)
        wd, Ud = np.linalg.eigh(Nh @ ((M + M.T) / 2) @ Nh.T)
        wd, Ud = wd[::-1], Ud[:, ::-1]  # descending
        if wd[0] > 0:
            for rank in gap_counts(wd[:r], RANGE_RTOL):
                if rank:
                    yield echelon(Ud[:, :rank])


def recession_frame(Q: sp.sparray, constraints: Sequence[Constraint], y: np.ndarray, *, max_n: int = RECESSION_MAX_N
                    ) -> tuple[Frame, sp.coo_array, list[Constraint]] | None:
    """(frame, TᵀQT, the constraints in it): the frame whose columns include the relaxation's recession
    directions in H(y)'s null space (module docstring), keeping the directions that are recession
    columns there: of all candidates (``recession_directions``), the one with the most; None when there
    is none."""
    best: tuple[Frame, sp.coo_array, list[Constraint]] | None = None
    for V, piv in recession_directions(Q, constraints, y, max_n=max_n):
        for _ in range(2):  # the second pass only without the directions the first found inexact
            frame = Frame.of(V, piv)
            Qf, cons_f = frame.relaxation(Q, constraints)
            J = recession_columns(Qf, entries(stack(cons_f)[0]))
            ok = np.isin(piv, J) & (np.count_nonzero(V, axis=1) > 1)  # single columns: recession columns already
            if not ok.any():
                break
            if ok.all():
                if best is None or piv.size > best[0].pivots.size:
                    best = (frame, Qf, cons_f)
                break
            V, piv = V[ok], piv[ok]
    return best


def frame_certificate(Q: sp.sparray, constraints: Sequence[Constraint], y: np.ndarray, theta_hat: np.ndarray,
                      cert, *, d: int = 1, tol: float = 1e-6, floor: float = 1e-12,
                      names: Sequence[str] | None = None, more: Sequence[np.ndarray] = ()):
    """(y, its Certificate, a note, the columns set aside, (Q′, constraints′, Θ̂′)) from the certificate on the
    face of the forced columns in the frame of the recession directions, with y polished onto that face
    (``face.forced_face``, no SDP) or, where that does not certify, from the face's own dual
    (``face.face_dual``, one SDP on the other columns); None where it does not certify or ``cert`` does.
    The certificate is that frame's: the same y and bᵀy, so the same bound on the QCQP (module
    docstring); its ``face`` names the directions.  more: other multipliers whose H's null space may show
    the directions where y's does not (the solver's own, before a polish)."""
    from .certificate import certificate
    from .face import face_dual, forced_face, forced_why

    got = None
    for yd in (y, *more):  # the directions from y's null space, else from the others'
        got = recession_frame(Q, constraints, yd)
        if got is not None:
            break
    if got is None:
        return None
    frame, Qf, cons_f = got
    Th_f = frame.point(theta_hat)
    As_f = stack(cons_f)[0]
    forced = forced_face(Qf, As_f, y, Th_f)
    if forced is None or cert.certified:
        return None
    yf, free = forced
    how = cert.method.split(";")[0]
    cf = certificate(Qf, cons_f, yf, Th_f, d=d, tol=tol, floor=floor, free=free,
                     method=how + ", on the face of the forced columns")
    if not cf.certified:  # the face's own dual, once (one SDP on the other columns)
        dual = face_dual(Qf, cons_f, free, d=d)
        if dual is None:
            return None
        yf = dual[0]
        cf = certificate(Qf, cons_f, yf, Th_f, d=d, tol=tol, floor=floor, free=free, method=f"{how}, from {dual[1]}")
        if not cf.certified:
            return None
    cf.face = forced_why(Qf, As_f, free, cf)
    r = frame.pivots.size
    cf.face = (f"{r} recession direction(s) set aside, combinations of columns along which X grows at no cost "
               f"({frame.describe(names)}); certified in the frame x = T x′ whose columns they are"
               + (f"; {cf.face}" if cf.face else ""))
    cf.assumptions += "; H vanishes on the recession directions (in their frame)"
    note = f"certified in the frame of {r} recession direction(s) ({cf.argument})"
    return yf, cf, note, free, (Qf, cons_f, Th_f)
