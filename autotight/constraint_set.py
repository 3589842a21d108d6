"""Which constraints an SDP gets: ``ConstraintSet`` and the names ``"primary"`` and ``"paper"``.

A constraint set is applied to one instance at a time, so the same set serves any instance and
any size of its problem:

- ``"primary"``: the homogenisation (h² = 1, or X_hh = I_d) and the problem's primary constraints;
- ``"paper"``: those plus every hand-derived family of the paper (``Model.paper``);
- a ``ConstraintSet`` learned by ``discover``: the primary constraints plus, on every factor of
  each learned type, the learned identities (``(factor type, identity)`` pairs), evaluated from their
  templates (``autotight.discovery.templates``: coefficients polynomial in the factor's measurements)
  and checked on fresh feasible states of the instance; types without a template are re-learned;
- a list of ``Constraint``: the primary constraints plus exactly these (for one instance).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np

from .errors import AutotightError, ParameterError
from .model import Constraint, Model
from .problem import Instance, Problem

NAMED = ("primary", "paper")


@dataclass
class ConstraintSet:
    """A learned constraint set: ``(factor type, identity)`` pairs of one problem.

    ``discovered`` is the saved form (``autotight.discovery.DiscoveredSet``); ``apply`` re-creates
    the constraints on any instance of the problem.  ``save``/``load`` use JSON (see
    ``docs/constraint_sets.md``).
    """

    discovered: Any  # autotight.discovery.DiscoveredSet (imported lazily: discovery imports this module's users)
    skip_invalid: bool = False
    """Leave out the constraints of factors whose template fails its check (default: AutotightError)."""

    @property
    def problem(self) -> str:
        return self.discovered.problem

    @property
    def pairs(self) -> list[tuple[str, str]]:
        return list(self.discovered.pairs)

    def __len__(self) -> int:
        return len(self.discovered.pairs)

    def __repr__(self) -> str:
        return f"ConstraintSet(problem={self.problem!r}, pairs={len(self)})"

    def apply(self, problem: Problem, inst: Instance, model: Model, rng: np.random.Generator) -> list[Constraint]:
        """The learned constraints on ``inst`` (without the primary ones): templates evaluated and checked on
        fresh states of ``inst``; a set of another problem or block layout is an AutotightError."""
        if not hasattr(self.discovered, "apply"):  # a stand-in with only the re-learning route
            return self.discovered.instantiate(problem, inst, rng, model=model)
        return self.discovered.apply(problem, inst, model, rng, skip_invalid=self.skip_invalid)

    def save(self, path: str | Path, model: Model | None = None, constraints: Sequence[Constraint] | None = None,
             extra: dict[str, Any] | None = None, replace: bool = False) -> Path:
        """Write the set as JSON; with ``model`` and ``constraints`` also the learning instance's constraints.
        An existing file is kept unless ``replace`` (the set is then saved beside it); returns the path written."""
        return self.discovered.save(path, model, None if constraints is None else list(constraints), extra,
                                    replace=replace)

    @classmethod
    def load(cls, path: str | Path, skip_invalid: bool = False) -> "ConstraintSet":
        """A saved set (format 2, or format 1 whose templates are learned on first use); a file that is not one,
        or has a malformed field (``autotight.set_file``), is a ParameterError."""
        from .set_file import check_set_file
        from .discovery.discovered import DiscoveredSet

        check_set_file(path, option="constraint set")
        return cls(DiscoveredSet.load(path), skip_invalid)


ConstraintsLike = Union[str, ConstraintSet, Sequence[Constraint], None]


def set_name(constraints: ConstraintsLike, model: Model) -> str:
    """The name a result records for ``constraints`` (None → the default for ``model``)."""
    if constraints is None:
        return default_name(model)
    if isinstance(constraints, str):
        return constraints
    if isinstance(constraints, ConstraintSet):
        return "discovered"
    return "custom"


def default_name(model: Model) -> str:
    """"paper" when the problem has hand-derived families, else "primary"."""
    return "paper" if model.paper else "primary"


def named(model: Model, name: str) -> list[Constraint]:
    """The named sets on ``model``: "primary" (homogenisation and primary constraints) or "paper"
    (those plus every paper family); ParameterError for another name or a model without families."""
    if name == "primary":
        return model.primary()
    if name == "paper":
        if not model.paper:
            raise ParameterError("this problem has no paper families; use 'primary' or a learned set")
        return model.primary() + model.paper_constraints()
    raise ParameterError(f"unknown constraint set {name!r}; use 'primary', 'paper', a ConstraintSet "
                         "or a list of Constraint")


def resolve(constraints: ConstraintsLike, problem: Problem, inst: Instance, model: Model,
            rng: np.random.Generator) -> list[Constraint]:
    """Every constraint of the SDP for ``inst``: homogenisation, primary and the set's own."""
    if constraints is None:
        constraints = default_name(model)
    if isinstance(constraints, str):
        if constraints == "paper" and not model.paper:
            raise ParameterError(f"problem {problem.name} has no paper families; use 'primary' or a learned set")
        return named(model, constraints)
    if isinstance(constraints, ConstraintSet):
        if constraints.problem != problem.name:
            raise AutotightError(f"the constraint set is for {constraints.problem!r}, not {problem.name!r}")
        return model.primary() + constraints.apply(problem, inst, model, rng)
    extra = list(constraints)
    bad = [type(c).__name__ for c in extra if not isinstance(c, Constraint)]
    if bad:
        raise ParameterError(f"constraints must be 'primary', 'paper', a ConstraintSet or Constraint objects, "
                             f"got {bad[0]}")
    return model.primary() + extra
