"""What an SDP backend provides (``Backend``), as ``registry.BACKENDS`` holds it."""

from __future__ import annotations

from typing import Callable, Protocol, Sequence

import numpy as np
import scipy.sparse as sp

from .config import Retries, SolverConfig
from .result import SDPResult

#: a caller's test of a solve's multipliers y (m,) (those of the constraints as given, unscaled): True ends an
#: iterative solve at the iterate they came from (``Backend.solve``'s ``stop``)
StopRule = Callable[[np.ndarray], bool]
#: a caller's test of a result (as the backend returned it: in the frame solved, with that frame's Q, Aᵢ (COO) and
#: b): True when the verdict the caller draws from it cannot change, so a retry (of a usable result) or the
#: fallback's solve (of a best iterate) is not needed (``autotight.sdp.solve``'s ``settled``)
SettledRule = Callable[[SDPResult, sp.csr_array, Sequence[sp.coo_array], np.ndarray], bool]


class EarlySettle(Protocol):
    """A ``SettledRule`` that an iterative backend with ``stops_early`` also asks of its iterates during the solve
    (``Backend.solve``'s ``settled``).  ``may_settle(P, D, scale)``, a cheap necessary condition on an iterate's
    primal and dual costs (those of the problem as given to the backend) and scale = max|Q_ij|·tr X, is asked first;
    only an iterate that meets it and is within reduced accuracy of feasibility (our IPM: pinf, dinf ≤ Clarabel's
    reduced tolerance) is completed into a result and tested by the rule.  True ends the solve at that iterate, which
    it returns marked ``settled``."""

    def __call__(self, res: SDPResult, Q: sp.csr_array, As: Sequence[sp.coo_array], b: np.ndarray) -> bool: ...

    def may_settle(self, primal: float, dual: float, scale: float) -> bool: ...


class Backend(Protocol):
    """What a solver backend provides: its name, whether solves decompose by default, the clique-cover
    policy it takes (None: none), the backend that re-solves an unusable result (None: none), the
    exceptions that mean a failed solve, and ``check``, ``solve`` and ``retries``.

    A backend that can end a solve early on the caller's word sets the optional attribute ``stops_early = True``;
    its ``solve`` then also takes ``stop`` (a ``StopRule``, or None): it asks the rule with the multipliers of its
    best iterate once that iterate is within reduced accuracy and progress has stalled (our IPM: two iterations
    without a better one), and returns that iterate when the rule says True; and ``settled`` (an ``EarlySettle``, or
    None), asked of its iterates as that protocol says.  The SDP layer passes ``stop`` and ``settled`` to those
    only, ``settled`` only when the caller's rule is an ``EarlySettle`` that asks for it."""

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
