"""The points of a range: every combination of the varied parameters' values on top of the fixed ones.

``parse_over`` validates the varied values by the problem's own ``Param`` parsers; ``points_of`` lists
(full params, varied values) in product order, the order in which ``check`` and discovery visit them.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from typing import Any

from .errors import ParameterError
from .problem import Problem


def parse_over(problem: Problem, over: Mapping[str, Sequence[Any]] | None) -> dict[str, list[Any]]:
    """Validate each varied parameter's values (by the problem's ``Param``), sorted, without duplicates."""
    out: dict[str, list[Any]] = {}
    for name, values in (over or {}).items():
        if name not in problem.params:
            raise ParameterError(f"unknown parameter {name!r} to vary for {problem.name}; known: "
                                 f"{', '.join(problem.params)}")
        vals = [problem.params[name].parse(name, v) for v in values]
        if not vals:
            raise ParameterError(f"no values given for {name}")
        if len(set(vals)) != len(vals):
            raise ParameterError(f"duplicate values for {name}: {vals}")
        out[name] = sorted(vals)
    return out


def points_of(problem: Problem, params: Mapping[str, Any] | None,
              over: Mapping[str, Sequence[Any]]) -> list[tuple[dict, dict]]:
    """(full params, varied values) for every point of the product of ``over``, in order."""
    fixed = dict(params or {})
    clash = [k for k in over if k in fixed]
    if clash:
        raise ParameterError(f"parameter {clash[0]} is both fixed (-p) and varied; give it once")
    names = list(over)
    out = []
    for combo in itertools.product(*(over[n] for n in names)) if names else [()]:
        varied = dict(zip(names, combo))
        out.append((problem.parse_params(fixed | varied), varied))
    return out
