"""Each SDP backend's own settings, as frozen option objects that ``SolverConfig`` carries (``clarabel``,
``ipm``): validated when built (``SolverConfigError``, one line naming the field and its allowed values).
The backends read them from the config they are given; the cvxpy path has none.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import SolverConfigError

#: ``ClarabelOptions.regularization``'s values
REGULARIZATIONS = ("small", "default")
#: ``ClarabelOptions.merge``'s values (Clarabel's ``chordal_decomposition_merge_method``)
CHORDAL_MERGES = ("parent_child", "clique_graph", "none")


@dataclass(frozen=True)
class ClarabelOptions:
    """The Clarabel backend's own settings (``SolverConfig.clarabel``); SolverConfigError when one is
    not a value it knows.

    chordal: let Clarabel decompose the PSD cone along the chordal sparsity of the data (when
        ``SolverConfig.decompose`` is off), merging cliques by ``merge``.  On by default: 4× faster
        on rotation averaging, 30× on pose averaging than one dense cone.  Off: one dense cone.
    merge: "parent_child" (default; Clarabel's own default "clique_graph" took > 120 s on the
        discrete trajectory at K = 10, where "parent_child" takes 1 s), "clique_graph" or "none".
        A parent-child solve that stalls on a small lifting is retried with "clique_graph"
        (``ClarabelBackend.retries``).
    regularization: "small" (static 1e-10, no dynamic regularisation) solves tight, rank-deficient
        relaxations to full accuracy; "default" (Clarabel's: static 1e-8, dynamic on) is more
        robust, and a solve that stalls with "small" is retried with it.
    """

    chordal: bool = True
    merge: str = "parent_child"
    regularization: str = "small"

    def __post_init__(self) -> None:
        if not isinstance(self.chordal, bool):
            raise SolverConfigError(f"ClarabelOptions.chordal must be True or False, got {self.chordal!r}")
        for field, allowed in (("merge", CHORDAL_MERGES), ("regularization", REGULARIZATIONS)):
            value = getattr(self, field)
            if value not in allowed:
                raise SolverConfigError(f"unknown ClarabelOptions.{field} {value!r}; use "
                                        + ", ".join(map(repr, allowed[:-1])) + f" or {allowed[-1]!r}")



#: the search directions of ``solve_blocks`` (``IpmOptions.search``): Nesterov–Todd and HKM
SEARCH_DIRECTIONS = ("nt", "hkm")


@dataclass(frozen=True)
class IpmOptions:
    """Our IPM's own settings (``SolverConfig.ipm``); SolverConfigError when one is not a value it knows.

    search: the search direction, "nt" (Nesterov–Todd, default) or "hkm" (see the module docstring).
    step_fraction: each step goes this fraction (in (0, 1)) of the way to the cone's boundary; None
        (default): SDPT3's rule, 0.9 and then 0.9 + 0.09·min(α_p, α_d) after steps of lengths α_p, α_d.
    threads: threads for the per-block work of large programs (``block_threads``), 1 or 2; None (default):
        2 where the process may use two CPUs.  The iterates are the same to the bit for every value.
    """

    search: str = "nt"
    step_fraction: float | None = None
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.search not in SEARCH_DIRECTIONS:
            raise SolverConfigError(f"unknown IpmOptions.search {self.search!r}; use "
                                    + " or ".join(map(repr, SEARCH_DIRECTIONS)))
        f = self.step_fraction
        if f is not None and (isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f < 1):
            raise SolverConfigError(f"IpmOptions.step_fraction must be None or a number in (0, 1), got {f!r}")
        t = self.threads
        if t is not None and (isinstance(t, bool) or t not in (1, 2)):
            raise SolverConfigError(f"IpmOptions.threads must be None, 1 or 2, got {t!r}")
