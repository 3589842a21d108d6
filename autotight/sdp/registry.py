"""The SDP backends by name: ``SolverConfig.backend`` "NAME" or "NAME:ARG" selects ``BACKENDS[NAME]``.

A backend is a small object with these attributes and methods (see ``Backend``):
``name``; ``decompose_default`` (what ``SolverConfig.decompose = None`` means); ``cover`` (the cover
policy of ``covers.CliqueCovers.choose``, or None when it takes no cover); ``fallback`` (the backend
that solves again when a result is unusable, or None); ``retries(config, decomposed, N)`` (the
configs to try, in order, each as (what, config, statuses): tried when the result so far has one
of those statuses);
``errors`` (exceptions the solver legitimately raises, turned into a "Failed" status; anything else
propagates); ``check(arg)`` (SolverConfigError when it is unusable, e.g. not installed);
``solve(Q, As, b, d, cliques, config) -> SDPResult``.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np
import scipy.sparse as sp

from .clarabel_direct import ClarabelBackend
from .config import Retries, SolverConfig
from .cvxpy_path import CvxpyBackend
from .result import SDPResult
from .schur_ipm import IPMBackend


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


#: name → backend; adding a backend is one module and one line here
BACKENDS: dict[str, Backend] = {
    "clarabel": ClarabelBackend(),
    "ipm": IPMBackend(),
    "cvxpy": CvxpyBackend(),
}
