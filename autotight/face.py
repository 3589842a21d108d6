"""The face of the bounded columns: multipliers that set aside the columns nothing bounds.

Argument (face).  If H = Q − Σ yᵢAᵢ vanishes on the rows (and so the columns) of a set F, then
⟨H, X⟩ = ⟨H_KK, X_KK⟩ for every X (K: the other columns), and every argument of ``certificate``
(H_KK ⪰ 0, trace bound on K, strict dual) applies to X_KK alone: the bound holds for the QCQP.
  Proof: every term H_jk X_jk with j or k in F is 0.
Soundness needs only that H vanish on F (``certificate`` checks it, to ``FREE_ATOL``·max|H|); how F
was found decides whether a certificate exists, never whether it is valid.  Two ways, tried in turn
by ``face_certificate``:

1. Forced columns (``forced_face``).  Start from the recession columns J (no diagonal entry in the cost
   or any constraint: every dual feasible H has H_J· = 0).  Move y by the least change onto
   H(y)Θ̂ᵀ = 0 and H(y)_J· = 0 (``certificate.polish_dual``).  A column j ∉ J on which H_jj is then 0
   (to ``FREE_ATOL``·max|H|) while its row is not is forced free: its diagonal entries all lie in
   combinations of the constraints that H_J· = 0 already fixes (stereo's t_x, whose only diagonal
   entries cancel once the rows of t_y and u tᵀ vanish), and H ⪰ 0 with H_jj = 0 needs H_j· = 0.
   Add it to J and polish again, until no column is added.  Multipliers of constraints that touch J
   may stay nonzero: H vanishes on J by cancellation.
2. Zero multipliers (``free_columns``, ``face_multipliers``).  F: the largest set found by the fixed
   point "a column on which the cost has no entry, and neither the cost nor any constraint that
   touches no column of F has a diagonal entry"; the multipliers of the constraints touching F are
   fixed at 0 and the others moved by the least change onto H(y)Θ̂ᵀ = 0.

Either face exists (a y with H(y)Θ̂ᵀ = 0 and H_F· = 0) exactly when the relaxation restricted to
the columns K is tight at x̂; whether the multipliers prove it is the certificate's to say.

Multipliers on the face (``face_dual``).  The SDP's own y is poor where columns are free: the primal
optimal set is unbounded along X_FF, every dual feasible H has H_F· = 0 (no strictly feasible dual),
and an interior-point solve stops early (stereo-2D's learned set: AlmostSolved, bᵀy above f(x̂) by
1.6e-3 relative); the least change onto the face then lands far from H ⪰ 0.  The face's own dual
is solved instead (facial reduction).  Write y = y₀ + N z with H(y₀)_F· = 0 and N a basis of the
multipliers that leave H_F· unchanged (the constraints that touch no column of F, and the null space
of the others' entries on F); then H(y) = H(y₀) − Σⱼ zⱼ Ãⱼ with Ãⱼ = Σᵢ Nᵢⱼ Aᵢ, all zero on F, and
bᵀy = bᵀy₀ + (Nᵀb)ᵀz.  So max bᵀy s.t. H(y) ⪰ 0, H_F· = 0 is the SDP on the columns K
    max (Nᵀb)ᵀz  s.t.  H(y₀)_KK − Σⱼ zⱼ (Ãⱼ)_KK ⪰ 0,
whose primal min ⟨H(y₀)_KK, X⟩ s.t. ⟨(Ãⱼ)_KK, X⟩ = (Nᵀb)ⱼ, X ⪰ 0 has the rank-1 point Θ̂_K and a
bounded optimal set.  Its z gives y = y₀ + N z, which ``certificate`` then judges (nothing about
this solve is trusted: only H(y)_F· = 0 and the argument on K are).  Where that y leaves H_jj = 0 on
some column j of K (``zero_diagonal``), j is free on the face too (its X_jj grew to ~1e6 in that
solve): it joins F and the face's dual is solved again (facial reduction, one more step).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from .certificate import (FREE_ATOL, dual_matrix, entries, polish_dual, recession_columns,
                          stationarity_system)
from .lstsq import min_norm_lstsq


#: ``face_dual`` works densely: at most this many constraints touching the face, and at most this many
#: entries in its matrix of directions × |K|² (1.6e8 bytes)
FACE_DUAL_MAX_TOUCHING = 3000
FACE_DUAL_MAX_ENTRIES = 20_000_000
#: a reduced constraint counts as zero (a linear dependence of the Aᵢ) below this multiple of the largest
DEPENDENT_RTOL = 1e-6


@dataclass
class Face:
    """free: the columns F set aside (sorted); touching: the constraints touching F (their multipliers
    are 0 on the face); kept: the other constraints."""

    free: np.ndarray
    touching: np.ndarray
    kept: np.ndarray


@dataclass
class FaceSystem:
    """The equations H(y)_F· = 0: GF y_T = gF over the constraints T touching F (one row per entry (j, k),
    j ∈ F, of some Aᵢ or Q), with GF's SVD (U, S, Vt) and its rank above ``DEPENDENT_RTOL``·S₀.
    y0T: the least-norm solution on GF's range; null: a basis of GF's (near-)null space, (|T|, nullity)."""

    T: np.ndarray
    GF: np.ndarray
    gF: np.ndarray
    U: np.ndarray
    S: np.ndarray
    Vt: np.ndarray
    rank: int

    def onto(self, yT: np.ndarray) -> np.ndarray:
        """yT moved by the least change onto GF yT = gF along GF's range."""
        k = self.rank
        return yT + self.Vt[:k].T @ ((self.U[:, :k].T @ (self.gF - self.GF @ yT)) / self.S[:k])

    @property
    def y0T(self) -> np.ndarray:
        return self.onto(np.zeros(self.T.size))

    @property
    def null(self) -> np.ndarray:
        return self.Vt[self.rank:].T

    def consistent(self) -> bool:
        """Whether some y makes H vanish on F (to 1e-9 of the system's scale)."""
        if not self.T.size:
            return not np.any(self.gF)
        return bool(np.linalg.norm(self.GF @ self.y0T - self.gF) <= 1e-9 * max(np.linalg.norm(self.gF), self.S[0]))


