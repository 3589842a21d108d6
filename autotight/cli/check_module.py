"""``autotight check-module PATH_OR_NAME``: check a problem module against its contract.

Prints one line per finding (PASS / WARN / FAIL) and exits 0 when every check passed (warnings
allowed), 1 when a check failed; bad input (unknown problem, bad parameter, a file that does not
import) is the usual one-line ``autotight: error: …`` with exit 2.
"""

from __future__ import annotations

import argparse
import json
from typing import Callable

from ..checks import check_problem
from ..io import jsonable
from ..problem import load, parse_assignments
from .options import pos_int


def cmd_check_module(args: argparse.Namespace) -> int:
    prob = load(args.problem)
    params = parse_assignments(args.param) if args.param else None
    if params is not None:
        prob.parse_params(params)  # a bad parameter is bad input (exit 2), not a failed check
    res = check_problem(prob, params, seed=args.seed, n_samples=args.samples)  # refuses samples that cannot fit
    if args.json:
        print(json.dumps(jsonable(res.record()), ensure_ascii=False))
    else:
        print("\n".join(res.lines()))
    return 0 if res.ok else 1


def register(sub: argparse._SubParsersAction, add_problem_args: Callable[[argparse.ArgumentParser], None]) -> None:
    p = sub.add_parser("check-module", help="check a problem module against the contract (docs/problem_contract.md)")
    add_problem_args(p)
    p.add_argument("--samples", type=pos_int, default=5, help="fresh samples per check (default 5)")
    p.set_defaults(func=cmd_check_module)
