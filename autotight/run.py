"""Deprecated module kept for old imports: use ``autotight.pipeline`` and ``autotight.sdp``."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from . import sdp
from .model import Constraint, Model
from .pipeline import LocalSearch, local_search
from .sdp.config import SolverConfig
from .sdp.result import SDPResult

__all__ = ["LocalSearch", "local_search", "solve_sdp"]


def solve_sdp(model: Model, constraints: Sequence[Constraint], config: SolverConfig = SolverConfig(),
              scale: np.ndarray | None = None) -> SDPResult:
    """Deprecated: ``sdp.solve_model``."""
    return sdp.solve_model(model, constraints, config, scale)
