"""Tightness of an instance's SDP with the primary constraints plus a chosen set of pairs.

The oracle counts its solves: ``n_solves`` counts solver calls (``SDPResult.n_calls`` when the SDP
layer reports retries and fallbacks, else 1 per solve) and ``solve_time_s`` their time; every solve's
status is kept (a failed solve is "not tight", with its status in ``log``).  What counts as tight is
``criteria.accept`` (``accepted``): "rank" (rank d and cost), "cost" (the cost bracket only) or
"certified" (cost with a certificate; until the verdict's certificate exists, the same as "cost").
Clarabel has no warm start: each solve starts cold.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..model import Constraint, Model
from ..run import solve_sdp
from ..sdp.result import SDPResult, SolverOptions
from ..tightness import Criteria, Verdict, judge
from ..unbounded import is_unbounded
from .catalog import Pair

ACCEPT = ("rank", "cost", "certified")


def accepted(v: Verdict, accept: str = "rank") -> bool:
    """Whether a verdict counts as tight under ``accept``: "rank" → v.tight (rank and cost);
    "cost" and "certified" → v.cost_tight (the bracket [SDP cost, best local cost] within tolerance)."""
    if accept not in ACCEPT:
        raise ValueError(f"unknown acceptance {accept!r}; use one of {', '.join(ACCEPT)}")
    return bool(v.tight) if accept == "rank" else bool(v.cost_tight)


@dataclass
class Oracle:
    model: Model
    pairs: dict[Pair, list[Constraint]]
    best_local: float
    criteria: Criteria = Criteria()
    options: SolverOptions = SolverOptions()
    solver: str = "clarabel"
    n_solves: int = 0
    solve_time_s: float = 0.0
    log: list[dict] = field(default_factory=list)

    @property
    def accept(self) -> str:
        return getattr(self.criteria, "accept", "rank")

    def ok(self, v: Verdict) -> bool:
        """Tight under the oracle's acceptance (``accepted``)."""
        return accepted(v, self.accept)

    def constraints(self, chosen: Iterable[Pair]) -> list[Constraint]:
        return self.model.primary() + [c for p in chosen for c in self.pairs[p]]

    def solve(self, chosen: Iterable[Pair], stage: str = "") -> tuple[Verdict, SDPResult]:
        """Primary constraints plus the chosen pairs."""
        chosen = list(chosen)
        return self._solve(self.constraints(chosen), stage, len(chosen))

    def solve_extra(self, extra: list[Constraint], stage: str = "") -> tuple[Verdict, SDPResult]:
        """Primary constraints plus arbitrary extra constraints (e.g. the paper's)."""
        return self._solve(self.model.primary() + list(extra), stage, 0)

    def _solve(self, cons: list[Constraint], stage: str, n_pairs: int) -> tuple[Verdict, SDPResult]:
        res = solve_sdp(self.model, cons, solver=self.solver, options=self.options)
        calls = int(getattr(res, "n_calls", 1) or 1)
        self.n_solves += calls
        self.solve_time_s += res.solve_time_s + res.setup_time_s
        v = judge(res, self.best_local, self.criteria)
        self.log.append({"stage": stage, "n_pairs": n_pairs, "status": res.status, "log_svr": res.log_svr,
                         "rel_gap": v.rel_gap, "tight": self.ok(v), "calls": calls,
                         "unbounded": is_unbounded(res)})
        return v, res

    def violation(self, X: np.ndarray, pair: Pair) -> float:
        """max over the pair's constraints of |⟨A,X⟩| / (‖A‖_F ‖X‖_F): 0 at every rank-1 feasible X."""
        nx = np.linalg.norm(X)
        return max(abs(c.value(X)) / (np.sqrt((c.A.multiply(c.A)).sum()) * nx) for c in self.pairs[pair])

    def importance(self, res: SDPResult, chosen: list[Pair]) -> dict[Pair, float]:
        """Σ |yᵢ|·‖Aᵢ‖_F over a pair's constraints, from the multipliers of a solve with ``chosen``."""
        out = {p: 0.0 for p in chosen}
        if res.y is None:
            return out
        k = len(self.model.primary())
        for p in chosen:
            for c in self.pairs[p]:
                out[p] += abs(res.y[k]) * float(np.sqrt((c.A.multiply(c.A)).sum()))
                k += 1
        return out
