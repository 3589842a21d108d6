"""``SolverConfig``: how the SDP layer solves one Shor relaxation (backend, accuracy, limits, scaling, and
each backend's own options).

A config is passed explicitly to every solve and never stored module-wide.  It is validated when it
is built: an unknown backend, an out-of-range field or a cvxpy solver that is not installed raises
``SolverConfigError`` (an ``AutotightError``: a one-line input error) before any work is done.
The backend-neutral fields sit on ``SolverConfig``; what only one backend reads is that backend's
option object, defined in the backend's module and validated when it is built:
``SolverConfig.clarabel`` (``options.ClarabelOptions``) and ``SolverConfig.ipm``
(``options.IpmOptions``).  The cvxpy path has none: it reads only the backend-neutral fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from ..errors import SolverConfigError
from .options import ClarabelOptions, IpmOptions
from .registry import BACKENDS

#: above this many columns an unusable result is not solved again, neither by a backend's retry nor by its
#: fallback: a retry costs as much as the long solve it repeats, and Clarabel's memory on the chordal cover
#: grows faster than the data (discrete trajectory with the set learned at K = 5: K = 4000, N = 96 000, passed
#: 21 GB before its first iteration, where the IPM had held 1.6 GB at K = 2000)
FALLBACK_MAX_N = 20_000

__all__ = ["SolverConfig", "SolverConfigError", "ClarabelOptions", "IpmOptions", "AUTO", "AUTO_IPM_MIN_N",
           "SCALES", "Retries"]

SCALES = ("auto", "none")
#: the backend name that lets the SDP layer choose (``SolverConfig.for_size``)
AUTO = "auto"
#: from this many columns of X on, "auto" solves with our IPM on a clique cover, below with Clarabel.  Measured
#: (benchmarks/README.md, "Backend by size"): discrete trajectory K = 100 (N = 2395), IPM 3.4 s against
#: Clarabel's chordal path 80–150 s; every instance of the regression set (rotation averaging, pose
#: averaging M = 10, discrete K = 20, continuous K = 21: N ≤ 517) stays with Clarabel
AUTO_IPM_MIN_N = 1000


@dataclass(frozen=True)
class SolverConfig:
    """How to solve min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

    backend: "auto" (default: the SDP layer picks by the problem's size, ``for_size``: our IPM from
        ``AUTO_IPM_MIN_N`` columns on, else Clarabel), "clarabel" (Clarabel called directly with sparse
        data), "ipm" (our Schur-complement interior-point method on clique blocks, ``schur_ipm``) or
        "cvxpy:<NAME>" (any solver cvxpy has installed: "cvxpy:SCS", "cvxpy:MOSEK", …).  See ``sdp.registry``.
    decompose: solve on a clique cover chosen by the SDP layer (``sdp.covers``): True, False, or
        None for the backend's default (clarabel: False, i.e. Clarabel's own chordal decomposition,
        see ``ClarabelOptions.chordal``; ipm: True; cvxpy: no decomposition at all).
    tol: the backend's relative gap and feasibility tolerance (the IPM stops at no less than
        ``schur_ipm.IPM_MIN_TOL``).
    max_iter: iteration limit per solver call.  time_limit: seconds per solver call (inf: none).
    threads: solver threads (0: the solver's default).  verbose: the solver's own log.
    scale: "auto" applies the diagonal congruence X = D X' D when ``solve`` is given a vector D;
        "none" ignores any vector (see ``sdp.scaling``).

    clarabel: the Clarabel backend's options (``ClarabelOptions``: its chordal decomposition, clique
        merging and regularisation, and the retries they imply); read by every solve that reaches
        Clarabel, also the IPM's fallback and "auto" below ``AUTO_IPM_MIN_N``.
    ipm: our IPM's options (``IpmOptions``: its search direction).
    """

    backend: str = AUTO
    decompose: bool | None = None
    tol: float = 1e-9
    max_iter: int = 500
    time_limit: float = float("inf")
    threads: int = 1
    verbose: bool = False
    scale: str = "auto"
    clarabel: ClarabelOptions = ClarabelOptions()
    ipm: IpmOptions = IpmOptions()

    def __post_init__(self) -> None:
        if not isinstance(self.backend, str):
            raise SolverConfigError(f"backend must be a string, got {self.backend!r}")
        if self.decompose not in (None, True, False):
            raise SolverConfigError(f"decompose must be True, False or None, got {self.decompose!r}")
        if not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
            raise SolverConfigError(f"tol must be in (0, 1), got {self.tol!r}")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise SolverConfigError(f"max_iter must be an integer ≥ 1, got {self.max_iter!r}")
        if not (isinstance(self.time_limit, (int, float)) and self.time_limit > 0 and not math.isnan(self.time_limit)):
            raise SolverConfigError(f"time_limit must be > 0 seconds (inf: none), got {self.time_limit!r}")
        if not (isinstance(self.threads, int) and self.threads >= 0):
            raise SolverConfigError(f"threads must be an integer ≥ 0 (0: the solver's default), got {self.threads!r}")
        if self.scale not in SCALES:
            raise SolverConfigError(f"unknown scale {self.scale!r}; use " + " or ".join(map(repr, SCALES)))
        for field, kind in (("clarabel", ClarabelOptions), ("ipm", IpmOptions)):
            if not isinstance(getattr(self, field), kind):
                raise SolverConfigError(f"{field} must be a {kind.__name__}, got {getattr(self, field)!r}")
        self.check()

    @property
    def backend_name(self) -> str:
        """The registry key: "cvxpy" for "cvxpy:SCS"."""
        return self.backend.split(":", 1)[0]

    @property
    def backend_arg(self) -> str | None:
        """What follows the colon ("SCS" for "cvxpy:SCS"), or None."""
        return self.backend.split(":", 1)[1] if ":" in self.backend else None

    def check(self) -> "SolverConfig":
        """Raise SolverConfigError unless the backend is registered and its solver installed;
        returns self.  Called on construction."""
        if self.backend_name == AUTO:
            if self.backend_arg is not None:
                raise SolverConfigError(f"backend 'auto' takes no argument, got {self.backend!r}")
            return self
        backend = BACKENDS.get(self.backend_name)
        if backend is None:
            raise SolverConfigError(f"unknown solver {self.backend!r}; use "
                                    + ", ".join(repr(n) for n in BACKENDS if n != "cvxpy")
                                    + " or 'cvxpy:<NAME>' ('cvxpy:SCS', 'cvxpy:MOSEK', …)")
        backend.check(self.backend_arg)
        return self

    def for_size(self, N: int) -> "SolverConfig":
        """The config with "auto" resolved for an SDP of N columns: "ipm" when N ≥ ``AUTO_IPM_MIN_N``, else
        "clarabel"; any other backend unchanged."""
        if self.backend != AUTO:
            return self
        return replace(self, backend="ipm" if N >= AUTO_IPM_MIN_N else "clarabel")


#: the old name of SolverConfig (deprecated; the same class, so every old field still works)
SolverOptions = SolverConfig


#: a backend's retry plan: (why, the config to retry with, the statuses that trigger it)
Retries = list[tuple[str, SolverConfig, tuple[str, ...]]]
