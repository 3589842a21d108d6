"""Command line: ``autotight list | solve | discover | report``.

Bad input (unknown problem, bad parameter, malformed module, Cayley singularity, failed solve)
prints one line ``autotight: error: …`` and exits with status 2; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence

import numpy as np

from .errors import AutotightError
from .io import jsonable, versions
from .problem import available, load, parse_assignments


def _add_problem_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("problem", help="problem name (see `autotight list`) or path to a .py problem module")
    p.add_argument("--param", "-p", action="append", default=[], metavar="NAME=VALUE",
                   help="problem parameter, repeatable (e.g. --param M=10 --param sigma=0.1)")
    p.add_argument("--seed", type=int, default=0, help="instance seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def cmd_list(args: argparse.Namespace) -> int:
    rows = []
    for name in available():
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


def cmd_solve(args: argparse.Namespace) -> int:
    from .run import solve_instance
    from .sdp.result import SolverOptions

    if args.decompose and args.solver.startswith("cvxpy"):
        raise ValueError(f"--decompose needs --solver clarabel or ipm, not {args.solver!r}")
    prob = load(args.problem)
    inst = prob.generate(parse_assignments(args.param), args.seed)
    out = solve_instance(prob, inst, set_name=args.set, solver=args.solver, options=SolverOptions(),
                         rng=np.random.default_rng(args.seed + 1_000_003), n_random=args.random_starts,
                         decompose=True if args.decompose else None)
    rec = out.record(prob)
    if args.json:
        rec |= {"measurements": inst.measurements, "truth": inst.truth, "estimate": out.estimate,
                "versions": versions()}
        print(json.dumps(jsonable(rec), ensure_ascii=False))
        return 0
    v = out.verdict
    print(f"problem {prob.name}  params {inst.params}  seed {inst.seed}")
    print(f"constraints: {args.set or rec['constraint_set']} ({rec['n_constraints']})  solver {out.sdp.solver}")
    print(f"SDP: status {out.sdp.status}  cost {out.sdp.primal_cost:.10g}  log SVR {out.sdp.log_svr:.2f}  "
          f"{'TIGHT' if v.tight else 'NOT TIGHT'} ({v.reason})")
    print(f"local solver from ground truth: cost {out.local.from_truth.cost:.10g}  "
          f"({out.local.from_truth.iterations} it, {out.local.from_truth.message})")
    for r in out.local.from_random:
        print(f"local solver from a random start: cost {r.cost:.10g}"
              f"{'  (trapped)' if r.cost > out.local.best.cost * (1 + 1e-6) + 1e-12 else ''}")
    print(f"relative gap (best local − SDP)/best local: {v.rel_gap:.3e}")
    print(f"errors: SDP estimate {out.errors_sdp}  local {out.errors_local}")
    print("times: " + "  ".join(f"{k} {t:.3f}s" for k, t in out.times.items()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="autotight", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("list", help="list problems and their parameters")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("solve", help="solve one instance: SDP, local solver, tightness")
    _add_problem_args(p)
    p.add_argument("--set", choices=["primary", "paper"], default=None,
                   help="constraint set (default: paper if the problem has paper families, else primary)")
    p.add_argument("--solver", default="clarabel", help="clarabel (default), ipm (our interior-point method on clique blocks) or cvxpy:SCS, cvxpy:MOSEK, …")
    p.add_argument("--decompose", action="store_true",
                   help="Clarabel on our own clique cover (min-fill covers of the columns and of the variable "
                        "blocks, autotight/run.py: CliqueCovers) instead of its built-in chordal decomposition; "
                        "faster on continuous time with marginalize=false (K = 21: 9 s against 30 s). "
                        "The IPM always uses our cover")
    p.add_argument("--random-starts", type=int, default=1, help="random-start local solves (default 1)")
    p.set_defaults(func=cmd_solve)
    for extra in _extensions():
        extra(sub, _add_problem_args)
    return ap


def _extensions() -> list:
    """Sub-commands defined in other modules (discover, report)."""
    out = []
    for mod in ("autotight.discovery.cli", "autotight.report.cli", "autotight.check_cli"):
        try:
            m = __import__(mod, fromlist=["register"])
        except ModuleNotFoundError:
            continue
        out.append(m.register)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (AutotightError, ValueError, np.linalg.LinAlgError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        print(f"autotight: error: {msg}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("autotight: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
