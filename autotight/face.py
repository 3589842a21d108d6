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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .certificate import (FREE_ATOL, dual_matrix, entries, polish_dual, recession_columns,
                          stationarity_system)
from .lstsq import min_norm_lstsq


@dataclass
class Face:
    """free: the columns F set aside (sorted); touching: the constraints touching F (their multipliers
    are 0 on the face); kept: the other constraints."""

    free: np.ndarray
    touching: np.ndarray
    kept: np.ndarray


#: rounds of ``forced_face`` at most (each adds at least one column; one or two suffice on stereo)
MAX_ROUNDS = 8


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
        new[F] = False
        if not new.any():
            break
        F = np.union1d(F, np.flatnonzero(new))
    return y, F


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
            n_rec = recession_columns(Q, entries(As)).size
            cf.face = (f"{F.size} column(s) set aside: {n_rec} on which neither the cost nor any constraint has a "
                       f"diagonal entry, {F.size - n_rec} whose diagonal of H the stationarity and H = 0 on those "
                       f"forces to 0; H vanishes on them to {cf.free_residual:.1e} of max |H|")
            return yf, cf, f"set on the face of the bounded columns ({F.size} free, H vanishes there)", F
    got = face_multipliers(Q, As, y, Th)
    if got is None or not np.all(np.isfinite(got[0])):
        return y, cert, "", None
    yf, face = got
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
