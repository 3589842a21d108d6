"""``autotight export SET.json --to python|latex|json-sparse``: a saved set as standalone code or data
(``autotight.export``)."""

from __future__ import annotations

import argparse
import json

from ..discovery.discovered import DiscoveredSet
from ..export import FORMATS, latex_source, python_source, sparse_record
from ..io import atomic_write_text, jsonable
from ..outpaths import check_file, writing
from ..problem import load
from ..set_file import check_set_file
from .options import nonneg_int


def register(sub: argparse._SubParsersAction, add_problem_args=None) -> None:
    """The ``export`` subcommand (the set file names its problem)."""
    p = sub.add_parser("export", help="a saved constraint set as standalone Python, LaTeX or sparse triplets")
    p.add_argument("set", help="a constraint-set file (from `discover --out`)")
    p.add_argument("--to", required=True, choices=FORMATS, help="python: a NumPy-only module; latex: the closed "
                   "forms beside the paper's; json-sparse: triplets")
    p.add_argument("--out", default=None, help="write to this file (default: standard output)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--seed", type=nonneg_int, default=None,
                   help="json-sparse: also the constraints of the instance with this seed at the set's parameters")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    if args.out is not None:
        check_file(args.out, force=args.force)
    check_set_file(args.set)
    ds = DiscoveredSet.load(args.set)
    prob = load(ds.problem)
    if args.to == "python":
        text = python_source(prob, ds, args.set)
    elif args.to == "latex":
        text = latex_source(prob, ds)
    else:
        text = json.dumps(jsonable(sparse_record(prob, ds, args.set, args.seed)), ensure_ascii=False)
    if args.out is None:
        print(text)
        return 0
    with writing(args.out):
        atomic_write_text(args.out, text)
    print(f"saved to {args.out}")
    return 0
