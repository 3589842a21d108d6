"""The closed form of one family: a relation of a factor type as exact polynomials in the factor's data.

A family (a discovered ``(factor type, identity)`` pair, or one row of a paper family) gives, on a factor
with data δ, a relation v(δ) over the factor's monomials.  Its closed form is

    u(δ) = NF(v(δ)) / NF(v(δ))[μ₀],

NF the normal form modulo the primary constraints (``samples``) and μ₀ the first monomial (svec order)
for which u is a polynomial in δ of the lowest degree (≤ ``MAX_DEGREE``) in the reduced monomial basis
(``polynomials``).  Both choices depend only on the family's line modulo the primary constraints, so two
families that are equal modulo the primary constraints have the same closed form.  The coefficients are
exact fractions when they reproduce held-out factors to ``EXACT_RTOL``; otherwise the closed form is kept
in floating point and says so, and a family whose u fits no polynomial has no closed form (the reason is
kept).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from . import polynomials as poly
from .samples import FactorSamples

#: highest degree in δ tried
MAX_DEGREE = 3
#: factors kept aside to check each fit
N_CHECK = 40


@dataclass
class ClosedForm:
    """u = Σ_μ (Σ_k coeffs[μ][k] · basis[k](δ)) · monomial μ, over ``monomials`` (positions in the factor's
    svec order); ``exact``: the coefficients are fractions verified to ``EXACT_RTOL`` (``residual``: the
    largest relative residual on held-out factors).  ``why``: why there is none (then ``monomials`` is
    empty)."""

    name: str
    factor_type: str
    monomials: list[int]
    basis: list[poly.Monomial]
    coeffs: list[list[Fraction]] | None
    W: np.ndarray | None
    normaliser: int | None
    degree: int | None
    residual: float
    exact: bool
    why: str = ""

    @property
    def found(self) -> bool:
        return self.W is not None

    def values(self, D: np.ndarray, m: int) -> np.ndarray:
        """u at data D (S, p) as full coefficient vectors (S, m), from the exact coefficients when there are."""
        W = poly.fractions_array(self.coeffs) if self.exact and self.coeffs is not None else self.W
        assert W is not None, "values() of a family without a closed form"
        out = np.zeros((np.atleast_2d(D).shape[0], m))
        out[:, self.monomials] = poly.evaluate(D, self.basis) @ W
        return out


def closed_form(name: str, fs: FactorSamples, V: np.ndarray) -> ClosedForm:
    """The closed form of relations V (S, m), one per factor of ``fs`` (NaN rows are left out)."""
    ok = np.all(np.isfinite(V), axis=1)
    N = fs.normal_form(V[ok])
    D = fs.D[ok]
    scale = np.maximum(np.max(np.abs(N), axis=1, keepdims=True), 1e-300)
    N = np.where(np.abs(N) < 1e-11 * scale, 0.0, N)
    support = np.flatnonzero(np.any(N != 0, axis=0))
    if support.size == 0:
        return ClosedForm(name, fs.factor_type, [], [], None, None, None, None, 0.0, False,
                          "it is a combination of the primary constraints (normal form 0)")
    candidates = [mu for mu in support if np.all(np.abs(N[:, mu]) > 1e-9 * scale[:, 0])]
    p = D.shape[1]
    last = "no monomial of the family has a coefficient that is never 0"
    for g in range(MAX_DEGREE + 1 if p else 1):
        if D.shape[0] - N_CHECK < 1.5 * len(poly.monomials(p, g)) and g > 0:
            last += f" (degree {g} was not tried: it needs more than the {D.shape[0]} factors sampled)"
            break
        basis = poly.reduced_basis(D, g)
        fitter = poly.Fitter(D, basis, min(N_CHECK, max(D.shape[0] // 4, 1)))
        for mu in candidates:
            Y = N[:, support] / N[:, [mu]]
            got = fitter.fit(Y)
            if got is None:
                last = f"no polynomial of degree ≤ {g} in the {p} data entries fits"
                continue
            W, res = got
            F, res_exact = poly.exact(W, D, Y, basis)
            keep = np.flatnonzero(np.any(np.abs(W) > 1e-12, axis=0)) if F is None else \
                np.flatnonzero([any(x != 0 for x in col) for col in zip(*F)])
            coeffs = None if F is None else [[row[j] for j in keep] for row in F]
            return ClosedForm(name, fs.factor_type, [int(support[j]) for j in keep], list(basis), coeffs,
                              W[:, keep], int(mu), g, res_exact if F is not None else res, F is not None)
    return ClosedForm(name, fs.factor_type, [], [], None, None, None, None, float("nan"), False,
                      f"no closed form: {last}")
