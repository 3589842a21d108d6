"""The face of the bounded columns: multipliers that set aside the columns nothing bounds.

Free columns F (``free_columns``): the largest set found by the fixed point "a column on which the cost
has no entry, and neither the cost nor any constraint that touches no column of F has a diagonal
entry".  It starts from the recession columns (``certificate.recession_columns``) and grows when a
column's only diagonal entries lie in constraints that touch F.

Argument (face).  Fix the multipliers of the constraints touching F at 0 (``face_multipliers``).
Then H = Q − Σ yᵢAᵢ vanishes on the rows and columns of F, and every dual bound on the face (the
relaxation on the other columns K, with the constraints that do not touch F) is a lower bound for
the QCQP.
  Proof: Q and every Aᵢ with yᵢ ≠ 0 vanish on F, so ⟨H, X⟩ = ⟨H_KK, X_KK⟩ for every X; any argument of
  ``certificate`` (H_KK ⪰ 0, trace bound on K, strict dual) then applies to X_KK alone.
The multipliers of the other constraints are moved by the least change (2-norm) onto stationarity at
x̂, H(y)Θ̂ᵀ = 0, with those of F's constraints held at 0; whether they prove anything is the
certificate's to say.  Such y exists exactly when the relaxation on the face is tight at x̂ with
the constraints that do not touch F.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .certificate import entries, recession_columns, stationarity_system
from .lstsq import min_norm_lstsq


@dataclass
class Face:
    """free: the columns F set aside (sorted); touching: the constraints touching F (their multipliers
    are 0 on the face); kept: the other constraints."""

    free: np.ndarray
    touching: np.ndarray
    kept: np.ndarray


def free_columns(Q: sp.sparray, As: Sequence[sp.sparray]) -> Face:
    """The fixed point of the module docstring (at most N passes; usually one or two)."""
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
    others moved by the least change onto H(y)Θ̂ᵀ = 0 (module docstring); None when F is empty."""
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
    """(y, its Certificate, a note): the multipliers on the face (``face_multipliers``) and their
    certificate when it certifies and ``cert`` (that of y) does not; else (y, cert, "")."""
    from .certificate import certificate, stack

    As, _ = stack(constraints)
    got = face_multipliers(Q, As, y, theta_hat)
    if got is None or not np.all(np.isfinite(got[0])):
        return y, cert, ""
    yf, face = got
    cf = certificate(Q, constraints, yf, np.asarray(theta_hat, dtype=float).reshape(d, -1), d=d, tol=tol,
                     floor=floor, trace=trace, method=cert.method.split(";")[0] + ", on the face")
    if not (cf.certified and not cert.certified):  # kept only where it proves what y does not
        return y, cert, ""
    why = (f"{face.free.size} column(s) set aside: the cost has no entry on them and no constraint that "
           f"leaves them out has a diagonal entry there; the multipliers of the {face.touching.size} "
           "constraint(s) touching them are 0, so H vanishes there")
    cf.face = why
    cf.assumptions += "; multipliers 0 on the constraints touching the columns set aside"
    return yf, cf, f"set on the face of the bounded columns ({face.free.size} free, {face.touching.size} multipliers 0)"
