"""The report's closed-form section: the sweep's discovered set (``discovered.json`` in the report folder)
as the table "discovered family | closed form | paper family | relation", and the paper's families in the
same notation.  Rendered from the saved set only (no SDP solve)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import AutotightError


def closed_form_tables(out: Path, meta: dict[str, Any]) -> list:
    """Report tables (``render.Table``) of the closed forms; none when the folder has no discovered set."""
    from ..discovery.discovered import DiscoveredSet
    from ..problem import load
    from ..report.render import Table
    from ..report.sweep import DISCOVERED_NAME
    from .table import N_FRESH, family_table

    path = Path(out) / DISCOVERED_NAME
    if not path.exists():
        return []
    try:
        ds = DiscoveredSet.load(path)
        tab = family_table(load(meta.get("source") or ds.problem), ds)
    except AutotightError as e:
        return [Table("Discovered families in closed form", ["note"], [[f"not computed: {e}"]])]
    rows = [[f"{r.factor_type}: {r.identity}", r.closed_form, r.paper,
             r.relation + ("" if r.residual != r.residual else f" (residual {r.residual:.1e})")] for r in tab.rows]
    note = ("Each family modulo the primary constraints (normal form), normalised to coefficient 1 on its first "
            "monomial whose coefficient is a polynomial in the measurement entries; equal families read equally. "
            f"Relations are exact identities between closed forms, residuals on {N_FRESH} factors of fresh instances "
            "(autotight/closed_form).")
    tables = [Table("Discovered families in closed form", ["discovered family", "closed form", "paper family",
                                                           "relation"], rows, note)]
    for t, prow in tab.paper.items():
        tables.append(Table(f"The paper's families on {t}, same notation", ["paper family", "closed form"],
                            [[n, c] for n, c, _ in prow]))
    return tables
