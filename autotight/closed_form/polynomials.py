"""Polynomials in a factor's measurement entries δ: a reduced monomial basis, exact fits and evaluation.

A monomial of δ (p entries) is a sorted index tuple: ``()`` is 1, ``(i,)`` is δ_i, ``(i, j)`` is δ_i δ_j
(i ≤ j), and so on up to degree 3.  The data of a factor type usually satisfy identities (a measured
rotation has C̃ᵀC̃ = I and c̃₁ × c̃₂ = c̃₃), so the monomials are linearly dependent on the data; the
*reduced basis* keeps a monomial only when it is independent of the ones before it (lower degree first,
then lexicographic), measured on sampled data.  A polynomial written in the reduced basis is unique,
which is what makes equal families print equally.

Exact coefficients: every fitted coefficient is replaced by the nearest fraction with denominator at
most ``MAX_DENOMINATOR`` (``fractions.Fraction.limit_denominator``), and the fraction form is kept only
when its residual on data that took no part in the fit is below ``EXACT_RTOL`` (relative to the largest
coefficient of each sample).
"""

from __future__ import annotations

from fractions import Fraction
from itertools import combinations_with_replacement
from typing import Sequence

import numpy as np

#: largest denominator of an exact coefficient
MAX_DENOMINATOR = 720
#: a fit (float or exact) is accepted when its largest relative residual on held-out data is below this
FIT_RTOL = 1e-9
#: an exact (fraction) form must reproduce the sampled relations to this relative accuracy (that of the
#: templates it is fitted to; the exact form is then checked on its own, on feasible states)
EXACT_RTOL = 1e-9
#: a monomial joins the reduced basis when its component orthogonal to the earlier ones keeps this
#: fraction of its norm on the sampled data
INDEPENDENCE_TOL = 1e-7

Monomial = tuple[int, ...]


def monomials(p: int, degree: int) -> list[Monomial]:
    """Every monomial of p entries up to ``degree``, lower degree first, lexicographic within a degree."""
    return [m for g in range(degree + 1) for m in combinations_with_replacement(range(p), g)]


def evaluate(D: np.ndarray, monos: Sequence[Monomial]) -> np.ndarray:
    """Φ (S, F): each monomial at each row of D (S, p)."""
    D = np.atleast_2d(np.asarray(D, dtype=float))
    out = np.ones((D.shape[0], len(monos)))
    for k, m in enumerate(monos):
        for i in m:
            out[:, k] *= D[:, i]
    return out


def reduced_basis(D: np.ndarray, degree: int) -> list[Monomial]:
    """The monomials up to ``degree`` that are independent on the sampled data D (S, p), in order."""
    monos = monomials(D.shape[1] if D.ndim == 2 else 0, degree)
    Phi = evaluate(D, monos)
    Phi = Phi / np.maximum(np.linalg.norm(Phi, axis=0), 1e-300)
    Q = np.zeros((Phi.shape[0], 0))
    keep: list[Monomial] = []
    for k, m in enumerate(monos):
        r = Phi[:, k].copy()
        for _ in range(2):  # Gram–Schmidt twice: stable to roundoff
            r -= Q @ (Q.T @ r)
        n = np.linalg.norm(r)
        if n > INDEPENDENCE_TOL:
            Q = np.column_stack([Q, r / n])
            keep.append(m)
    return keep


def relative_residual(pred: np.ndarray, Y: np.ndarray) -> float:
    """max over rows of max |pred − Y| / max |Y| (0 for an empty Y)."""
    if Y.size == 0:
        return 0.0
    return float(np.max(np.max(np.abs(pred - Y), axis=1) / np.maximum(np.max(np.abs(Y), axis=1), 1e-300)))


def to_fractions(W: np.ndarray) -> list[list[Fraction]]:
    """Each entry as the nearest fraction with denominator ≤ ``MAX_DENOMINATOR``."""
    return [[Fraction(float(x)).limit_denominator(MAX_DENOMINATOR) for x in row] for row in np.atleast_2d(W)]


def fractions_array(F: Sequence[Sequence[Fraction]]) -> np.ndarray:
    return np.array([[float(x) for x in row] for row in F], dtype=float)


class Fitter:
    """Least squares Y ≈ Φ(D) W in one basis, fitted on all but the last ``n_check`` rows of D (one QR for any
    number of right-hand sides); ``fit`` returns (W, held-out residual), or None when the held-out rows are
    off by more than ``FIT_RTOL`` or there are too few rows (fewer than 1.5 per basis monomial)."""

    def __init__(self, D: np.ndarray, basis: Sequence[Monomial], n_check: int):
        self.basis = list(basis)
        self.Phi = evaluate(D, basis)
        self.n_fit = D.shape[0] - n_check
        self.enough = self.n_fit >= 1.5 * len(basis)
        if self.enough:
            self.Q, self.R = np.linalg.qr(self.Phi[:self.n_fit])

    def fit(self, Y: np.ndarray) -> tuple[np.ndarray, float] | None:
        if not self.enough:
            return None
        W = np.linalg.lstsq(self.R, self.Q.T @ Y[:self.n_fit], rcond=None)[0]
        res = relative_residual(self.Phi[self.n_fit:] @ W, Y[self.n_fit:])
        return (W, res) if res <= FIT_RTOL else None


def exact(W: np.ndarray, D: np.ndarray, Y: np.ndarray, basis: Sequence[Monomial]) -> tuple[list[list[Fraction]] | None,
                                                                                      float]:
    """The fraction form of W when it reproduces Y on D to ``EXACT_RTOL``, or to 10 times the float fit's own
    residual when the sampled relations are less accurate than that (a polynomial template holds to its fit
    accuracy, 1e-9; the float fit follows its errors, the fractions do not) (else None), and its residual."""
    Phi = evaluate(D, basis)
    F = to_fractions(W)
    res = relative_residual(Phi @ fractions_array(F), Y)
    return (F if res <= max(EXACT_RTOL, 10 * relative_residual(Phi @ W, Y)) else None), res
