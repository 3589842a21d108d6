"""Discovery of redundant constraints: learn per group, tighten greedily, reduce, carry over.

``discover(problem, params, seed)`` runs the whole pipeline; ``DiscoveredSet`` is its portable
result (pairs of factor type and identity) with ``load``/``save``/``instantiate``.
"""

from .catalog import Catalog, instantiate, learn
from .discovered import DiscoveredSet
from .learn import Group, LearnOptions
from .pipeline import DiscoveryResult, discover

__all__ = ["discover", "DiscoveryResult", "DiscoveredSet", "LearnOptions", "Group", "learn", "instantiate", "Catalog"]
