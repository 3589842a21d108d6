"""A closed form as one formula: variables by role (the factor's block roles), data by the module's names.

Terms are grouped per pair of blocks as ``pretty`` does: a coefficient block p(δ)·I reads ``p aᵀb``; other
entries read ``p a.x·b.y``; h·x reads x and h² is the constant.  Coefficients are polynomials in the data
entries, named by the problem module's ``DATA_NAMES[factor type]`` (default δ1, δ2, …).  ``latex=True``
gives the same formula in LaTeX.
"""

from __future__ import annotations

import re
from fractions import Fraction
from typing import Sequence

from ..pretty import AXES, symbol
from ..svec import triu_indices
from .family import ClosedForm

GREEK_TEX = {"ρ": r"\rho", "φ": r"\phi", "ξ": r"\xi", "ℓ": r"\ell", "ϖ": r"\varpi", "θ": r"\theta", "ψ": r"\psi",
             "δ": r"\delta"}
TILDE = "\u0303"


def data_names(problem, factor_type: str, p: int) -> list[str]:
    """The module's ``DATA_NAMES[factor_type]`` (p names), else δ1 … δp."""
    names = (getattr(problem.module, "DATA_NAMES", None) or {}).get(factor_type)
    if names is not None and len(names) == p:
        return list(names)
    return [f"δ{i + 1}" for i in range(p)]


def tex_name(name: str) -> str:
    """'C̃_12' → '\\tilde{C}_{12}', 'ρ' → '\\rho', "r'" → "r'", 'c1' → 'c_{1}'."""
    m = re.fullmatch(r"([^\W\d_]+)(" + TILDE + r"?)('*)_?([0-9A-Za-z,.]*)", name)
    if not m:
        return name
    base, tilde, primes, sub = m.groups()
    base = "".join(GREEK_TEX.get(ch, ch) for ch in base)
    if tilde:
        base = rf"\tilde{{{base}}}"
    return base + primes + (f"_{{{sub}}}" if sub else "")


def _split_role(role: str) -> tuple[str, str, str]:
    """'c1' → ('c', '1', ''), "r'" → ('r', '', "'"), 'rho' → ('ρ', '', '')."""
    m = re.fullmatch(r"([A-Za-z]+?)(?:_([A-Za-z0-9]+)|(\d*))('*)", role)
    if not m:
        return symbol(role), "", ""
    head, named, digits, primes = m.groups()
    return symbol(head), named or digits, primes


def _element(role: str, k: int, size: int, latex: bool) -> str:
    head, digits, primes = _split_role(role)
    axis = "" if size == 1 else (AXES[k] if size <= 3 else str(k))
    if latex:
        base = "".join(GREEK_TEX.get(ch, ch) for ch in head) + primes
        sub = ",".join(x for x in (digits, axis) if x)
        return base + (f"_{{{sub}}}" if sub else "")
    name = f"{head}{'_' if digits and not digits[0].isdigit() else ''}{digits}{primes}"
    return name if not axis else f"{name}.{axis}"


def _block(role: str, latex: bool) -> str:
    return _element(role, 0, 1, latex)


def _frac(c: Fraction, latex: bool) -> str:
    if c.denominator == 1:
        return str(abs(c.numerator))
    return rf"\tfrac{{{abs(c.numerator)}}}{{{c.denominator}}}" if latex else f"{abs(c.numerator)}/{c.denominator}"


def _coef_poly(terms: list[tuple[Fraction | float, tuple[int, ...]]], names: list[str], latex: bool) -> str:
    """Σ c·monomial (signed, first term with its sign only when negative)."""
    out = []
    for n, (c, mono) in enumerate(terms):
        neg = c < 0
        mag = _frac(c, latex) if isinstance(c, Fraction) else f"{abs(c):.6g}"
        powers = [(i, mono.count(i)) for i in sorted(set(mono))]
        prod = (r"\," if latex else " ").join(
            (tex_name(names[i]) + (f"^{k}" if k > 1 else "")) if latex else names[i] + ("²³"[k - 2] if k > 1 else "")
            for i, k in powers)
        txt = prod if (mag == "1" and prod) else (f"{mag}\\,{prod}" if latex and prod else
                                                   f"{mag} {prod}" if prod else mag)
        sign = ("-" if latex else "−") if neg else "+"
        out.append((sign if neg else "") + txt if n == 0 else f" {sign} {txt}")
    return "".join(out)


