"""The code snippets of docs/factor_graph.md against the shipped modules they quote."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def missing_lines(marker: str, module: str) -> tuple[list[str], list[str]]:
    """(the lines of the page's one Python snippet containing ``marker``, those of them not lines of
    ``problems/<module>.py``), blank lines and trailing spaces ignored."""
    page = (ROOT / "docs" / "factor_graph.md").read_text()
    [snippet] = [c for c in re.findall(r"```python\n(.*?)```", page, re.S) if marker in c]
    shipped = {line.rstrip() for line in (ROOT / "problems" / f"{module}.py").read_text().splitlines()}
    lines = [line.rstrip() for line in snippet.splitlines() if line.strip()]
    return lines, [line for line in lines if line not in shipped]