def face_system(Q: sp.sparray, stacked: tuple[np.ndarray, ...], F: np.ndarray) -> FaceSystem:
    """The ``FaceSystem`` of F (``stacked`` = ``certificate.entries(As)``), dense in the touching constraints."""
    n = Q.shape[0]
    r, c, v, owner = stacked
    onF = np.isin(r, F)
    T = np.unique(owner[onF])
    Qc = sp.coo_array(Q)
    qF = np.isin(Qc.row, F)
    keys = np.concatenate([r[onF] * n + c[onF], Qc.row[qF] * n + Qc.col[qF]])
    uniq, inv = np.unique(keys, return_inverse=True)
    n_on = int(onF.sum())
    GF = np.zeros((uniq.size, T.size))
    np.add.at(GF, (inv[:n_on], np.searchsorted(T, owner[onF])), v[onF])
    gF = np.zeros(uniq.size)
    np.add.at(gF, inv[n_on:], Qc.data[qF])
    if T.size:
        U, S, Vt = np.linalg.svd(GF, full_matrices=True)
    else:
        U, S, Vt = np.zeros((uniq.size, 0)), np.zeros(0), np.zeros((0, 0))
    rank = int(np.sum(S > DEPENDENT_RTOL * S[0])) if S.size else 0
    return FaceSystem(T, GF, gF, U, S, Vt, rank)


def forced_columns(Q: sp.sparray, stacked: tuple[np.ndarray, ...], F: np.ndarray) -> np.ndarray:
    """The columns j ∉ F whose H_jj the equations H_F· = 0 fix at 0 whatever y (linear algebra, no y):
    no constraint off T has a diagonal entry at j, the diagonal functional of T's constraints at j lies in
    GF's row space, and its value there is 0 (to 1e-9 of its scale).  H ⪰ 0 then needs H_j· = 0."""
    if F.size == 0 or F.size >= Q.shape[0]:
        return np.zeros(0, dtype=np.int64)
    sys_ = face_system(Q, stacked, F)
    if not sys_.T.size or sys_.T.size > FACE_DUAL_MAX_TOUCHING or not sys_.consistent():
        return np.zeros(0, dtype=np.int64)
    r, c, v, owner = stacked
    n, m = Q.shape[0], int(owner.max()) + 1 if owner.size else 0
    on_diag = (r == c) & (v != 0)
    D = sp.csc_array((v[on_diag], (owner[on_diag], r[on_diag])), shape=(m, n))  # (constraint, column) → (Aᵢ)_jj
    inT = np.zeros(m, dtype=bool)
    inT[sys_.T] = True
    off_T = np.asarray(abs(D[~inT]).sum(axis=0)).ravel() if (~inT).any() else np.zeros(n)
    q_diag = sp.csr_array(Q).diagonal()
    DT = D[sys_.T].toarray()  # (|T|, n)
    on_null = np.linalg.norm(sys_.null.T @ DT, axis=0) if sys_.null.size else np.zeros(n)
    size = np.linalg.norm(DT, axis=0)
    value = q_diag - sys_.y0T @ DT
    scale = np.abs(q_diag) + size * np.linalg.norm(sys_.y0T) + float(abs(Q).max())
    forced = (off_T == 0) & (size > 0) & (on_null <= 1e-9 * size) & (np.abs(value) <= 1e-9 * scale)
    forced[F] = False
    return np.flatnonzero(forced)


