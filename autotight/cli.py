"""Command line: ``autotight list | solve | discover | report | check | check-module | certify | templates |
export``.

The CLI is a thin layer over the Python API (``autotight.api``).  Errors: an input error or a
failed solve (any ``autotight.errors.AutotightError``) prints one line ``autotight: error: …``
and exits with status 2; anything else is a bug and raises with its traceback.  ``--debug``
shows the traceback of every error.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, NoReturn, Sequence

import numpy as np

from .cli_checks import nonneg_int
from .errors import AutotightError
from .io import jsonable, versions
from .limits import check_random_starts
from .problem import available, load, parse_assignments, registered


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's error rule: one line ``autotight: error: …``, exit status 2."""

    def error(self, message: str) -> NoReturn:
        where = self.prog.removeprefix("autotight").strip()
        print(f"autotight: error: {where + ': ' if where else ''}{message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def _add_problem_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("problem", help="problem name (see `autotight list`) or path to a .py problem module")
    p.add_argument("--param", "-p", action="append", default=[], metavar="NAME=VALUE",
                   help="problem parameter, repeatable (e.g. --param M=10 --param sigma=0.1)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="instance seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


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


def constraints_arg(value: str | None, skip_invalid: bool = False):
    """``--set``: "primary", "paper", or the path of a saved constraint set (JSON)."""
    if value is None or value in ("primary", "paper"):
        return value
    from .cli_checks import check_set_file
    from .constraint_set import ConstraintSet

    check_set_file(value)
    cs = ConstraintSet.load(value, skip_invalid=skip_invalid)
    warning = cs.discovered.validation_warning()
    if warning:
        print(f"warning: {value}: {warning}", file=sys.stderr)
    return cs


def add_solver_args(p: argparse.ArgumentParser, default: str | None = "auto", note: str = "") -> None:
    """``--solver``, ``--decompose`` and ``--scale``: the SDP backend of every solve of the command.  default
    None: the command picks it (``solver_config(args, default_backend=…)``), ``note`` says how."""
    p.add_argument("--solver", default=default,
                   help="SDP backend: auto (default" + (f"; {note}" if note else "") + ": ipm from 1000 "
                        "columns of X on, else clarabel), clarabel, ipm (our interior-point method on clique "
                        "blocks) or cvxpy:SCS, cvxpy:MOSEK, … (see autotight/sdp/registry.py)")
    p.add_argument("--decompose", action=argparse.BooleanOptionalAction, default=None,
                   help="Clarabel on our own clique cover (min-fill covers of the columns and of the variable "
                        "blocks, autotight/sdp/covers.py) instead of its built-in chordal decomposition "
                        "(--no-decompose: never). Default: as the problem's model advises (continuous time: "
                        "our cover), else Clarabel's own. The IPM always uses our cover")
    p.add_argument("--scale", default="auto", choices=["auto", "none"],
                   help="auto (default): solve for X' in X = D X' D, D the lifted blocks' magnitudes at the best "
                        "local solution, so that O(σ) residual blocks are resolved at low noise "
                        "(autotight/sdp/scaling.py); none: the data as built (fewer solver iterations where "
                        "every block is O(1))")


def add_accept_arg(p: argparse.ArgumentParser) -> None:
    """``--accept rank|cost|certified``: what counts as tight (``tightness.Criteria.accept``)."""
    p.add_argument("--accept", default="rank", choices=["rank", "cost", "certified"],
                   help="what counts as tight: rank d and cost (default); cost: the cost bracket closed to "
                        "tolerance and a dual certificate of the best local solution (on the face of the bounded "
                        "columns where some columns are free; a certificate alone also decides a bracket the "
                        "solver's accuracy leaves open); certified: the dual certificate alone")


def solver_config(args: argparse.Namespace, default_backend: str = "auto", **fields: Any):
    """The ``SolverConfig`` of ``--solver``/``--decompose``/``--scale`` (validated before any work);
    ``default_backend`` when --solver was not given."""
    from .errors import ParameterError
    from .sdp.config import SolverConfig

    backend = default_backend if args.solver is None else args.solver
    if not backend.strip():
        raise ParameterError("--solver '': give a backend (clarabel, ipm or cvxpy:NAME)")
    if args.decompose and backend.startswith("cvxpy"):
        raise ParameterError(f"--decompose needs --solver clarabel or ipm, not {backend!r}")
    return SolverConfig(backend=backend, decompose=args.decompose, scale=getattr(args, "scale", "auto"), **fields)


def cmd_solve(args: argparse.Namespace) -> int:
    from .api import solve
    from .tightness import Criteria
    from .limits import check_size

    from .errors import ParameterError

    if args.skip_invalid and args.set in (None, "primary", "paper"):
        raise ParameterError("--skip-invalid applies to a saved set (--set FILE); it does nothing here")
    config = solver_config(args)
    prob = load(args.problem)
    params = prob.parse_params(parse_assignments(args.param))
    check_size(prob, params, config)
    check_random_starts(prob, params, args.random_starts, "--random-starts")
    if args.verify == "certificate":  # the certificate of the local solution first; the SDP only if it fails
        from .certify_cmd import certificate_first

        done = certificate_first(args, prob, params, constraints_arg(args.set, args.skip_invalid),
                                 Criteria(accept=args.accept))
        if done is not None:
            return done
    out = solve(prob, params, args.seed, constraints=constraints_arg(args.set, args.skip_invalid), solver=config,
                n_random=args.random_starts, criteria=Criteria(accept=args.accept))
    inst = out.instance
    rec = out.record()
    if args.json:
        rec |= {"scale": config.scale, "measurements": inst.measurements, "truth": inst.truth, "estimate": out.estimate,
                "versions": versions()}
        print(json.dumps(jsonable(rec), ensure_ascii=False))
        return _failed(out)
    v = out.verdict
    print(f"problem {prob.name}  params {inst.params}  seed {inst.seed}")
    print(f"constraints: {rec['constraint_set']} ({rec['n_constraints']})  solver {out.sdp.solver}")
    print(f"SDP: status {out.sdp.status}  cost {out.sdp.primal_cost:.10g}  log SVR {out.sdp.log_svr:.2f}  "
          f"{out.outcome.upper()} ({v.reason})")
    raw = out.sdp.dual_cost_raw
    print(f"bounds: L {v.lower:.10g} ≤ optimum ≤ best feasible {out.upper:.10g}  (SDP dual {out.sdp.dual_cost:.10g}"
          + (f", the solver's own {raw:.10g} before the polish" if np.isfinite(raw) else "")
          + "; L corrects it for λ_min(H) < 0)")
    print(f"local solver from ground truth: cost {out.local.from_truth.cost:.10g}  "
          f"({out.local.from_truth.iterations} it, {out.local.from_truth.message})")
    for r in out.local.from_random:
        print(f"local solver from a random start: cost {r.cost:.10g}"
              f"{'  (trapped)' if r.cost > out.upper * (1 + 1e-6) + 1e-12 else ''}")
    if out.refined is not None:
        print(f"local solver from the SDP estimate: cost {out.refined.cost:.10g}"
              f"{'  (better than every local search)' if out.sdp_beats_local else ''}")
    print(f"relative gap (upper bound − SDP)/upper bound: {v.rel_gap:.3e}")
    print(f"errors: SDP estimate {out.errors_sdp}  local {out.errors_local}")
    print("times: " + "  ".join(f"{k} {t:.3f}s" for k, t in out.times.items()))
    return _failed(out)


def _failed(out) -> int:
    """0, or SolverError when the SDP gave no usable solution (the result above says why)."""
    from .errors import SolverError

    if not out.sdp.usable:
        raise SolverError(f"the SDP solve failed: status {out.sdp.status} ({out.sdp.solver})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="autotight", description=__doc__.splitlines()[0],
                                 epilog="--debug (anywhere on the line): show the traceback of any error")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("list", help="list problems and their parameters")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("solve", help="solve one instance: SDP, local solver, tightness")
    _add_problem_args(p)
    p.add_argument("--set", default=None, metavar="primary|paper|FILE",
                   help="constraint set: primary, paper, or a saved set's JSON (from `discover --out`), applied "
                        "to this instance whatever its size (default: paper if the problem has paper families, "
                        "else primary)")
    p.add_argument("--skip-invalid", action="store_true",
                   help="with --set FILE: leave out the constraints of factors whose template fails its check on "
                        "this instance (default: a one-line error naming the factor)")
    add_solver_args(p)
    add_accept_arg(p)
    p.add_argument("--random-starts", type=nonneg_int, default=1, help="random-start local solves (default 1)")
    p.add_argument("--verify", default="sdp", choices=["sdp", "certificate"],
                   help="sdp (default): solve the SDP and judge it; certificate: certify the local solution from "
                        "the ground truth first, as `autotight certify` does, and solve the SDP only when that "
                        "is not certified (docs/certificates.md)")
    p.set_defaults(func=cmd_solve)
    from .certify_cmd import register as register_certify
    from .check_cli import register as register_check_module
    from .check_cmd import register as register_check
    from .discovery.cli import register as register_discover
    from .discovery.templates_cmd import register as register_templates
    from .export import register as register_export
    from .report.cli import register as register_report

    for register in (register_discover, register_report, register_check, register_check_module, register_certify,
                     register_templates, register_export):
        register(sub, _add_problem_args)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    try:
        return int(args.func(args) or 0)
    except AutotightError as e:
        if debug:
            raise
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
