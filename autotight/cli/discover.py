"""``autotight discover PROBLEM``: the engine (``discovery.engine``) with progress, a table, JSON and --out.

Exit codes: 0 when the set is validated (or validation was not asked for), 1 when validation failed
(one line on stderr; the set is still saved and records it), 2 for bad input.  --out is checked before
any work; if writing it still fails at the end, the set is written next to the current folder instead
and the message says where.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from ..errors import AutotightError
from ..io import jsonable
from ..limits import check_count, check_size
from ..outpaths import check_file
from ..problem import load, parse_assignments
from ..discovery.engine import carry_hint, discover
from ..discovery.learn import LearnOptions
from ..discovery.result import DiscoveryResult
from .closed_form import closed_form_output
from .options import (add_accept_arg, add_range_args, add_solver_args, nonneg_float, nonneg_int, parse_range,
                      pos_float, pos_int, solver_config)


def register(sub: argparse._SubParsersAction, add_problem_args: Callable) -> None:
    p = sub.add_parser("discover", help="learn, tighten and reduce redundant constraints until held-out "
                                        "instances pass; compare with the paper")
    add_problem_args(p)
    add_range_args(p)
    p.add_argument("--out", default=None, help="save the discovered set as JSON to this file (checked before the work)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--groups", default=None, help="the problem's META.default_groups or 'factors' (default), 'whole', "
                   "'adjacent:TYPE+TYPE' (unions of neighbouring factors), comma-joined, or explicit blocks 'a,b;c,d'")
    p.add_argument("--train", type=pos_int, default=1, help="training instances per point (default 1)")
    p.add_argument("--heldout", type=nonneg_int, default=10,
                   help="held-out instances per point and round (default 10; 0: no validation)")
    p.add_argument("--min-fraction", type=float, default=0.9,
                   help="a point passes when tight / (held-out − undecided) ≥ this, as in check (default 0.9)")
    p.add_argument("--max-rounds", type=pos_int, default=5,
                   help="held-out rounds at most; each round's failures become training instances (default 5)")
    p.add_argument("--max-solves", type=pos_int, default=None, help="SDP solver calls at most (default: no limit)")
    p.add_argument("--carry-to", action="append", default=[], metavar="NAME=VALUE",
                   help="a size the set must pass at too, e.g. K=200 (repeatable; default: the problem's "
                        "META.carry_to hint)")
    p.add_argument("--no-carry", action="store_true", help="ignore the problem's META.carry_to hint")
    p.add_argument("--jobs", "-j", type=pos_int, default=None,
                   help="worker processes for the held-out solves (default: every CPU when the largest held-out "
                        "point's SDP has 1000 columns or more, or from the batch after one that took 1 s or more "
                        "per instance in this process, else 1; the result is the same either way)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the held-out solves on a Dask cluster at this scheduler address")
    p.add_argument("--min-gap", type=pos_float, default=6.0,
                   help="spectral gap in decades that decides the rank (default 6; half of it where the "
                        "values below the gap are at roundoff, nullspace.spectrum)")
    p.add_argument("--gap-tol", type=nonneg_float, default=1e-5,
                   help="relative cost gap counted as tight (default 1e-5)")
    add_accept_arg(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--latex", default=None, metavar="FILE",
                   help="write the discovered families' closed forms beside the paper's as LaTeX to FILE")
    add_solver_args(p, default=None, note="with a META.carry_to hint that names a backend: that one")
    p.set_defaults(func=cmd_discover)


def _groups(spec: str | None):
    if spec is None:
        return None
    if ";" not in spec and all(p.strip() in ("factors", "whole") or p.strip().startswith("adjacent:")
                               for p in spec.split(",")):
        return spec
    return [tuple(x.strip() for x in g.split(",") if x.strip()) for g in spec.split(";") if g.strip()]


@contextmanager
def progress_bar(args: argparse.Namespace) -> Iterator[Callable[[str, str], None]]:
    """A progress callback ``progress(stage, text)`` drawing a bar unless --json or --no-progress."""
    bar = None
    if not args.json and not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(desc="discover", unit="step", leave=False)

    def progress(stage: str, text: str) -> None:
        if bar is not None:
            bar.set_description(f"{stage} {text}"[:60])
            bar.update(1)

    try:
        yield progress
    finally:
        if bar is not None:
            bar.close()


def fallback_path(problem: str, seed: int) -> Path:
    """A new file name in the current folder for a set whose --out could not be written."""
    base = Path.cwd() / f"discovered-{Path(problem).stem}-seed{seed}"
    k = 0
    while (p := base.with_name(base.name + (f"-{k}" if k else "") + ".json")).exists():
        k += 1
    return p


def save_or_fallback(res: DiscoveryResult, out: str, replace: bool = False) -> tuple[Path, str]:
    """Write ``res`` to ``out`` (over an existing file only with ``replace``; a file that appeared there during
    the run is kept and the set saved beside it, ``DiscoveredSet.save``); if writing fails, next to the
    current folder.  Returns (path written, '' or why ``out`` could not be written)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a diversion beside ``out`` is reported by the caller
            return Path(res.save(out, replace=replace)), ""
    except (OSError, ValueError, AutotightError) as e:
        first = (str(e).splitlines() or [type(e).__name__])[0]
        alt = fallback_path(res.problem, res.seed)
        return Path(res.save(alt)), f"cannot write {out} ({first})"


def cmd_discover(args: argparse.Namespace) -> int:
    from ..tightness import Criteria

    if args.out is not None:
        check_file(args.out, force=args.force)
    if args.latex is not None:
        check_file(args.latex, force=args.force)
    prob = load(args.problem)
    hint, backend = carry_hint(prob)
    carry = {} if args.no_carry else (parse_assignments(args.carry_to) if args.carry_to else None)
    config = solver_config(args, default_backend=backend if carry is None and hint and backend else "clarabel")
    params = prob.parse_params(parse_assignments(args.param))
    check_size(prob, params, config)
    check_count(prob, params, f"--heldout {args.heldout}", args.heldout, per_item=3, what="held-out instances")
    check_count(prob, params, f"--train {args.train}", args.train, per_item=3, what="training instances per point")
    with progress_bar(args) as progress:
        res = discover(prob, parse_assignments(args.param), args.seed, over=parse_range(args.sigmas, args.range),
                       n_train=args.train, n_heldout=args.heldout, min_fraction=args.min_fraction,
                       max_rounds=args.max_rounds, max_solves=args.max_solves, carry_to=carry,
                       groups=_groups(args.groups), learn_options=LearnOptions(min_gap_decades=args.min_gap),
                       criteria=Criteria(gap_tol=args.gap_tol, accept=args.accept), solver=config,
                       jobs=args.jobs, scheduler=args.scheduler, progress=progress)
    where, failed = (None, "") if not args.out else save_or_fallback(res, args.out, replace=args.force)
    if args.json:
        print(json.dumps(jsonable(res.record()), ensure_ascii=False))
    else:
        print(res.table())
        if where is not None:
            print(f"\nsaved to {where}")
    closed_form_output(prob, res.discovered, args)
    if failed:
        print(f"error: {failed}; the set is saved to {where} instead", file=sys.stderr)
        return 2
    if where is not None and where != Path(args.out):
        print(f"autotight: note: {args.out} appeared while discovery ran and is kept; the set is saved as {where}",
              file=sys.stderr)
    if res.validated is False or not res.tight:  # validation failed, or the set is not tight on its training
        print(f"error: {res.validation['message']}", file=sys.stderr)
        return 1
    return 0
