"""What every verb shares: its options, their checks, and the parsing of their values.

Option types (``nonneg_int``, ``pos_int``, ``nonneg_float``, ``pos_float``) are argparse ``type=``
functions: a negative, NaN or infinite value is refused with one line.  ``check_solver`` refuses a
backend that is unknown or not installed.  The shared options: the problem and its parameters
(``add_problem_args``), ``--set`` (``constraints_arg``), ``--solver``/``--decompose``/``--scale``
(``add_solver_args``, ``solver_config``), ``--accept`` (``add_accept_arg``), and ``--sigmas``/``--range``
(``add_range_args``, ``parse_range``).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any, Callable, Sequence

from ..errors import ParameterError


def _number(kind: Callable[[str], Any], what: str, low: float, low_open: bool = False) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        bad = not math.isfinite(v) or v < low or (low_open and v == low)
        if bad:
            raise argparse.ArgumentTypeError(f"must be a finite number {'>' if low_open else '≥'} {low:g}, got {text}")
        return v

    parse.__name__ = what
    return parse


nonneg_int = _number(int, "an integer", 0)
pos_int = _number(int, "an integer", 1)
nonneg_float = _number(float, "a number", 0.0)
pos_float = _number(float, "a number", 0.0, low_open=True)


def check_solver(name: str) -> str:
    """``name`` if the SDP layer knows it and its solver is installed (``SolverConfig`` validates
    both), else ParameterError naming ``--solver``."""
    from ..sdp.config import SolverConfig, SolverConfigError

    try:
        SolverConfig(backend=name)
    except SolverConfigError as e:
        raise ParameterError(f"--solver: {e}") from None
    return name


def add_problem_args(p: argparse.ArgumentParser) -> None:
    """The problem (a name or a .py path), ``--param NAME=VALUE``, ``--seed`` and ``--json``."""
    p.add_argument("problem", help="problem name (see `autotight list`) or path to a .py problem module")
    p.add_argument("--param", "-p", action="append", default=[], metavar="NAME=VALUE",
                   help="problem parameter, repeatable (e.g. --param M=10 --param sigma=0.1)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="instance seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def constraints_arg(value: str | None, skip_invalid: bool = False, points: Sequence[dict[str, Any]] = ()):
    """``--set``: "primary", "paper", or the path of a saved constraint set (JSON).  For a saved set, one line on
    stderr when its discovery failed validation, and one naming the parameter points of ``points`` (full
    parameters) outside those its held-out validation ran at (``DiscoveredSet.scope_note``)."""
    if value is None or value in ("primary", "paper"):
        return value
    from ..set_file import check_set_file
    from ..constraint_set import ConstraintSet

    check_set_file(value)
    cs = ConstraintSet.load(value, skip_invalid=skip_invalid)
    warning = cs.discovered.validation_warning()
    if warning:
        print(f"warning: {value}: {warning}", file=sys.stderr)
    note = cs.discovered.scope_note(points)
    if note:
        print(f"note: {value}: {note}", file=sys.stderr)
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
                        "columns where some columns, or combinations of them, are free; a certificate alone "
                        "also decides a bracket the solver's accuracy leaves open); certified: the dual "
                        "certificate alone")


def solver_config(args: argparse.Namespace, default_backend: str = "auto", **fields: Any):
    """The ``SolverConfig`` of ``--solver``/``--decompose``/``--scale`` (validated before any work);
    ``default_backend`` when --solver was not given."""
    from ..sdp.config import SolverConfig

    backend = default_backend if args.solver is None else args.solver
    if not backend.strip():
        raise ParameterError("--solver '': give a backend (clarabel, ipm or cvxpy:NAME)")
    if args.decompose and backend.startswith("cvxpy"):
        raise ParameterError(f"--decompose needs --solver clarabel or ipm, not {backend!r}")
    return SolverConfig(backend=backend, decompose=args.decompose, scale=getattr(args, "scale", "auto"), **fields)


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
