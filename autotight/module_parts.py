"""The fields of a problem's ``META`` (``autotight.meta.Meta``), each validated where it is read and by
``check-module``:

- ``sigmas``: the noise levels of ``report``, a non-empty sequence of finite numbers > 0;
- ``paper_claim``: what the paper reports, shown by ``report``: a dict with optional ``source``,
  ``set`` and ``default`` (strings) and ``by_sigma`` ({σ > 0: text});
- ``default_groups``: discovery's learning groups, "factors", "whole", "adjacent:…" or a list of block-name lists;
- ``carry_to``: a hint of the sizes a discovered set must also pass at, ``{"params": {name: value},
  "solver": backend}`` (``solver`` optional);
- ``check_params``: the parameters ``check-module`` uses, valid by ``PARAMS``.

Each reader returns the value (or the default when the field is not given) and raises
``ProblemDefinitionError`` naming the module, the field and what is wrong, so a bad value is one line
before any work instead of a traceback after it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from numbers import Real
from typing import Any, Callable

import numpy as np

from .errors import AutotightError, ProblemDefinitionError

#: keys ``META.paper_claim`` may hold
CLAIM_KEYS = ("source", "set", "default", "by_sigma")


def _bad(problem: Any, part: str, what: str) -> ProblemDefinitionError:
    return ProblemDefinitionError(f"{problem.where()}: META.{part} {what}")


def _number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, Real) and math.isfinite(float(v))


def sigmas(problem: Any, default: Sequence[float] = ()) -> tuple[float, ...]:
    """``sigmas`` as floats (``default`` when not given)."""
    v = problem.meta.sigmas
    if v is None:
        return tuple(float(s) for s in default)
    if isinstance(v, np.ndarray) and v.ndim == 1:
        v = v.tolist()
    if isinstance(v, (str, bytes, Mapping)) or not isinstance(v, Sequence) or not len(v):
        raise _bad(problem, "sigmas", f"must be a non-empty list of noise levels, got {v!r}")
    bad = [s for s in v if not _number(s) or s <= 0]
    if bad:
        raise _bad(problem, "sigmas", f"must hold finite numbers > 0, got {bad[0]!r}")
    return tuple(float(s) for s in v)


def paper_claim(problem: Any) -> dict[str, Any] | None:
    """``paper_claim`` with ``by_sigma``'s keys as floats, or None when not given."""
    v = problem.meta.paper_claim
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise _bad(problem, "paper_claim", f"must be a dict ({', '.join(CLAIM_KEYS)}), got {type(v).__name__}")
    unknown = sorted(str(k) for k in v if k not in CLAIM_KEYS)
    if unknown:
        raise _bad(problem, "paper_claim", f"has unknown key(s) {', '.join(unknown)}; known: {', '.join(CLAIM_KEYS)}")
    for k in ("source", "set", "default"):
        if k in v and not isinstance(v[k], str):
            raise _bad(problem, "paper_claim", f"{k!r} must be text, got {type(v[k]).__name__}")
    by = v.get("by_sigma", {})
    if not isinstance(by, Mapping):
        raise _bad(problem, "paper_claim", f"'by_sigma' must be a dict {{σ: text}}, got {type(by).__name__}")
    out: dict[float, str] = {}
    for k, text in by.items():
        try:
            s = float(k)
        except (TypeError, ValueError):
            s = float("nan")
        if not (math.isfinite(s) and s > 0) or not isinstance(text, str):
            raise _bad(problem, "paper_claim", f"'by_sigma' must map noise levels > 0 to text, got {k!r}: {text!r}")
        out[s] = text
    return dict(v) | ({"by_sigma": out} if "by_sigma" in v else {})


def default_groups(problem: Any) -> Any:
    """``default_groups`` ("factors" when not given): a spec string or a list of block-name lists."""
    v = problem.meta.default_groups
    if isinstance(v, str) and v.strip():
        return v
    if isinstance(v, Sequence) and not isinstance(v, (str, bytes)) and v and all(
            isinstance(g, Sequence) and not isinstance(g, (str, bytes)) and g and all(isinstance(b, str) for b in g)
            for g in v):
        return v
    raise _bad(problem, "default_groups", f"must be 'factors', 'whole', 'adjacent:…' or a list of block-name lists, "
                                          f"got {v!r}")


def carry_to(problem: Any) -> tuple[dict[str, Any], str | None]:
    """``carry_to`` as (parameters a discovered set must also pass at, each parsed; suggested backend or
    None); ({}, None) when not given."""
    spec = problem.meta.carry_to
    if spec is None:
        return {}, None
    if (not isinstance(spec, Mapping) or set(spec) - {"params", "solver"} or not isinstance(spec.get("params"), Mapping)
            or not isinstance(spec.get("solver", ""), str)):
        raise _bad(problem, "carry_to", f"must be {{'params': {{name: value}}, 'solver': backend}}, got {spec!r}")
    values = dict(spec["params"])
    try:
        problem.parse_params(values)
    except AutotightError as e:
        raise _bad(problem, "carry_to", f"is invalid: {str(e).splitlines()[0]}") from None
    return {k: problem.params[k].parse(k, v) for k, v in values.items()}, spec.get("solver")


def check_params(problem: Any) -> dict[str, Any]:
    """``check_params`` as given (empty when not given); each value must parse by ``PARAMS``."""
    v = problem.meta.check_params
    if not isinstance(v, Mapping):
        raise _bad(problem, "check_params", f"must be a dict of parameters, got {type(v).__name__}")
    try:
        problem.parse_params(dict(v))
    except AutotightError as e:
        raise _bad(problem, "check_params", f"is invalid: {str(e).splitlines()[0]}") from None
    return dict(v)


#: every declared value with its reader, in the order check-module reports them
READERS: dict[str, Callable[[Any], Any]] = {
    "META.sigmas": sigmas, "META.paper_claim": paper_claim, "META.default_groups": default_groups,
    "META.carry_to": carry_to, "META.check_params": check_params,
}
