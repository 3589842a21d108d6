"""A factor-graph layer for problem modules: declare variables and factors, derive the contract's parts.

A module on this layer writes ``PARAMS``, ``generate``, ``VARIABLES`` (``Variable``: a manifold and its
lifting blocks) and ``factors(instance)`` (``Factor``: residual, optional Jacobian, lifted cost and
constraints, data; ``Family``: many factors of one type at once, on stacks; ``Group``: a learning group of
blocks with no cost), then
``build, lift, cost, sample, local_solve, recover = derive(VARIABLES, factors)``.
``derive(…, width=fn)`` lifts a matrix Θ of width d (the paper's matrix lifting) instead of a vector.
See ``docs/factor_graph.md`` and the worked example ``docs/range_only_2d.md``.
"""

from .declare import Auxiliary, Factor, Family, Group, Variable, View
from .derive import Parts, derive
from .manifolds import Binary, Euclidean, Manifold, Rotation

__all__ = ["Auxiliary", "Binary", "Euclidean", "Factor", "Family", "Group", "Manifold", "Parts", "Rotation", "Variable",
           "View", "derive"]
