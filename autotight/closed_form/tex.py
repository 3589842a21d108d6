"""The closed-form table as a LaTeX document (``discover --latex FILE``, ``export --to latex``)."""

from __future__ import annotations

import re


from .table import FamilyTable, residual_note


UNICODE = {"−": "-", "≤": r"$\le$", "≥": r"$\ge$", "·": r"$\cdot$", "ᵀ": r"$^\top$", "²": r"$^2$", "³": r"$^3$",
           "ρ": r"$\rho$", "φ": r"$\phi$", "ξ": r"$\xi$", "ℓ": r"$\ell$", "ϖ": r"$\varpi$", "θ": r"$\theta$",
           "ψ": r"$\psi$", "δ": r"$\delta$", "σ": r"$\sigma$", "×": r"$\times$", "—": "---", "–": "--"}


def _esc(s: str) -> str:
    """Plain text for LaTeX: special characters escaped, the symbols the tables use written as maths, any
    other non-ASCII character dropped (pdflatex without extra packages)."""
    special = {"\\": r"\textbackslash{}", "_": r"\_", "&": r"\&", "%": r"\%", "#": r"\#", "{": r"\{",
               "}": r"\}", "$": r"\$", "^": r"\^{}"}
    s = re.sub(r"[\\_&%#{}$^]", lambda m: special[m.group(0)], s)
    s = re.sub(r"(\w)\u0303", lambda m: rf"$\tilde{{{m.group(1)}}}$", s)
    return "".join(UNICODE.get(ch, ch if ord(ch) < 128 else "") for ch in s)


def document(tab: FamilyTable) -> str:
    """A standalone LaTeX document: per discovered family its closed form, the paper family and the relation
    (with its residual on fresh data), then the paper's families in the same notation.  Formulas are
    ``equation*`` (amsmath only; a long one runs past the margin rather than depend on a line-breaking package)."""
    out = [r"\documentclass{article}", r"\usepackage{amsmath}", r"\usepackage[margin=2cm]{geometry}",
           r"\begin{document}", rf"\section*{{Closed forms: {_esc(tab.problem)}}}",
           "Each family is written modulo the primary constraints (normal form), normalised as the table's "
           "code does, so equal families read equally.", ""]
    for r in tab.rows:
        out.append(rf"\paragraph{{{_esc(r.factor_type)}: {_esc(r.identity)}}} "
                   f"paper family: {_esc(r.paper)}; relation: {_esc(r.relation)}"
                   + residual_note(r)
                   + ("" if r.exact else " (coefficients in floating point)"))
        out.append(r"\begin{equation*}" + r.latex + r"\end{equation*}" if r.latex
                   else _esc(r.closed_form))
    for t, rows in tab.paper.items():
        out.append(rf"\subsection*{{Paper families on {_esc(t)}}}")
        for name, _, tex in rows:
            out.append(rf"\paragraph{{{_esc(name)}}}" + r"\begin{equation*}" + tex + r"\end{equation*}")
    out += [_esc(n) for n in tab.notes]
    out.append(r"\end{document}")
    return "\n".join(out) + "\n"
