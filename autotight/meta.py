"""``Meta``: how autotight's tools treat a problem, declared in one object apart from its mathematics.

A problem module declares its variables, factors, cost and constraints; what the tools do with it
(the noise levels ``report`` sweeps, what the paper claims, discovery's learning groups and carry hint,
``check-module``'s parameters, sampling spreads) is policy, declared as one optional value::

    META = Meta(sigmas=(0.01, 0.1, 1.0), paper_claim={"source": "Fig. 5", "default": "rank 1"})

Every field is optional; an absent field takes the tools' default.  The values are checked where
they are read (``autotight.module_parts``: the readers name the module and the field), so that
``check-module`` reports a malformed one as a failed check instead of refusing to load the module.
``spread`` and ``random_spread`` are checked when the module loads (``Problem``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

#: the module-level names the fields replace (a module that still declares one is refused with a hint)
LOOSE_NAMES = {"SIGMAS": "sigmas", "PAPER_CLAIM": "paper_claim", "DEFAULT_GROUPS": "default_groups",
               "CARRY_TO": "carry_to", "CHECK_PARAMS": "check_params", "SPREAD": "spread",
               "RANDOM_SPREAD": "random_spread"}


@dataclass(frozen=True, kw_only=True)
class Meta:
    """Tool policy of one problem.

    sigmas: the noise levels ``report`` sweeps when ``--sigmas`` is not given (None: 7 log-spaced
        levels over 1e-3 … 1); finite numbers > 0.
    paper_claim: what the paper reports for its families, shown in the report's "Against the paper" table:
        ``{"source": str, "set": str, "default": str, "by_sigma": {σ: str}}``, each key optional.
    default_groups: discovery's learning groups when ``--groups`` is not given: "factors", "whole",
        "adjacent:…" or a list of block-name lists.
    carry_to: a hint of the sizes a discovered set must also pass at, ``{"params": {name: value},
        "solver": backend}`` (``solver`` optional); discovery does not need it.
    check_params: the parameters ``check-module`` uses when none are given (default: ``PARAMS``' defaults).
    spread: the spread of the feasible samples discovery and ``check-module`` draw (> 0).
    random_spread: the spread of the derived ``random_state`` around the truth (> 0; π: a rotation by
        |N(0, π² I)| is far from the nominal).
    """

    sigmas: Sequence[float] | None = None
    paper_claim: Mapping[str, Any] | None = None
    default_groups: str | Sequence[Sequence[str]] = "factors"
    carry_to: Mapping[str, Any] | None = None
    check_params: Mapping[str, Any] = field(default_factory=dict)
    spread: float = 0.5
    random_spread: float = math.pi
