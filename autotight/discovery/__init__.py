"""Discovery of redundant constraints: learn per group, tighten greedily, reduce, validate, carry over.

``discover(problem, params, seed)`` runs the engine (``engine``); ``DiscoveredSet`` is its portable
result (pairs of factor type and identity) with ``load``/``save``/``instantiate``.
"""

from .catalog import Catalog, instantiate, learn
from .discovered import DiscoveredSet
from .engine import discover
from .learn import Group, LearnOptions
from .result import DiscoveryResult

__all__ = ["discover", "DiscoveryResult", "DiscoveredSet", "LearnOptions", "Group", "learn", "instantiate", "Catalog"]
