"""``autotight report PROBLEM``: run (or resume) a noise sweep and write the report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Callable

from ..extras import require
from ..io import jsonable
from ..limits import check_count, check_size
from ..parallel import usable_cpus
from ..problem import load, parse_assignments
from ..tightness import Criteria
from ..report.spec import SETS, ReportError, make_spec
from .options import add_accept_arg, check_solver, nonneg_int


def register(sub: Any, add_problem_args: Callable[[argparse.ArgumentParser], None]) -> None:
    p = sub.add_parser("report", help="noise sweep: tightness per constraint set, trapped local solves, figures",
                       description="Sweep the noise level σ: per σ and trial, a fresh instance, the SDP with each "
                                   "constraint set and the local solver from the truth and a random start. "
                                   "Resumable; writes trials.csv, meta.json, PNG figures, report.md, report.html.")
    add_problem_args(p)
    for action in p._actions:  # the shared --seed is the sweep's base seed here
        if action.dest == "seed":
            action.help = "base seed: trial (i, t) uses SeedSequence((seed, i, t)) (default 0)"
    p.add_argument("--sigmas", metavar="LIST", default=None,
                   help="comma-separated noise levels (default: the problem's META.sigmas, else 7 levels over 1e-3…1)")
    p.add_argument("--trials", type=nonneg_int, default=100, help="trials per noise level (default 100)")
    p.add_argument("--sets", metavar="LIST", default=None,
                   help=f"constraint sets, a subset of {','.join(SETS)} "
                        "(default: primary, plus paper if the problem has paper families); file:PATH: a saved "
                        "constraint set (`discover --out`) as the discovered set")
    p.add_argument("--jobs", "-j", type=int, default=None,
                   help="local worker processes (default: all cores; at most the cores and the trials to compute)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on a Dask distributed cluster at this scheduler address (e.g. tcp://host:8786)")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="report folder (default: out/PROBLEM in the current folder; a folder holding another "
                        "sweep or files no report wrote is refused)")
    p.add_argument("--discovered", metavar="FILE", default=None,
                   help="a saved discovered-set JSON for the 'discovered' set (default: run discovery)")
    p.add_argument("--limit", type=nonneg_int, default=None, metavar="N",
                   help="compute at most N missing trials now (the rest on a later run)")
    p.add_argument("--redo", metavar="STATUSES", default=None,
                   help="re-run the saved trials where any solve ended with one of these comma-separated "
                        "statuses (e.g. InsufficientProgress,NumericalError after a solver upgrade)")
    p.add_argument("--solver", default="clarabel",
                   help="SDP backend: clarabel (default), ipm (our interior-point method on clique blocks) "
                        "or cvxpy:SCS, cvxpy:MOSEK, …; part of the sweep's settings (a resume must match)")
    add_accept_arg(p)
    p.add_argument("--decompose", action="store_true",
                   help="Clarabel on our own clique cover instead of its built-in chordal decomposition "
                        "(faster on continuous time with marginalize=false); part of the sweep's settings")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (there is none either when stderr is not a terminal)")
    p.set_defaults(func=cmd_report)


def cmd_report(args: argparse.Namespace) -> int:
    require("report", "autotight report")
    from ..report.render import render  # heavy imports (matplotlib, pandas) only when reporting
    from ..report.store import Store
    from ..report.sweep import run_sweep

    if args.out is not None and not args.out.strip():
        raise ReportError("--out '': give a folder")
    prob = load(args.problem)
    given = parse_assignments(args.param)
    check_size(prob, prob.parse_params(given))  # before make_spec builds an instance
    spec = make_spec(prob, args.problem, given, sigmas=args.sigmas, trials=args.trials,
                     sets=args.sets, seed=args.seed, discovered=args.discovered, solver=args.solver,
                     decompose=args.decompose, criteria=Criteria(accept=args.accept))
    check_solver(spec.solver)
    if spec.decompose and spec.solver.startswith("cvxpy"):
        raise ReportError(f"--decompose needs --solver clarabel or ipm, not {spec.solver!r}")
    fixed = prob.parse_params(spec.params)  # σ at its default
    check_count(prob, fixed, f"--trials {spec.trials}", spec.trials * len(spec.sigmas), per_item=2,
                what=f"trials ({len(spec.sigmas)} noise levels)")
    if args.discovered is not None and "discovered" not in spec.sets:
        raise ReportError(f"--discovered {args.discovered}: the sweep has no 'discovered' set; add it to --sets "
                          f"(e.g. --sets {','.join(spec.sets)},discovered)")
    out = Path(args.out) if args.out else Path("out") / prob.name
    jobs = usable_cpus() if args.jobs is None else args.jobs
    most = max(1, min(usable_cpus(), len(spec.tasks()) if args.limit is None else max(args.limit, 1)))
    if jobs > most:  # (jobs < 1 is refused by run_sweep)
        if args.jobs is not None:
            print(f"autotight: note: --jobs {args.jobs} capped at {most} (the cores here and the trials to compute)",
                  file=sys.stderr)
        jobs = most
    redo = [x.strip() for x in args.redo.split(",") if x.strip()] if args.redo is not None else []
    if args.redo is not None and not redo:
        raise ReportError("--redo '': give solver statuses, e.g. --redo NumericalError,InsufficientProgress")
    try:
        summary = run_sweep(spec, out, jobs=jobs, scheduler=args.scheduler, limit=args.limit, redo=redo,
                            progress=not args.no_progress, log=lambda msg: print(msg, file=sys.stderr))
    except KeyboardInterrupt:
        print(f"autotight: interrupted; finished trials are saved in {out / 'trials.csv'} — "
              "re-run the same command to resume", file=sys.stderr)
        return 130
    meta = Store(out).meta() or {}
    files = render(out, meta)
    rec: dict[str, Any] = {"problem": prob.name, "params": spec.params, "sigmas": spec.sigmas, "trials": spec.trials,
           "sets": spec.sets, "seed": spec.seed, "out": str(out), "total": summary.total,
           "done_before": summary.done_before, "computed": summary.computed, "failed": summary.failed,
           "complete": summary.complete, "files": sorted(p.name for p in files.values())}
    if args.json:
        print(json.dumps(jsonable(rec), ensure_ascii=False))
        return 0
    done = summary.done_before + summary.computed
    print(f"report {prob.name}: {done}/{summary.total} trials in {out} ({summary.computed} computed now"
          f"{f', {summary.failed} failed' if summary.failed else ''})")
    if not summary.complete:
        print("incomplete: re-run the same command to compute the remaining trials")
    print("files: " + ", ".join(["trials.csv", "meta.json", *rec["files"]]))
    return 0
