"""Checks of command-line input made before any work: option values, the solver, constraint-set files.

Option types (``nonneg_int``, ``nonneg_float``) are argparse ``type=`` functions: a negative,
NaN or infinite value is refused with one line.  ``check_solver`` refuses a backend that is
unknown or not installed (``cvxpy:NAME`` when cvxpy lacks NAME).  ``check_set_file`` reads a
saved constraint set's JSON and refuses one that is not an object, lacks ``problem`` or
``pairs``, or has a malformed field (``autotight.set_file``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Callable

from .errors import ParameterError


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
    from .sdp.config import SolverConfig, SolverConfigError

    try:
        SolverConfig(backend=name)
    except SolverConfigError as e:
        raise ParameterError(f"--solver: {e}") from None
    return name


def check_set_file(path: str | Path, option: str = "--set") -> dict[str, Any]:
    """The JSON object of a saved constraint set (``discover --out``), checked as the module docstring says."""
    from .discovery.discovered import FORMAT, FORMAT_V1
    from .set_file import check_fields

    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"{option} {path}: no such file")
    try:
        obj = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ParameterError(f"{option} {path}: not a readable JSON file ({e})") from None
    if not isinstance(obj, dict):
        raise ParameterError(f"{option} {path}: a constraint-set file holds a JSON object, not {type(obj).__name__}")
    if obj.get("format") not in (FORMAT, FORMAT_V1):
        raise ParameterError(f"{option} {path}: not a constraint-set file (format {obj.get('format')!r}, "
                             f"expected {FORMAT!r})")
    missing = [k for k in ("problem", "pairs") if k not in obj]
    if missing:
        raise ParameterError(f"{option} {path}: lacks {' and '.join(repr(k) for k in missing)}")
    if not isinstance(obj["problem"], str):
        raise ParameterError(f"{option} {path}: 'problem' must be a problem name")
    pairs = obj["pairs"]
    if not isinstance(pairs, list) or not all(isinstance(x, dict) and isinstance(x.get("factor_type"), str)
                                              and isinstance(x.get("identity"), str) for x in pairs):
        raise ParameterError(f"{option} {path}: 'pairs' must be a list of {{factor_type, identity}} objects")
    opts = obj.get("learn_options", {})
    if not isinstance(opts, dict):
        raise ParameterError(f"{option} {path}: 'learn_options' must be an object")
    if not isinstance(obj.get("params", {}), dict):
        raise ParameterError(f"{option} {path}: 'params' must be an object")
    why = check_fields(obj)
    if why:
        raise ParameterError(f"{option} {path}: {why}")
    return obj
