"""Solve one instance end to end: SDP with a constraint set, local solves, tightness, errors."""

from __future__ import annotations

from .threads import single_blas_thread
import time
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from . import sdp
from .errors import AutotightError
from .model import Constraint, Model
from .problem import Instance, LocalResult, Problem
from .sdp.config import SolverConfig
from .sdp.result import SDPResult
from .tightness import Criteria, Verdict, judge


def constraint_set(model: Model, name: str, extra: Sequence[Constraint] | None = None) -> list[Constraint]:
    """'primary' → homogenisation + primary; 'paper' → also the paper's families; 'discovered' → primary + extra."""
    if name == "primary":
        return model.primary()
    if name == "paper":
        return model.primary() + model.paper_constraints()
    if name == "discovered":
        if extra is None:
            raise AutotightError("the 'discovered' set needs discovered constraints (run discovery or load its JSON)")
        return model.primary() + list(extra)
    raise AutotightError(f"unknown constraint set {name!r}; use primary, paper or discovered")


def default_set(model: Model) -> str:
    return "paper" if model.paper else "primary"


@dataclass
class LocalSearch:
    """Local solves from the ground truth and from random starts; ``best`` is the lowest cost."""

    from_truth: LocalResult
    from_random: list[LocalResult]

    @property
    def best(self) -> LocalResult:
        return min([self.from_truth, *self.from_random], key=lambda r: r.cost)


def local_search(problem: Problem, inst: Instance, rng: np.random.Generator, n_random: int = 1) -> LocalSearch:
    truth = problem.local_solve(inst, inst.truth)
    rand = [problem.local_solve(inst, problem.random_state(inst, rng)) for _ in range(n_random)]
    return LocalSearch(truth, rand)


def solve_sdp(model: Model, constraints: Sequence[Constraint], config: SolverConfig = SolverConfig(),
              scale: np.ndarray | None = None) -> SDPResult:
    """Deprecated: ``sdp.solve_model``."""
    return sdp.solve_model(model, constraints, config, scale)


@dataclass
class SolveOutcome:
    """Everything ``autotight solve`` reports for one instance and one constraint set."""

    instance: Instance
    set_name: str
    n_constraints: int
    sdp: SDPResult
    local: LocalSearch
    verdict: Verdict
    estimate: dict[str, np.ndarray] | None
    errors_sdp: dict[str, float]
    errors_local: dict[str, float]
    times: dict[str, float] = field(default_factory=dict)

    def record(self, problem: Problem) -> dict[str, Any]:
        lt = self.local.from_truth
        return {
            "problem": problem.name, "params": self.instance.params, "seed": self.instance.seed,
            "constraint_set": self.set_name, "n_constraints": self.n_constraints,
            "solver": self.sdp.solver, "status": self.sdp.status, "tight": self.verdict.tight,
            "rank_tight": self.verdict.rank_tight, "cost_tight": self.verdict.cost_tight, "verdict": self.verdict.reason,
            "log_svr": self.sdp.log_svr, "sdp_cost": self.sdp.primal_cost, "sdp_dual_cost": self.sdp.dual_cost,
            "local_cost": lt.cost, "local_cost_random": [r.cost for r in self.local.from_random],
            "best_local_cost": self.local.best.cost, "rel_gap": self.verdict.rel_gap,
            "solve_time_s": self.sdp.solve_time_s, "errors_sdp": self.errors_sdp, "errors_local": self.errors_local,
            "times": self.times,
        }


@single_blas_thread
def solve_instance(problem: Problem, inst: Instance, *, set_name: str | None = None,
                   extra: Sequence[Constraint] | None = None, solver: str = "clarabel",
                   options: SolverConfig | None = None, criteria: Criteria = Criteria(),
                   rng: np.random.Generator | None = None, n_random: int = 1,
                   decompose: bool | None = None) -> SolveOutcome:
    t0 = time.perf_counter()
    model = problem.build(inst)
    name = set_name or default_set(model)
    cons = constraint_set(model, name, extra)
    t1 = time.perf_counter()
    config = replace(options or SolverConfig(), backend=solver, decompose=decompose)
    res = sdp.solve_model(model, cons, config)
    t2 = time.perf_counter()
    rng = rng or np.random.default_rng(0 if inst.seed is None else inst.seed + 1)
    loc = local_search(problem, inst, rng, n_random)
    t3 = time.perf_counter()
    verdict = judge(res, loc.best.cost, criteria)
    estimate, err_sdp = None, {}
    if res.Theta is not None and res.usable:
        try:
            estimate = problem.recover(inst, res.Theta)
            err_sdp = problem.errors(inst, estimate)
        except (ValueError, np.linalg.LinAlgError) as e:  # a useless X is reported, not raised
            verdict.reason += f"; recovery failed: {e}"
    times = {"build_s": t1 - t0, "sdp_total_s": t2 - t1, "sdp_solve_s": res.solve_time_s,
             "local_s": t3 - t2, "local_truth_s": loc.from_truth.time_s}
    return SolveOutcome(inst, name, len(cons), res, loc, verdict, estimate, err_sdp,
                        problem.errors(inst, loc.from_truth.state), times)
