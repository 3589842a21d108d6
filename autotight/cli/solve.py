"""``autotight solve PROBLEM``: one instance — local solves, the SDP with a constraint set, the verdict.

Exit status: 0 when the SDP returned a usable solution (whatever the verdict), 2 on bad input or a failed
solve (``SolverError``).
"""

from __future__ import annotations

import argparse
import json
from typing import Any, Callable

import numpy as np

from ..errors import ParameterError, SolverError
from ..io import jsonable, versions
from ..limits import check_random_starts
from ..problem import load, parse_assignments
from .options import add_accept_arg, add_solver_args, constraints_arg, nonneg_int, solver_config


def register(sub: Any, add_problem_args: Callable[[argparse.ArgumentParser], None]) -> None:
    p = sub.add_parser("solve", help="solve one instance: SDP, local solver, tightness")
    add_problem_args(p)
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


def cmd_solve(args: argparse.Namespace) -> int:
    from ..api import solve
    from ..limits import check_certify_size
    from ..tightness import Criteria

    if args.skip_invalid and args.set in (None, "primary", "paper"):
        raise ParameterError("--skip-invalid applies to a saved set (--set FILE); it does nothing here")
    config = solver_config(args)
    prob = load(args.problem)
    params = prob.parse_params(parse_assignments(args.param))
    check_random_starts(prob, params, args.random_starts, "--random-starts")
    constraints = constraints_arg(args.set, args.skip_invalid, points=[params])
    if args.verify == "certificate":  # the certificate of the local solution first; the SDP only if it fails
        from .certify import certificate_first

        check_certify_size(prob, params)  # ``solve`` checks the SDP's size itself, before any work

        done = certificate_first(args, prob, params, constraints, Criteria(accept=args.accept))
        if done is not None:
            return done
    out = solve(prob, params, args.seed, constraints=constraints, solver=config,
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
    """0, or SolverError when the SDP gave no usable solution and no certificate decided the verdict (the
    result above says why)."""
    if not out.sdp.usable and not out.tight:
        raise SolverError(f"the SDP solve failed: status {out.sdp.status} ({out.sdp.solver})")
    return 0
