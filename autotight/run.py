"""Solve one instance end to end: SDP with a constraint set, local solves, tightness, errors."""

from __future__ import annotations

from .threads import single_blas_thread
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import sdp
from .errors import AutotightError
from .model import Constraint, Model
from .problem import Instance, LocalResult, Problem
from .sdp.result import SDPResult, SolverOptions
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


#: largest clique that small neighbouring cliques are merged into for Clarabel (see ``chordal.merge_small``)
MERGE_MAX_SIZE = 20
#: merging caps tried for our IPM, whose cost per block grows more slowly with the block size
IPM_MERGE_CAPS = (16, 20, 24, 28, 32, 40, 48)


class CliqueCovers:
    """Candidate clique covers of a model's SDP (h in every clique) and the choice per solver.

    Candidates: the min-fill chordal cover of Q and the constraints (``chordal.entry_cliques``),
    the min-fill cover of the graph of variable blocks (``chordal.block_cliques``), each with small
    neighbours merged, and the model's own block cliques when it declares them.  For Clarabel both
    covers merged up to ``MERGE_MAX_SIZE`` columns and the model's are compared by the
    interior-point cost estimate Σ_k svec(|C_k|)³ (Clarabel's dense KKT blocks); for the IPM every
    cap in ``IPM_MERGE_CAPS`` (and the unmerged block cover) is a candidate, compared by
    ``schur_ipm.iteration_cost``.  The block cover keeps blocks whole, so its separators are unions
    of blocks: on continuous time (ϖ kept) {h, ξ_{k+1,k}, ϖ_{k+1}} rather than a whole pose.
    """

    def __init__(self, model: Model, constraints: Sequence[Constraint]):
        from .sdp.chordal import block_cliques, entry_cliques, merged_covers, nonzeros, support_matrix

        V = model.variables
        owner, rows, cols = nonzeros([model.Q] + [c.A for c in constraints])  # one pass over the data
        caps = tuple(sorted({MERGE_MAX_SIZE, *IPM_MERGE_CAPS}))
        #: {cap: cover} for each base cover (cap 0: unmerged), on one clique tree per base
        self.columns = merged_covers(entry_cliques(V.N, rows, cols, always=V.index(["h"])), caps)
        self.blocks = merged_covers(block_cliques([V.sizes[n] for n in V.names], rows, cols), (0,) + caps)
        self.own = [model.clique_indices()] if model.cliques else []
        con = owner > 0  # (N × m) the columns of each constraint (owner 0 is Q)
        self.support = support_matrix(rows[con], cols[con], owner[con] - 1, V.N, len(constraints))

    def choose(self, solver: str = "clarabel") -> list[np.ndarray]:
        from .sdp.chordal import block_loads
        from .sdp.schur_ipm import iteration_cost
        from .svec import svec_dim

        if solver != "ipm":
            covers = [self.columns[MERGE_MAX_SIZE], self.blocks[MERGE_MAX_SIZE]] + self.own
            return min(covers, key=lambda cl: sum(float(svec_dim(len(c))) ** 3 for c in cl))
        candidates = [self.columns[c] for c in IPM_MERGE_CAPS] + [self.blocks[c] for c in (0,) + IPM_MERGE_CAPS]
        unique: dict[tuple, list[np.ndarray]] = {}  # equal covers (caps that merge nothing more) once
        for cl in candidates:
            unique.setdefault(tuple(tuple(c.tolist()) for c in cl), cl)
        return min(list(unique.values()) + self.own,
                   key=lambda cl: iteration_cost([len(c) for c in cl], block_loads(cl, self.support)))


def cliques_for(model: Model, constraints: Sequence[Constraint], solver: str = "clarabel") -> list[np.ndarray]:
    """Column cliques for the decomposed SDP solved by ``solver`` (see ``CliqueCovers``)."""
    return CliqueCovers(model, constraints).choose(solver)


def solve_sdp(model: Model, constraints: Sequence[Constraint], *, solver: str = "clarabel",
              decompose: bool | None = None, options: SolverOptions | None = None) -> SDPResult:
    """The Shor SDP of ``model`` with ``constraints``.

    decompose: True → our own clique decomposition (``cliques_for``, solved by
    ``sdp.clarabel_direct.solve_cliques``); otherwise Clarabel with
    ``options`` (by default its chordal decomposition with parent-child merging, see SolverOptions).
    solver "ipm" (our interior-point method, ``sdp.schur_ipm``) always runs on ``cliques_for``
    unless ``decompose`` is False; when its result is unusable, Clarabel solves again on the
    cover chosen for Clarabel.
    """
    cliques = fallback = None
    if (solver == "ipm" and decompose is not False) or (solver == "clarabel" and decompose):
        covers = CliqueCovers(model, constraints)
        cliques = covers.choose(solver)
        if solver == "ipm":
            fallback = covers.choose("clarabel")
        if solver == "clarabel" and len(cliques) == 1:
            cliques = None  # one cone: Clarabel's dense path
    return sdp.solve(model.Q, constraints, d=model.d, solver=solver, cliques=cliques, options=options,
                     fallback_cliques=fallback)


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
            "rank_tight": self.verdict.rank_tight, "cost_tight": self.verdict.cost_tight,
            "verdict": self.verdict.reason,
            "log_svr": self.sdp.log_svr, "sdp_cost": self.sdp.primal_cost, "sdp_dual_cost": self.sdp.dual_cost,
            "local_cost": lt.cost, "local_cost_random": [r.cost for r in self.local.from_random],
            "best_local_cost": self.local.best.cost, "rel_gap": self.verdict.rel_gap,
            "solve_time_s": self.sdp.solve_time_s, "errors_sdp": self.errors_sdp, "errors_local": self.errors_local,
            "times": self.times,
        }


@single_blas_thread
def solve_instance(problem: Problem, inst: Instance, *, set_name: str | None = None,
                   extra: Sequence[Constraint] | None = None, solver: str = "clarabel",
                   options: SolverOptions | None = None, criteria: Criteria = Criteria(),
                   rng: np.random.Generator | None = None, n_random: int = 1,
                   decompose: bool | None = None) -> SolveOutcome:
    t0 = time.perf_counter()
    model = problem.build(inst)
    name = set_name or default_set(model)
    cons = constraint_set(model, name, extra)
    t1 = time.perf_counter()
    res = solve_sdp(model, cons, solver=solver, decompose=decompose, options=options)
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
