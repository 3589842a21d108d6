"""A report table: a title, a header, rows of text cells and an optional note (rendered by ``render``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Table:
    title: str
    header: list[str]
    rows: list[list[str]]
    note: str = ""
