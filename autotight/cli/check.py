"""``autotight check PROBLEM --set paper|primary|FILE``: does a set suffice over a range?  Exit 0/1/2.

Exit status: 0 when every point reaches ``--min-fraction`` (tight / (instances − undecided), see
``autotight.check``), 1 when one does not, 2 on bad input (as every verb: ``autotight.cli.main``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from ..errors import ParameterError
from ..io import jsonable
from ..problem import load, parse_assignments
from .options import (add_accept_arg, add_range_args, add_solver_args, constraints_arg, parse_range, pos_int,
                      solver_config)


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
    add_solver_args(p)
    add_accept_arg(p)
    p.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from ..check import check_sufficient
    from ..points import points_of
    from ..tightness import Criteria

    config = solver_config(args)
    prob = load(args.problem)
    over: dict[str, Any] = parse_range(args.sigmas, args.range)
    fixed = parse_assignments(args.param)
    try:  # the points, for the set's scope note; check_sufficient reports bad parameters its own way
        points = [full for full, _ in points_of(prob, fixed, over)]
    except ParameterError:
        points = []
    cons = constraints_arg(args.set, points=points)
    rep = check_sufficient(prob, cons, None, args.instances, args.min_fraction, fixed, args.seed, config,
                           over=over, criteria=Criteria(accept=args.accept))
    if args.json:
        print(json.dumps(jsonable(rep.record()), ensure_ascii=False))
    else:
        print(rep.table())
    return 0 if rep.passed else 1
