"""The optional declared values of a problem module, each validated where it is read and by ``check-module``.

A module may declare (``docs/problem_contract.md``):

- ``SIGMAS``: the noise levels of ``report``, a non-empty sequence of finite numbers > 0;
- ``PAPER_CLAIM``: what the paper reports, shown by ``report``: a dict with optional ``source``,
  ``set`` and ``default`` (strings) and ``by_sigma`` ({σ > 0: text});
- ``DEFAULT_GROUPS``: discovery's learning groups, "factors", "whole", "adjacent:…" or a list of block-name lists;
- ``CARRY_TO``: a hint of the sizes a discovered set must also pass at, ``{"params": {name: value},
  "solver": backend}`` (``solver`` optional);
- ``CHECK_PARAMS``: the parameters ``check-module`` uses, valid by ``PARAMS``.

Each reader returns the value (or the default when the module does not declare it) and raises
``ProblemDefinitionError`` naming the module, the part and what is wrong, so a bad value is one line
before any work instead of a traceback after it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from numbers import Real
from typing import Any, Callable

import numpy as np

from .errors import AutotightError, ProblemDefinitionError

#: keys ``PAPER_CLAIM`` may hold
CLAIM_KEYS = ("source", "set", "default", "by_sigma")

_MISSING = object()


def _bad(problem: Any, part: str, what: str) -> ProblemDefinitionError:
    return ProblemDefinitionError(f"{problem.where()}: {part} {what}")


def _number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, Real) and math.isfinite(float(v))


def sigmas(problem: Any, default: Sequence[float] = ()) -> tuple[float, ...]:
    """``SIGMAS`` as floats (``default`` when absent)."""
    v = getattr(problem.module, "SIGMAS", _MISSING)
    if v is _MISSING:
        return tuple(float(s) for s in default)
    if isinstance(v, np.ndarray) and v.ndim == 1:
        v = v.tolist()
    if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) or not len(v):
        raise _bad(problem, "SIGMAS", f"must be a non-empty list of noise levels, got {v!r}")
    bad = [s for s in v if not _number(s) or s <= 0]
    if bad:
        raise _bad(problem, "SIGMAS", f"must hold finite numbers > 0, got {bad[0]!r}")
    return tuple(float(s) for s in v)


def paper_claim(problem: Any) -> dict[str, Any] | None:
    """``PAPER_CLAIM`` with ``by_sigma``'s keys as floats, or None when absent."""
    v = getattr(problem.module, "PAPER_CLAIM", None)
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise _bad(problem, "PAPER_CLAIM", f"must be a dict ({', '.join(CLAIM_KEYS)}), got {type(v).__name__}")
    unknown = sorted(str(k) for k in v if k not in CLAIM_KEYS)
    if unknown:
        raise _bad(problem, "PAPER_CLAIM", f"has unknown key(s) {', '.join(unknown)}; known: {', '.join(CLAIM_KEYS)}")
    for k in ("source", "set", "default"):
        if k in v and not isinstance(v[k], str):
            raise _bad(problem, "PAPER_CLAIM", f"{k!r} must be text, got {type(v[k]).__name__}")
    by = v.get("by_sigma", {})
    if not isinstance(by, Mapping):
        raise _bad(problem, "PAPER_CLAIM", f"'by_sigma' must be a dict {{σ: text}}, got {type(by).__name__}")
    out: dict[float, str] = {}
    for k, text in by.items():
        try:
            s = float(k)
        except (TypeError, ValueError):
            s = float("nan")
        if not (math.isfinite(s) and s > 0) or not isinstance(text, str):
            raise _bad(problem, "PAPER_CLAIM", f"'by_sigma' must map noise levels > 0 to text, got {k!r}: {text!r}")
        out[s] = text
    return dict(v) | ({"by_sigma": out} if "by_sigma" in v else {})


def default_groups(problem: Any) -> Any:
    """``DEFAULT_GROUPS`` ("factors" when absent): a spec string or a list of block-name lists."""
    v = getattr(problem.module, "DEFAULT_GROUPS", "factors")
    if isinstance(v, str) and v.strip():
        return v
    if isinstance(v, Sequence) and not isinstance(v, (str, bytes)) and v and all(
            isinstance(g, Sequence) and not isinstance(g, (str, bytes)) and g and all(isinstance(b, str) for b in g)
            for g in v):
        return v
    raise _bad(problem, "DEFAULT_GROUPS", f"must be 'factors', 'whole', 'adjacent:…' or a list of block-name lists, "
                                          f"got {v!r}")


def carry_to(problem: Any) -> tuple[dict[str, Any], str | None]:
    """``CARRY_TO`` as (parameters a discovered set must also pass at, each parsed; suggested backend or
    None); ({}, None) when absent."""
    spec = getattr(problem.module, "CARRY_TO", None)
    if spec is None:
        return {}, None
    if (not isinstance(spec, Mapping) or set(spec) - {"params", "solver"} or not isinstance(spec.get("params"), Mapping)
            or not isinstance(spec.get("solver", ""), str)):
        raise _bad(problem, "CARRY_TO", f"must be {{'params': {{name: value}}, 'solver': backend}}, got {spec!r}")
    values = dict(spec["params"])
    try:
        problem.parse_params(values)
    except AutotightError as e:
        raise _bad(problem, "CARRY_TO", f"is invalid: {str(e).splitlines()[0]}") from None
    return {k: problem.params[k].parse(k, v) for k, v in values.items()}, spec.get("solver")


def check_params(problem: Any) -> dict[str, Any]:
    """``CHECK_PARAMS`` as given (empty when absent); each value must parse by ``PARAMS``."""
    v = getattr(problem.module, "CHECK_PARAMS", {})
    if not isinstance(v, Mapping):
        raise _bad(problem, "CHECK_PARAMS", f"must be a dict of parameters, got {type(v).__name__}")
    try:
        problem.parse_params(dict(v))
    except AutotightError as e:
        raise _bad(problem, "CHECK_PARAMS", f"is invalid: {str(e).splitlines()[0]}") from None
    return dict(v)


#: every declared value with its reader, in the order check-module reports them
READERS: dict[str, Callable[[Any], Any]] = {
    "SIGMAS": sigmas, "PAPER_CLAIM": paper_claim, "DEFAULT_GROUPS": default_groups,
    "CARRY_TO": carry_to, "CHECK_PARAMS": check_params,
}
