"""Tightness of an instance's SDP with the primary constraints plus a chosen set of pairs.

The oracle counts its solves: ``n_solves`` counts solver calls (``SDPResult.n_calls`` when the SDP
layer reports retries and re-solves, else 1 per solve) and ``solve_time_s`` their time; every solve's
status is kept (a failed solve is "not tight", with its status in ``log``).  What counts as tight is
``criteria.accept`` (applied by ``tightness.judge``): "rank" (rank d and cost), "cost" (the cost
bracket, with the dual certificate of the best local solution from the solve's y: as in the
per-instance pipeline, a certificate decides a bracket the solver's accuracy leaves undecided) or
"certified" (the certificate alone).
Clarabel has no warm start: each solve starts cold.  As in the per-instance pipeline
(``autotight.pipeline.solve_instance``), each solve runs in X = D X' D with D from the lifted best local
solution (``sdp.scaling.block_scale``) when ``scaled`` and the configuration allows it, and falls back
to the plain data when the scaled solve is unusable; both calls are counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from .. import sdp
from ..model import Constraint, Model, frobenius
from ..sdp.config import SolverConfig
from ..sdp.result import SDPResult
from ..sdp.scaling import block_scale
from ..dual_polish import polished
from ..tightness import Criteria, Verdict, judge
from ..unbounded import is_unbounded
from .catalog import Pair

@dataclass
class Oracle:
    model: Model
    pairs: dict[Pair, list[Constraint]]
    best_local: float
    criteria: Criteria = Criteria()
    options: SolverConfig = SolverConfig()
    n_solves: int = 0
    solve_time_s: float = 0.0
    log: list[dict] = field(default_factory=list)
    best_theta: np.ndarray | None = None  # the lifted best local solution (certificates, accept="certified")
    scaled: bool = False  # solve in X = D X' D, D from best_theta (see the module docstring)

    @property
    def accept(self) -> str:
        return self.criteria.accept

    def ok(self, v: Verdict) -> bool:
        """Tight under the oracle's acceptance (``judge`` applies ``criteria.accept``)."""
        return bool(v.tight)

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
        D = None
        if self.scaled and self.best_theta is not None and self.options.scale != "none":
            D = block_scale(self.model.variables, [self.best_theta])
        res = sdp.solve_model(self.model, cons, self.options, D)
        calls = int(getattr(res, "n_calls", 1) or 1)
        self.n_solves += calls
        self.solve_time_s += res.solve_time_s + res.setup_time_s
        if D is not None and not res.usable and not is_unbounded(res):  # the scaling did not help: the plain data
            plain = sdp.solve_model(self.model, cons, self.options)
            n = int(getattr(plain, "n_calls", 1) or 1)
            self.n_solves += n
            calls += n
            self.solve_time_s += plain.solve_time_s + plain.setup_time_s
            if plain.usable:
                res = plain
        cert = None
        if self.best_theta is not None:  # the better of y and its polish at x̂ (autotight.dual_polish)
            res, cert = polished(self.model.Q, cons, res, self.best_theta, d=self.model.d, tol=self.criteria.gap_tol,
                                 floor=self.criteria.cost_atol / self.criteria.gap_tol)
        v = judge(res, self.best_local, self.criteria, cert, Q=self.model.Q, constraints=cons)
        if not v.tight and cert is not None and cert.recession:  # name the blocks nothing bounds
            from ..unbounded import rank_out_of_reach

            v.reason += f"; {rank_out_of_reach(self.model, cons)}"
        self.log.append({"stage": stage, "n_pairs": n_pairs, "status": res.status, "log_svr": res.log_svr,
                         "rel_gap": v.rel_gap, "tight": self.ok(v), "calls": calls,
                         "unbounded": is_unbounded(res)})
        return v, res

    def violation(self, X: np.ndarray, pair: Pair) -> float:
        """max over the pair's constraints of |⟨A,X⟩| / (‖A‖_F ‖X‖_F): 0 at every rank-1 feasible X."""
        nx = frobenius(X)
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
