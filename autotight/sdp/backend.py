"""What an SDP backend provides (``Backend``), as ``registry.BACKENDS`` holds it."""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np
import scipy.sparse as sp

from .config import Retries, SolverConfig
from .result import SDPResult


class Backend(Protocol):
    """What a solver backend provides: its name, whether solves decompose by default, the clique-cover
    policy it takes (None: none), the backend that re-solves an unusable result (None: none), the
    exceptions that mean a failed solve, and ``check``, ``solve`` and ``retries``."""

    @property
    def name(self) -> str: ...

    @property
    def decompose_default(self) -> bool: ...

    @property
    def cover(self) -> str | None: ...

    @property
    def fallback(self) -> str | None: ...

    @property
    def errors(self) -> tuple[type[BaseException], ...]: ...

    def check(self, arg: str | None) -> None: ...

    def solve(self, Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, config: SolverConfig) -> SDPResult: ...

    def retries(self, config: SolverConfig, decomposed: bool, N: int) -> Retries: ...
