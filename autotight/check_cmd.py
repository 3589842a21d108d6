"""``autotight check PROBLEM --set paper|primary|FILE``: does a set suffice over a range?  Exit 0/1/2.

Exit status: 0 when every point reaches ``--min-fraction`` (tight / (instances − undecided), see
``autotight.check``), 1 when one does not, 2 on bad input (as every verb: ``autotight.cli.main``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from .cli_checks import pos_int
from .errors import ParameterError
from .io import jsonable
from .problem import load, parse_assignments


def parse_values(text: str, what: str) -> list[str]:
    """"0.001,0.01" → ["0.001", "0.01"] (each parsed later by the problem's parameter)."""
    vals = [v.strip() for v in text.split(",") if v.strip()]
    if not vals:
        raise ParameterError(f"{what} {text!r}: expected comma-separated values, e.g. 0.001,0.01,0.1")
    return vals


def parse_range(sigmas: str | None, ranges: list[str] | None) -> dict[str, list[str]]:
    """``--sigmas a,b`` and ``--range NAME=v1,v2`` (repeatable) → {name: values}."""
    over: dict[str, list[str]] = {}
    if sigmas is not None:
        over["sigma"] = parse_values(sigmas, "--sigmas")
    for item in ranges or []:
        if "=" not in item:
            raise ParameterError(f"--range {item!r}: expected NAME=v1,v2,…")
        name, vals = (x.strip() for x in item.split("=", 1))
        if name in over:
            raise ParameterError(f"--range: {name} is given twice")
        over[name] = parse_values(vals, f"--range {name}")
    return over


def add_range_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sigmas", default=None, metavar="S1,S2,…", help="noise levels, e.g. 0.001,0.01,0.1,0.316,1")
    p.add_argument("--range", action="append", default=[], metavar="NAME=V1,V2,…",
                   help="vary any parameter over these values (repeatable; the points are the product)")


def register(sub: argparse._SubParsersAction, add_problem_args: Callable) -> None:
    p = sub.add_parser("check", help="does a constraint set suffice? N fresh instances per point; "
                                     "exit 0 if so, 1 if not")
    add_problem_args(p)
    p.add_argument("--set", default=None, metavar="paper|primary|FILE",
                   help="paper, primary, or a saved set's JSON (default: paper if the problem has paper families)")
    add_range_args(p)
    p.add_argument("--instances", type=pos_int, default=10, help="fresh instances per point (default 10)")
    p.add_argument("--min-fraction", type=float, default=1.0,
                   help="a point passes when tight / (instances − undecided) ≥ this (default 1)")
    from .cli import add_accept_arg, add_solver_args

    add_solver_args(p)
    add_accept_arg(p)
    p.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from .check import check_sufficient
    from .cli import constraints_arg, solver_config
    from .tightness import Criteria

    config = solver_config(args)
    prob = load(args.problem)
    over: dict[str, Any] = parse_range(args.sigmas, args.range)
    rep = check_sufficient(prob, constraints_arg(args.set), None, args.instances, args.min_fraction,
                           parse_assignments(args.param), args.seed, config, over=over,
                           criteria=Criteria(accept=args.accept))
    if args.json:
        print(json.dumps(jsonable(rep.record()), ensure_ascii=False))
    else:
        print(rep.table())
    return 0 if rep.passed else 1
