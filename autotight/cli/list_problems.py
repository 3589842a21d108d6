"""``autotight list``: the problems and their parameters."""

from __future__ import annotations

import argparse
import json
from typing import Any, Callable

from ..io import jsonable
from ..problem import available, load, registered


def cmd_list(args: argparse.Namespace) -> int:
    rows: list[dict[str, Any]] = []
    for name in available() + sorted(registered()):
        prob = load(name)
        params = {k: {"default": p.default, "help": p.help} for k, p in prob.params.items()}
        rows.append({"name": name, "description": prob.description, "params": params})
    if args.json:
        print(json.dumps(jsonable(rows), indent=1, ensure_ascii=False))
        return 0
    for r in rows:
        print(f"{r['name']}: {r['description']}")
        for k, p in r["params"].items():
            print(f"    {k} = {p['default']!r:<10} {p['help']}")
    return 0


def register(sub: Any, add_problem_args: Callable[[argparse.ArgumentParser], None] | None = None) -> None:
    p = sub.add_parser("list", help="list problems and their parameters")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_list)