def formula(cf: ClosedForm, roles: Sequence[str], sizes: Sequence[int], names: list[str], latex: bool = False,
            d: int = 1) -> str:
    """The closed form as ``… = 0`` (or its reason when there is none)."""
    if not cf.found:
        return cf.why
    n = int(sum(sizes))
    ii, jj = triu_indices(n)
    owner: list[tuple[int, int]] = []  # (block index, element index) per local column
    for b, s in enumerate(sizes):
        owner += [(b, k) for k in range(s)]
    coeffs: list
    if cf.exact and cf.coeffs is not None:
        coeffs = cf.coeffs
    else:
        assert cf.W is not None, "a family without a closed form has no formula"
        coeffs = [[float(x) for x in row] for row in cf.W]
    polys: dict[int, list] = {}
    for col, mu in enumerate(cf.monomials):
        polys[mu] = [(row[col], m) for row, m in zip(coeffs, cf.basis) if row[col] != 0]
    # group per block pair, in svec order of the first monomial
    pairs: dict[tuple[int, int], dict[tuple[int, int], list]] = {}
    for mu in sorted(polys):
        (ba, ka), (bb, kb) = owner[ii[mu]], owner[jj[mu]]
        pairs.setdefault((ba, bb), {})[(ka, kb)] = polys[mu]
    terms: list[tuple[str, str]] = []  # (coefficient polynomial, variable part)
    for (ba, bb), entries in pairs.items():
        ra, rb = roles[ba], roles[bb]
        sa, sb = sizes[ba], sizes[bb]
        diag = [entries.get((k, k)) for k in range(sa)]
        if ba != 0 and sa == sb and sa > 1 and len(entries) == sa and all(x is not None and x == diag[0] for x in diag):
            var = (f"{_block(ra, latex)}^\\top {_block(rb, latex)}" if latex else
                   f"{_block(ra, False)}ᵀ{_block(rb, False)}")
            terms.append((_coef_poly(diag[0] or [], names, latex), var))
            continue
        for (ka, kb), p in entries.items():
            ea, eb = _element(ra, ka, sa, latex), _element(rb, kb, sb, latex)
            if ba == 0 and bb == 0:
                var = ""  # h·h: a constant (d > 1: entries of X_hh)
                if d > 1 and ka != kb:
                    var = ea + (r"\,\cdot\," if latex else "·") + eb
            elif ba == 0:
                var = eb if d == 1 else ea + (r"\,\cdot\," if latex else "·") + eb
            elif ba == bb and ka == kb:
                var = f"{ea}^2" if latex else f"{ea}²"
            else:
                var = ea + (r"\," if latex else "·") + eb
            terms.append((_coef_poly(p, names, latex), var))
    out = []
    for n_, (c, var) in enumerate(terms):
        single = " + " not in c[1:] and " − " not in c[1:] and " - " not in c[1:]
        neg = c.startswith("−") or c.startswith("-")
        body = c[1:] if (single and neg) else c
        if var:
            if body == "1":
                body = ""
            elif not single:
                body = f"({body})" if not latex else rf"\left({body}\right)"
            txt = f"{body}\\,{var}" if latex and body else f"{body} {var}" if body else var
        else:
            txt = body if single else (f"({body})" if not latex else rf"\left({body}\right)")
        sign = ("-" if latex else "−") if (single and neg) else "+"
        out.append((sign if sign != "+" else "") + txt if n_ == 0 else f" {sign} {txt}")
    return "".join(out) + " = 0"