#: rounds of ``forced_face`` at most (each adds at least one column; one or two suffice on stereo)
MAX_ROUNDS = 8


def zero_diagonal(H: sp.sparray) -> np.ndarray:
    """Columns j with |H_jj| ≤ ``FREE_ATOL``·max|H|: where H ⪰ 0 needs H_j· = 0 (sorted)."""
    top = float(abs(H).max()) if H.nnz else 0.0
    return np.flatnonzero(np.abs(sp.csr_array(H).diagonal()) <= FREE_ATOL * top) if top > 0 else np.zeros(0, int)


def forced_face(Q: sp.sparray, As: Sequence[sp.sparray], y: np.ndarray,
                theta_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(y on the face, the columns F set aside, sorted): way 1 of the module docstring; None when
    there are no recession columns to start from or y is not finite."""
    stacked = entries(As)
    F = recession_columns(Q, stacked)
    if F.size == 0:
        return None
    Th = np.atleast_2d(np.asarray(theta_hat, dtype=float))
    y = np.asarray(y, dtype=float)
    for _ in range(MAX_ROUNDS):
        y = polish_dual(Q, As, y, Th, free=F)
        if not np.all(np.isfinite(y)):
            return None
        H = dual_matrix(Q, As, y, stacked=stacked)
        top = float(abs(H).max()) if H.nnz else 0.0
        if top == 0.0:
            break
        diag = np.abs(H.diagonal())
        rowmax = np.asarray(abs(H).max(axis=0).todense()).ravel()
        new = (diag <= FREE_ATOL * top) & (rowmax > FREE_ATOL * top)
        new[forced_columns(Q, stacked, F)] = True  # what the equations force, whatever this y
        new[F] = False
        if not new.any():
            break
        F = np.union1d(F, np.flatnonzero(new))
    return y, F




def face_dual(Q: sp.sparray, constraints, F: np.ndarray, *, d: int = 1,
              scale: np.ndarray | None = None, config=None) -> tuple[np.ndarray, str] | None:
    """(y, the solve's note): multipliers with H(y)_F· = 0 from the SDP on the columns K off F
    (module docstring, facial reduction); y₀ is the least-norm y with H(y₀)_F· = 0 (not the SDP's
    own y, whose multipliers grow without bound along the face where no dual point is strictly
    feasible: stereo-2D, pairs of multipliers near ±10 cancelling on F to 1e-10).  The reduced
    constraints are the (Ãⱼ)_KK of a well-separated subset spanning them (``independent_rows``, each
    scaled to unit Frobenius norm), so near-dependent learned constraints give the solver no ill-posed
    rows and the solve keeps their sparsity; the final y is put back onto H_F· = 0 along GF's range.
    scale: the SDP's diagonal scaling D on all N columns (restricted to K here).  None when the dense work would exceed
    ``FACE_DUAL_MAX_TOUCHING`` or ``FACE_DUAL_MAX_ENTRIES``, no y makes H vanish on F, or the solve
    returns no finite multipliers."""
    from . import sdp
    from .certificate import stack
    from .model import Constraint

    As, b = stack(constraints)
    n, m = Q.shape[0], len(As)
    F = np.asarray(F, dtype=np.int64)
    K = np.setdiff1d(np.arange(n), F)
    stacked = r, c, v, owner = entries(As)
    T = np.unique(owner[np.isin(r, F)])  # the constraints touching F
    if T.size > FACE_DUAL_MAX_TOUCHING or m * K.size ** 2 > FACE_DUAL_MAX_ENTRIES:
        return None
    y0 = np.zeros(m)
    keep = np.setdiff1d(np.arange(m), T)
    P = sp.csc_array((np.ones(keep.size), (keep, np.arange(keep.size))), shape=(m, keep.size))
    system = face_system(Q, stacked, F)
    if T.size:  # y₀ and the null space N_T of the touching constraints' entries on F, from one SVD
        if not system.consistent():
            return None  # no y makes H vanish on F
        y0[T] = system.y0T
        NT = system.null  # (|T|, nullity)
        rows, cols = np.repeat(T, NT.shape[1]), np.tile(np.arange(NT.shape[1]), T.size)
        P = sp.hstack([P, sp.csc_array((NT.ravel(), (rows, cols)), shape=(m, NT.shape[1]))], format="csc")
    Kpos = np.full(n, -1)
    Kpos[K] = np.arange(K.size)
    sel = (Kpos[r] >= 0) & (Kpos[c] >= 0)
    A_K = sp.csr_array((v[sel], (owner[sel], Kpos[r[sel]] * K.size + Kpos[c[sel]])), shape=(m, K.size ** 2))
    R = sp.csr_array(P.T @ A_K)  # (p, |K|²): each direction's entries on K
    sel, norms = independent_rows(R)
    W = P[:, sel] / norms  # (m, kr): y = y₀ + W z moves H by −Σ zⱼ (row sel[j] of R, unit norm)
    bw = np.asarray(W.T @ b).ravel()
    rows = sp.csr_array(R[sel] / norms[:, None])
    reduced = [Constraint(sp.coo_array(rows[[j]].reshape((K.size, K.size))), float(bw[j]),
                          name=f"face direction {j}", family="learned") for j in range(sel.size)]
    Qr = sp.csr_array(dual_matrix(Q, As, y0))[K][:, K]
    res = sdp.solve(Qr, reduced, d=d, config=config, scale=None if scale is None else scale[K])
    if res.y is None or not np.all(np.isfinite(res.y)):
        return None
    out = y0 + np.asarray(W @ np.asarray(res.y, dtype=float)).ravel()
    if T.size:  # back onto H_F· = 0 on GF's range (z can be large where the reduced constraints are small);
        # not along GF's near-null directions (singular values below DEPENDENT_RTOL, learned relations that
        # cancel on F to ~1e-11): that moves H_KK by far more (test module: 2e-5 against a cost of 2e-5;
        # stereo-2D: λ_min(H_KK) to −9e-4)
        out[T] = system.onto(out[T])
    return out, f"the SDP on the {K.size} columns off the {F.size} set aside ({res.solver} {res.status})"


def independent_rows(R: sp.csr_array) -> tuple[np.ndarray, np.ndarray]:
    """(rows, their Frobenius norms): a subset of R's nonzero rows spanning its row space, chosen by a QR
    with column pivoting of the normalised rows (a pivot counts while |R_kk| > ``DEPENDENT_RTOL``·|R_00|).
    Selected rows keep the constraints' sparsity, where an orthonormal basis of the span is dense and
    makes the solve an order of magnitude slower; the pivoting keeps them far from dependent, so the
    solver gets no ill-posed rows.  R must fit densely (``face_dual`` checks its size first)."""
    norms = np.sqrt(np.asarray(R.multiply(R).sum(axis=1)).ravel())
    nz = np.flatnonzero(norms > 0)
    if nz.size == 0:
        return nz, norms[nz]
    G = np.asarray((R[nz] / norms[nz][:, None]).T.todense())  # (|K|², rows): the rows as columns
    _, Rq, piv = scipy.linalg.qr(G, mode="economic", pivoting=True)
    d = np.abs(np.diag(Rq))
    k = int(np.sum(d > DEPENDENT_RTOL * d[0])) if d[0] > 0 else 0
    sel = np.sort(nz[piv[:k]])
    return sel, norms[sel]


def free_columns(Q: sp.sparray, As: Sequence[sp.sparray]) -> Face:
    """The fixed point of way 2 of the module docstring (at most N passes; usually one or two)."""
    Qc = sp.coo_array(Q)
    stacked = r, c, v, owner = entries(As)
    n = Q.shape[0]
    on_cost = np.zeros(n, dtype=bool)
    on_cost[Qc.row[Qc.data != 0]] = True
    F = np.setdiff1d(recession_columns(Q, stacked), np.flatnonzero(on_cost))
    q_diag = np.zeros(n, dtype=bool)
    q_diag[Qc.row[(Qc.row == Qc.col) & (Qc.data != 0)]] = True
    touching = np.zeros(0, dtype=np.int64)
    for _ in range(n):
        touching = np.unique(owner[np.isin(r, F) | np.isin(c, F)])
        keep = ~np.isin(owner, touching)
        diag = q_diag.copy()
        sel = keep & (r == c) & (v != 0)
        diag[r[sel]] = True
        F_new = np.flatnonzero(~diag & ~on_cost)
        if np.array_equal(F_new, F):
            break
        F = F_new
    kept = np.setdiff1d(np.arange(len(As)), touching)
    return Face(F, touching, kept)


def face_multipliers(Q: sp.sparray, As: Sequence[sp.sparray], y: np.ndarray, theta_hat: np.ndarray,
                     face: Face | None = None) -> tuple[np.ndarray, Face] | None:
    """(y on the face, the face): y with the multipliers of the constraints touching F at 0 and the
    others moved by the least change onto H(y)Θ̂ᵀ = 0 (way 2 of the module docstring); None when F is
    empty."""
    face = free_columns(Q, As) if face is None else face
    if face.free.size == 0:
        return None
    Th = np.atleast_2d(np.asarray(theta_hat, dtype=float))
    out = np.array(y, dtype=float)
    out[face.touching] = 0.0
    kept_As = [As[i] for i in face.kept]
    G, g = stationarity_system(Q, kept_As, Th)
    yk = out[face.kept]
    out[face.kept] = yk + min_norm_lstsq(G, g - G @ yk)
    return out, face


def face_certificate(Q: sp.sparray, constraints, y: np.ndarray, theta_hat: np.ndarray, cert, *, d: int = 1,
                     tol: float = 1e-6, floor: float = 1e-12, trace: float | None = None):
    """(y, its Certificate, a note, F): the multipliers on the first face of the module docstring whose
    certificate certifies where ``cert`` (that of y) does not, and the columns F it set aside (pass them
    as ``free`` to any later ``certificate`` of a y on that face); else (y, cert, "", None)."""
    from .certificate import certificate, stack

    As, _ = stack(constraints)
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    how = cert.method.split(";")[0]
    forced = forced_face(Q, As, y, Th)
    if forced is not None:
        yf, F = forced
        cf = certificate(Q, constraints, yf, Th, d=d, tol=tol, floor=floor, trace=trace, free=F,
                         method=how + ", on the face of the forced columns")
        if cf.certified and not cert.certified:
            cf.face = forced_why(Q, As, F, cf)
            return yf, cf, f"set on the face of the bounded columns ({F.size} free, H vanishes there)", F
    for _ in range(MAX_ROUNDS if forced is not None else 0):  # the face's own dual (facial reduction)
        got = face_dual(Q, constraints, F, d=d)
        if got is None:
            break
        yd = got[0]  # not polished onto stationarity: that system is consistent only along directions
        # that move H_KK off ⪰ 0 (learned constraints hold at x̂ to ~1e-12 of ‖Aᵢ‖, not exactly)
        cf = certificate(Q, constraints, yd, Th, d=d, tol=tol, floor=floor, trace=trace, free=F,
                         method=how + f", from {got[1]}")
        if cf.certified and not cert.certified:
            cf.face = forced_why(Q, As, F, cf)
            return yd, cf, f"solved on the face of the bounded columns ({F.size} free, H vanishes there)", F
        grown = np.union1d(F, zero_diagonal(dual_matrix(Q, As, yd)))
        if grown.size == F.size:
            break
        F = grown  # columns the face's optimal H leaves at H_jj = 0: free on the face too; solve again
    multipliers = face_multipliers(Q, As, y, Th)
    if multipliers is None or not np.all(np.isfinite(multipliers[0])):
        return y, cert, "", None
    yf, face = multipliers
    cf = certificate(Q, constraints, yf, Th, d=d, tol=tol, floor=floor, trace=trace,
                     method=how + ", on the face")
    if not (cf.certified and not cert.certified):  # kept only where it proves what y does not
        return y, cert, "", None
    why = (f"{face.free.size} column(s) set aside: the cost has no entry on them and no constraint that "
           f"leaves them out has a diagonal entry there; the multipliers of the {face.touching.size} "
           "constraint(s) touching them are 0, so H vanishes there")
    cf.face = why
    cf.assumptions += "; multipliers 0 on the constraints touching the columns set aside"
    note = f"set on the face of the bounded columns ({face.free.size} free, {face.touching.size} multipliers 0)"
    return yf, cf, note, face.free


def forced_why(Q: sp.sparray, As: Sequence[sp.sparray], F: np.ndarray, cert) -> str:
    """The certificate's ``face`` text for a face of ``forced_face``."""
    n_rec = recession_columns(Q, entries(As)).size
    return (f"{F.size} column(s) set aside: {n_rec} on which neither the cost nor any constraint has a diagonal "
            f"entry, {F.size - n_rec} whose diagonal of H the vanishing of those rows and stationarity force to 0; "
            f"H vanishes on them to {cert.free_residual:.1e} of max |H|")
