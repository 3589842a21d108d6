"""A discovered set: (factor type, identity) pairs that carry over to any instance, saved as JSON."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import AutotightError, LearningError
from ..io import versions, write_json
from ..model import Constraint, Model
from ..pretty import polynomial
from ..problem import Instance, Problem
from .catalog import Pair, carry_over
from .learn import LearnOptions

FORMAT = "autotight.discovered/1"


def constraint_record(c: Constraint, model: Model) -> dict[str, Any]:
    """A constraint as sparse upper-triangle triplets (i, j, A_ij) with its readable form."""
    U = sp.triu(sp.coo_array(c.A)).tocoo()
    return {"name": c.name, "factor": c.factor, "identity": c.identity, "family": c.family, "b": c.b,
            "triplets": [[int(i), int(j), float(v)] for i, j, v in zip(U.row, U.col, U.data)],
            "readable": polynomial(c.A, model.variables, c.b)}


@dataclass
class DiscoveredSet:
    """The pairs found by discovery on (problem, params, seed) and how they were learned."""

    problem: str
    params: dict[str, Any]
    seed: int | None
    pairs: list[Pair]
    learn_options: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    groups: str | list[list[str]] = "factors"

    def options(self) -> LearnOptions:
        return LearnOptions(**self.learn_options) if self.learn_options else LearnOptions()

    def instantiate(self, problem: Problem, inst: Instance, rng: np.random.Generator,
                    model: Model | None = None, strict: bool = True) -> list[Constraint]:
        """The set's constraints on ``inst`` (each checked on held-out samples of ``inst``).

        strict: any shortfall (per factor type, fewer constraints than pairs × factors of the type)
        or identity rejected on held-out samples raises LearningError naming the factor types and
        their counts; strict=False returns what was instantiated."""
        if problem.name != self.problem:
            raise AutotightError(f"discovered set is for {self.problem!r}, not {problem.name!r}")
        co = carry_over(problem, inst, self.pairs, rng, self.options(), model, self.groups)
        if co.issues and strict:
            raise LearningError(f"cannot re-instantiate the discovered set: {co.message() or co.issues[0]}")
        return co.constraints

    def save(self, path: str | Path, model: Model | None = None, constraints: list[Constraint] | None = None,
             extra: dict[str, Any] | None = None) -> None:
        obj: dict[str, Any] = {
            "format": FORMAT, "problem": self.problem, "params": self.params, "seed": self.seed,
            "versions": versions(), "learn_options": self.learn_options, "groups": self.groups,
            "pairs": [{"factor_type": t, "identity": i} for t, i in self.pairs], "info": self.info,
        }
        if model is not None:
            obj["variables"] = [{"block": n, "size": model.variables.sizes[n], "offset": model.variables.offsets[n]}
                                for n in model.variables.names]
            obj["d"] = model.d
        if constraints is not None and model is not None:
            groups: dict[str, list] = {}
            for c in constraints:
                groups.setdefault(c.factor or "", []).append(constraint_record(c, model))
            obj["constraints_by_factor"] = groups
        obj |= extra or {}
        write_json(path, obj)

    @classmethod
    def load(cls, path: str | Path) -> "DiscoveredSet":
        try:
            obj = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as e:
            raise AutotightError(f"cannot read discovered set {path}: {e}") from None
        if obj.get("format") != FORMAT:
            raise AutotightError(f"{path} is not a discovered-set file (format {obj.get('format')!r})")
        pairs = [(p["factor_type"], p["identity"]) for p in obj["pairs"]]
        return cls(obj["problem"], obj["params"], obj.get("seed"), pairs, obj.get("learn_options", {}),
                   obj.get("info", {}), obj.get("groups", "factors"))
