"""``autotight certify``: certify a local solution without solving the full SDP (``autotight.certify``).

Exit status: 0 certified, 1 not certified, 2 bad input (``autotight.cli.main``).
"""

from __future__ import annotations

import argparse
import gc
import json
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

from ..io import jsonable, versions



def start_arg(value: str) -> Any:
    """``--from``: "truth", "random", or a JSON file with a state: {variable: array}, or an object
    whose "state" or "estimate" holds one (e.g. the output of ``autotight solve --json``)."""
    if value in ("truth", "random"):
        return value
    from ..errors import ParameterError

    path = Path(value)
    if not path.is_file():
        raise ParameterError(f"--from {value!r}: not 'truth', 'random' or an existing JSON file")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ParameterError(f"--from {value}: not readable JSON ({e})") from e
    if isinstance(data, dict):
        for key in ("state", "estimate"):
            if isinstance(data.get(key), dict):
                return data[key]
        return data
    raise ParameterError(f"--from {value}: expected a JSON object with the state's variables")


@contextmanager
def _without_cyclic_gc() -> Iterator[None]:
    """Automatic cyclic garbage collection off inside the block (its previous state restored after).  A command
    holds ~10⁵ long-lived objects (the model's and the constraint set's constraints) that each automatic
    collection would traverse again, and makes no reference cycles of note: reference counting frees its
    arrays."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def cmd_certify(args: argparse.Namespace) -> int:
    from ..api import _seed
    from ..certifier import certify_instance
    from ..limits import check_certify_size
    from ..problem import load, parse_assignments
    from ..validate import check_data
    from .options import constraints_arg

    start = start_arg(args.start)
    prob = load(args.problem)
    params = prob.parse_params(parse_assignments(args.param))
    with _without_cyclic_gc():
        check_certify_size(prob, params)
        inst = prob.generate(params, _seed(args.seed))
        model = prob.build(inst)
        check_data(prob, inst, model)  # NaN/inf data, weights beyond the solver's reach
        cons = constraints_arg(args.set, points=[params])
        run = certify_instance(prob, inst, cons, start=start, model=model)
    c = run.certificate
    rec = {"problem": prob.name, "params": inst.params, "seed": inst.seed,
           "constraint_set": run.constraint_set,
           "n_constraints": len(run.constraints), "start": run.start,
           "local": {"cost": run.local.cost, "converged": run.local.converged, "iterations": run.local.iterations},
           **c.record()}
    if args.json:
        print(json.dumps(jsonable(rec | {"state": run.local.state, "versions": versions()}), ensure_ascii=False))
    else:
        _header(prob, run, f"{run.start}: cost {run.local.cost:.10g} ({run.local.iterations} it)")
        print(f"{'CERTIFIED' if c.certified else 'NOT CERTIFIED'}: f(x̂) − p* ≤ {c.bound:.3e} "
              f"(relative {c.rel_bound:.3e})  λ_min(H) ≥ {c.lambda_lower:.3e}"
              + (f"  by {c.argument}" if c.argument else ""))
        if c.assumptions and c.certified:
            print(f"assuming: {c.assumptions}")
        if c.face:
            print(f"face: {c.face}")
        if c.message:
            print(c.message)
        print(f"method: {c.method}")
        print(f"time: {c.time_s:.3f}s")
    return 0 if c.certified else 1


def _header(prob: Any, run: Any, start: str) -> None:
    """The first two lines of a certify run's text output: the instance, the set and the local solve."""
    print(f"problem {prob.name}  params {run.instance.params}  seed {run.instance.seed}")
    print(f"constraints: {run.constraint_set} ({len(run.constraints)})  local solve from {start}")


def certificate_first(args: argparse.Namespace, prob: Any, params: dict, constraints: Any, criteria: Any) -> int | None:
    """``solve --verify certificate``: certify the local solution from the ground truth first
    (``certify_instance``, the path of ``autotight certify``); when it is certified, print that and return
    0 without solving the SDP; else None (the caller solves the SDP, whose verdict then decides)."""
    from ..api import _seed
    from ..certifier import certify_instance

    inst = prob.generate(params, _seed(args.seed))
    run = certify_instance(prob, inst, constraints, start="truth", criteria=criteria)
    c = run.certificate
    if not c.certified:
        if not args.json:
            print(f"certificate of the local solution: not certified ({c.message or 'bound above tolerance'}); "
                  "solving the SDP")
        return None
    rec = {"problem": prob.name, "params": inst.params, "seed": inst.seed, "verify": "certificate",
           "outcome": "tight", "certified": True, "constraint_set": run.constraint_set,
           "n_constraints": len(run.constraints), "local_cost": run.local.cost, "certificate": c.record()}
    if args.json:
        print(json.dumps(jsonable(rec | {"estimate": run.local.state, "versions": versions()}), ensure_ascii=False))
    else:
        _header(prob, run, f"the ground truth: cost {run.local.cost:.10g}")
        print(f"CERTIFIED ({c.argument}): f(x̂) − p* ≤ {c.bound:.3e} (relative {c.rel_bound:.3e}); the SDP was not "
              f"solved (--verify certificate)")
        print(f"method: {c.method}")
    return 0


def register(sub: Any, add_problem_args: Callable[[argparse.ArgumentParser], None]) -> None:
    p = sub.add_parser("certify", help="certify a local solution without solving the full SDP",
                       description="Run the local solver from a start, then look for dual multipliers that prove "
                                   "its solution globally optimal for the relaxation (exit 0 certified, 1 not).")
    add_problem_args(p)
    p.add_argument("--set", default=None, metavar="primary|paper|FILE",
                   help="constraint set: primary, paper, or a saved set's JSON (default: paper if the problem has "
                        "paper families, else primary)")
    p.add_argument("--from", dest="start", default="truth", metavar="truth|random|FILE",
                   help="local solver start: the ground truth (default), the first random start of `solve`, or a "
                        "JSON state file (e.g. `autotight solve --json` output: its estimate)")
    p.set_defaults(func=cmd_certify)
