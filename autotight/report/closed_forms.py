"""The report's closed-form section: for the sweep's discovered set (``discovered.json`` in the report
folder, else the command's ``--discovered`` file) and each ``file:`` set of its command, the table
"discovered family | closed form | paper family | relation", then the paper's families in the same
notation.  No SDP is solved: the tables come from the saved sets.

The tables are kept in ``closed_forms.json`` in the report folder, keyed by each set file's SHA-256, so a
re-render reads them instead of computing them again.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

from ..errors import AutotightError
from ..io import atomic_write_text

CACHE = "closed_forms.json"


def _sets(out: Path, meta: dict[str, Any]) -> list[tuple[str, Path]]:
    """(name, path) of the discovered set in ``out`` and the command's file: sets that still exist."""
    from .spec import file_sets
    from .sweep import DISCOVERED_NAME

    found = [("discovered", out / DISCOVERED_NAME)] if (out / DISCOVERED_NAME).exists() else []
    command = meta["runs"][-1].get("command", "") if meta.get("runs") else ""
    try:
        words = shlex.split(command)
    except ValueError:
        words = []
    arg = next((a.split("=", 1)[-1] for a in words if a.startswith("--sets=")), None)
    if arg is None and "--sets" in words[:-1]:
        arg = words[words.index("--sets") + 1]
    given = next((a.split("=", 1)[-1] for a in words if a.startswith("--discovered=")), None)
    if given is None and "--discovered" in words[:-1]:
        given = words[words.index("--discovered") + 1]
    if not found and given is not None and Path(given).exists():  # the sweep's set, read from where it was given
        found.append(("discovered", Path(given)))
    for name, path in (file_sets(arg)[1] if arg else ()):
        if Path(path).exists():
            found.append((name, Path(path)))
    return found


def _table(name: str, path: Path, meta: dict[str, Any], cache: dict[str, Any]):
    from ..discovery.discovered import DiscoveredSet
    from ..problem import load
    from ..closed_form.table import FamilyTable, family_table
    from .sweep import _sha256

    key = _sha256(path)
    if key in cache:
        return FamilyTable.from_record(cache[key]["table"]), False
    ds = DiscoveredSet.load(path)
    tab = family_table(load(meta.get("source") or ds.problem), ds)
    cache[key] = {"set": name, "file": str(path), "table": tab.record()}
    return tab, True


def closed_form_tables(out: Path, meta: dict[str, Any]) -> list:
    """Report tables (``report.table.Table``) of the closed forms; none when the report has no learned set."""
    from .table import Table
    from ..closed_form.table import N_FRESH, residual_note

    out = Path(out)
    sets = _sets(out, meta)
    if not sets:
        return []
    try:
        cache = json.loads((out / CACHE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        cache = {}
    rows: list[list[str]] = []
    paper: dict[str, list] = {}
    changed = False
    for name, path in sets:
        try:
            tab, new = _table(name, path, meta, cache)
        except AutotightError as e:
            rows.append([name, f"not computed: {e}", "—", "—"])
            continue
        changed |= new
        rows += [[f"{name}: {r.factor_type}: {r.identity}", r.closed_form, r.paper, r.relation + residual_note(r)]
                 for r in tab.rows]
        rows += [[name, n, "—", "—"] for n in tab.notes]
        for t, prow in tab.paper.items():
            paper.setdefault(t, prow)
    if changed:
        atomic_write_text(out / CACHE, json.dumps(cache, indent=1, ensure_ascii=False))
    note = ("Each family modulo the primary constraints (normal form), normalised to coefficient 1 on its first "
            "monomial whose coefficient is a polynomial in the measurement entries; equal families read equally. "
            f"Relations are exact identities between closed forms, residuals on {N_FRESH} factors of fresh instances "
            f"(autotight/closed_form; tables kept in {CACHE}).")
    tables = [Table("Discovered families in closed form", ["set: discovered family", "closed form", "paper family",
                                                           "relation"], rows, note)]
    for t, prow in paper.items():
        tables.append(Table(f"The paper's families on {t}, same notation", ["paper family", "closed form"],
                            [[n, c] for n, c, _ in prow]))
    return tables
