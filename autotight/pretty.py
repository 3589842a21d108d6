"""Constraints printed as readable polynomials in the variable names.

⟨A, X⟩ = Σ_{a≤b} terms of block pair (a, b).  A pair whose coefficient block is α·I reads
``α aᵀb``; otherwise each entry reads ``α a.x·b.y``.  h·x prints as x and h² as a constant.
For d > 1 the same text describes tr(Θ_a M Θ_bᵀ) with aᵀb meaning the column products.
"""

from __future__ import annotations

import re

import numpy as np
import scipy.sparse as sp

from .model import HOMOGENISING, Variables

#: Greek letters by name.  A block's name is rendered with the letter only when the name *is* the
#: letter's name, alone or followed by a subscript ('_…' or digits): 'varpi_3' → 'ϖ_3', while
#: 'w_3' and 'weight' print unchanged (continuous_trajectory's twist blocks ϖ_k are named w_k and
#: print as w_k; an outlier variable w_m of a robust problem is not ϖ).
GREEK = {"rho": "ρ", "phi": "φ", "xi": "ξ", "ell": "ℓ", "varpi": "ϖ", "theta": "θ", "psi": "ψ"}
AXES = "xyz"


def symbol(block: str) -> str:
    """'rho_3' → 'ρ_3', 'phi' → 'φ', 'xi12' → 'ξ12'; one Latin letter before a letter's name keeps it as
    a prefix ('urho_2' → 'uρ_2', 'zphi_0' → 'zφ_0'); other names unchanged."""
    m = re.fullmatch(r"([A-Za-z]+)((?:[_0-9].*)?)", block)
    if not m:
        return block
    head, tail = m.groups()
    if head not in GREEK and head[1:] in GREEK:
        return head[0] + GREEK[head[1:]] + tail
    return GREEK.get(head, head) + tail


def _mag(a: float) -> str:
    """|a| with 4 significant digits."""
    return f"{abs(a):.4g}"


def _elem(block: str, k: int, size: int) -> str:
    s = symbol(block)
    return s if size == 1 else f"{s}.{AXES[k] if size <= 3 else k}"


def column_names(V: Variables) -> list[str]:
    """Each column's printed name, in column order (e.g. 't.x', 'z0.10', 'h')."""
    return [_elem(b, k, V.sizes[b]) for b in V.names for k in range(V.sizes[b])]


def _num(c: float, first: bool) -> str:
    """Sign and coefficient in front of a term; a coefficient that prints as 1 is left out."""
    txt = "" if _mag(c) == "1" else f"{_mag(c)} "
    if first:
        return ("−" if c < 0 else "") + txt
    return f" {'−' if c < 0 else '+'} {txt}"


def _const(c: float, first: bool) -> str:
    if first:
        return ("−" if c < 0 else "") + _mag(c)
    return f" {'−' if c < 0 else '+'} {_mag(c)}"


def polynomial(A: sp.spmatrix | sp.sparray, V: Variables, b: float = 0.0, tol: float = 1e-10) -> str:
    """``A`` (N×N symmetric) as text ``… = b``; coefficients below tol·max|A| are dropped."""
    A = sp.csr_array(A)
    scale = abs(A).max() if A.nnz else 1.0
    names = V.names
    terms: list[tuple[float, str]] = []
    const = 0.0
    for ia, a in enumerate(names):
        for b_ in names[ia:]:
            M = A[V.slice(a), :][:, V.slice(b_)].toarray()
            if a != b_:
                M = 2.0 * M  # (a,b) and (b,a) blocks
            if not np.any(np.abs(M) > tol * scale):
                continue
            na, nb = M.shape
            if a == HOMOGENISING and b_ == HOMOGENISING:
                const += float(np.trace(M)) if V.d > 1 else float(M[0, 0])
                continue
            if a == HOMOGENISING and V.d == 1:
                for k in np.flatnonzero(np.abs(M[0]) > tol * scale):
                    terms.append((M[0, k], _elem(b_, int(k), nb)))
                continue
            if na == nb and na > 1 and np.allclose(M, M[0, 0] * np.eye(na), atol=tol * scale):
                terms.append((M[0, 0], f"{symbol(a)}ᵀ{symbol(b_)}" if a != b_ else f"{symbol(a)}ᵀ{symbol(a)}"))
                continue
            if a == b_:
                M = np.triu(M + M.T - np.diag(np.diag(M)))
            for i, j in zip(*np.nonzero(np.abs(M) > tol * scale)):
                ea, eb = _elem(a, i, na), _elem(b_, j, nb)
                terms.append((M[i, j], f"{ea}²" if (a == b_ and i == j) else f"{ea}·{eb}"))
    if abs(const) > tol * scale:
        terms.append((const, "§"))
    rhs = _const(b, True) if b != 0 else "0"
    if not terms:
        return f"0 = {rhs}"
    out = "".join(_const(c, n == 0) if t == "§" else _num(c, n == 0) + t for n, (c, t) in enumerate(terms))
    return f"{out} = {rhs}"
