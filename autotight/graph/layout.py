"""The lifted vector of one instance of a factor-graph problem: its blocks, lift, recover and samples.

The truth fixes the variables' multiplicity (``declare.Variable``).  Blocks, in order: per variable
(declaration order), per element (index order), the main block ``name`` (one variable) or ``name{i}``
(a stack; ``Variable.block`` for ``name`` when given), then its lifting blocks ``block`` or ``block{i}``.
A state is ``{name: value or (N, *shape) stack}`` with one entry per declared variable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ProblemDefinitionError
from ..model import Variables
from .declare import Variable


@dataclass
class Element:
    """One variable of the instance: the declaration, its index in a stack (None: a single variable),
    its block names (main first) and its offset in the stacked tangent vector."""

    var: Variable
    index: int | None
    blocks: tuple[str, ...]
    tangent_offset: int

    @property
    def main(self) -> str:
        return self.blocks[0]

    @property
    def dof(self) -> int:
        return self.var.manifold.dof

    def value(self, state: Mapping[str, Any]) -> np.ndarray:
        v = np.asarray(state[self.var.name], float)
        return v if self.index is None else v[self.index]


class Layout:
    """The instance's elements and ``Variables`` (d = 1), with lift, recover and retraction."""

    def __init__(self, variables: Sequence[Variable], truth: Mapping[str, Any]):
        if not variables or not all(isinstance(v, Variable) for v in variables):
            raise ProblemDefinitionError("VARIABLES must be a non-empty list of autotight.graph.Variable")
        names = [v.name for v in variables]
        if len(set(names)) != len(names):
            raise ProblemDefinitionError(f"variable names must be unique, got {names}")
        self.variables = list(variables)
        self.elements: list[Element] = []
        self.counts: dict[str, int | None] = {}
        blocks: list[tuple[str, int]] = []
        offset = 0
        for var in self.variables:
            if var.name not in truth:
                raise ProblemDefinitionError(f"the truth has no entry {var.name!r} for variable {var.name!r}")
            shape, want = np.shape(truth[var.name]), var.manifold.shape
            if shape == want:
                count = None
            elif len(shape) == len(want) + 1 and shape[1:] == want:
                count = shape[0]
            else:
                raise ProblemDefinitionError(f"variable {var.name!r} on {var.manifold!r}: the truth's entry has shape "
                                             f"{shape}, expected {want} or (N, *{want})")
            self.counts[var.name] = count
            fits = var.fits()
            for i in [None] if count is None else range(count):
                sfx = "" if i is None else str(i)
                el = Element(var, i, ((var.block or var.name) + sfx,) + tuple(f.name + sfx for f in fits), offset)
                self.elements.append(el)
                blocks += [(el.main, var.manifold.size)] + [(b, f.size) for b, f in zip(el.blocks[1:], fits)]
                offset += el.dof
        self.n_tangent = offset
        self.V = Variables(blocks)
        self.by_main = {el.main: el for el in self.elements}
        for el in self.elements:  # also by name and index when the main block is renamed
            self.by_main.setdefault(el.var.name + ("" if el.index is None else str(el.index)), el)
        #: an element's index in ``elements`` (and in a value list), by main block
        self.position = {el.main: k for k, el in enumerate(self.elements)}
        #: the truth's values, element by element
        self.truth_values = self.values(truth)

    def element(self, main: str, where: str) -> Element:
        if main not in self.by_main:
            raise ProblemDefinitionError(f"{where}: unknown variable {main!r}; variables are {list(self.by_main)}")
        return self.by_main[main]

    def columns(self, el: Element) -> np.ndarray:
        """The element's columns of the lifted vector, main block first."""
        return self.V.index(el.blocks)

    def values(self, state: Mapping[str, Any]) -> list[np.ndarray]:
        """The elements' values in order (checked against the manifold's shape)."""
        out = []
        for el in self.elements:
            if el.var.name not in state:
                raise ProblemDefinitionError(f"the state has no entry {el.var.name!r}")
            x = el.value(state)
            if x.shape != el.var.manifold.shape:
                raise ProblemDefinitionError(f"state entry {el.var.name!r} has an element of shape {x.shape}, "
                                             f"expected {el.var.manifold.shape}")
            out.append(x)
        return out

    def state(self, values: Sequence[np.ndarray]) -> dict[str, np.ndarray]:
        """The state holding the elements' values."""
        out: dict[str, np.ndarray] = {}
        k = 0
        for var in self.variables:
            count = self.counts[var.name]
            if count is None:
                out[var.name] = np.asarray(values[k], float)
                k += 1
            else:
                out[var.name] = np.array(values[k:k + count], float).reshape((count,) + var.manifold.shape)
                k += count
        return out

    def lift(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """x = [h, blocks…] (N,) with h = 1."""
        x = np.zeros(self.V.N)
        x[0] = 1.0
        for el, v in zip(self.elements, values):
            x[self.columns(el)] = el.var.lifted(v)
        return x

    def recover(self, x: np.ndarray) -> list[np.ndarray]:
        """Each element's value: its main block (x divided by h when h ≠ 0) unembedded and projected."""
        x = np.asarray(x, float).reshape(-1)
        x = x / x[0] if x[0] != 0 else x
        return [el.var.manifold.project(el.var.manifold.unembed(x[self.V.slice(el.main)])) for el in self.elements]

    def retract(self, values: Sequence[np.ndarray], eps: np.ndarray) -> list[np.ndarray]:
        """Each element retracted by its slice of the stacked tangent vector ε (n_tangent,)."""
        return [el.var.manifold.retract(v, eps[el.tangent_offset:el.tangent_offset + el.dof])
                for el, v in zip(self.elements, values)]
