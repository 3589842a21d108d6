"""Held-out validation of a discovered set: fresh instances per point, solved in parallel.

Each held-out instance is independent: generated from its seed, solved with every set through
``autotight.pipeline.solve_instance`` (a learned set is instantiated on it first; failing to is a
failure of the instance, as in ``check``).  The instances run where ``report``'s trials run
(``autotight.parallel.execute``: in process, joblib processes with ``jobs`` > 1, or a Dask
cluster at ``scheduler``), and the results are put back in instance order, so the outcome does not
depend on where they ran.  Counting is ``check``'s (``autotight.check.PointResult``): undecided instances
are left out of the fraction, and a point passes when tight / (instances − undecided) ≥ min_fraction.

With ``shortcut`` an instance whose local solution's certificate proves the set tight
(``shortcut.certified_tight``: cost and rank, by exact tests) is counted tight without the full SDP;
every other instance is solved as above, so an instance that fails is always one the full SDP judged.
The set's constraints are checked on the instance's feasible points (``validity.check_valid``) either way.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..check import PointResult
from ..constraint_set import ConstraintSet, ConstraintsLike
from ..errors import AutotightError, ParameterError
from .. import sdp
from ..constraint_set import resolve
from ..pipeline import LocalSearch, feasible_points, local_search, seeds, solve_instance
from ..validate import check_instance
from ..validity import check_valid
from .shortcut import Shortcut, certified_tight
from ..problem import Problem, load, registered_name
from ..sdp.config import SolverConfig
from ..tightness import Criteria


def problem_ref(prob: Problem, local: bool) -> Problem | str:
    """How a worker loads ``prob``: the object itself in this process (``local``), else its name when an entry point
    registers it, else the absolute path of its module file."""
    if local:
        return prob
    name = registered_name(prob)
    if name is not None:
        return name
    if prob.path is None:
        raise ParameterError(f"problem {prob.name!r} has no module file: it cannot run in worker processes "
                             "(use jobs=1)")
    return str(Path(prob.path).resolve())


def solve_one(ref: Problem | str, params: dict[str, Any], seed: int, sets: Mapping[str, ConstraintsLike],
              criteria: Criteria, config: SolverConfig, n_random: int,
              shortcut: bool = False) -> dict[str, dict[str, Any]]:
    """One held-out instance solved with every set: {set name: outcome, log SVR, reason, …} (``shortcut``: the
    module docstring; such a row has status "certified", log SVR NaN and no solver call)."""
    prob = load(ref)
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    loc = local_search(prob, inst, seeds(seed).local(), n_random)
    out: dict[str, dict[str, Any]] = {}
    for name, cons in sets.items():
        given: Any = cons
        if isinstance(cons, ConstraintSet):
            try:
                given = cons.apply(prob, inst, model, seeds(seed).constraints())
            except AutotightError as e:
                out[name] = {"outcome": "not tight", "log_svr": float("nan"), "n_constraints": 0,
                             "reason": f"cannot instantiate the set: {e}", "status": "not instantiated",
                             "rel_gap": float("nan"), "calls": 0}
                continue
        if shortcut:
            proved = _certified(prob, inst, model, given, loc, criteria, config)
            if proved is not None:
                out[name] = {"outcome": "tight", "log_svr": float("nan"), "n_constraints": proved[0],
                             "reason": proved[1].reason(), "status": "certified",
                             "rel_gap": proved[1].rel_bound, "calls": 0}
                continue
        r = solve_instance(prob, inst, given, config=config, criteria=criteria, model=model, local=loc,
                           raise_unbounded=False)
        out[name] = {"outcome": r.outcome, "log_svr": float(r.log_svr), "n_constraints": r.n_constraints,
                     "reason": r.verdict.reason, "status": r.sdp.status, "rel_gap": float(r.verdict.rel_gap),
                     "calls": max(1, len(r.attempts))}
    return out


def _certified(prob: Problem, inst: Any, model: Any, given: ConstraintsLike, loc: LocalSearch, criteria: Criteria,
               config: SolverConfig) -> tuple[int, Shortcut] | None:
    """(number of constraints, the proof) when the certificate of ``loc``'s best solution proves ``given`` tight
    on ``inst``; the checks of ``solve_instance`` (data, costs, every constraint on the feasible points) first."""
    s = seeds(inst.seed if inst.seed is not None else 0)
    cons = resolve(given, prob, inst, model, s.constraints())
    check_instance(prob, inst, model, loc)
    check_valid(prob.name, cons, feasible_points(prob, inst, loc, s.validity()))
    gap = sdp.effective_tol(config.for_size(model.variables.N))
    proof = certified_tight(model, cons, prob.lift(inst, loc.best.state), criteria, gap=gap)
    return None if proof is None else (len(cons), proof)


def _indexed(key: tuple[int, int], ref: Any, params: dict[str, Any], seed: int, sets: Any, criteria: Criteria,
             config: SolverConfig, n_random: int, shortcut: bool) -> tuple[tuple[int, int], dict[str, dict[str, Any]]]:
    return key, solve_one(ref, params, seed, sets, criteria, config, n_random, shortcut)


def solve_batch(prob: Problem, sets: Mapping[str, ConstraintsLike], points: Sequence[tuple[dict, dict]],
                batch: Sequence[Sequence[int]], *, min_fraction: float, criteria: Criteria, config: SolverConfig,
                n_random: int = 1, jobs: int = 1, scheduler: Any = None,
                shortcut: bool = False) -> tuple[dict[str, list[PointResult]], dict[str, int]]:
    """Solve the seeds ``batch[i]`` at point i with every set (``shortcut``: the module docstring); the sets of
    one instance share its generation, model and local search.  Returns {set name: [PointResult per point]}
    (instances in seed order) and {set name: SDP solver calls}."""
    from ..parallel import execute

    local = jobs == 1 and scheduler is None
    ref = problem_ref(prob, local)
    calls = [((i, t), ref, points[i][0], s, dict(sets), criteria, config, n_random, shortcut)
             for i, seeds_ in enumerate(batch) for t, s in enumerate(seeds_)]
    done = dict(execute(_indexed, calls, jobs=jobs, scheduler=scheduler))
    out = {name: [PointResult(full, varied, min_fraction) for full, varied in points] for name in sets}
    n = {name: 0 for name in sets}
    for key, _, _, s, *_ in calls:
        for name, row in done[key].items():
            pr = out[name][key[0]]
            pr.seeds.append(int(s)); pr.outcomes.append(row["outcome"]); pr.log_svr.append(row["log_svr"])
            pr.reasons.append(row["reason"]); pr.n_constraints.append(row["n_constraints"])
            pr.statuses.append(row["status"]); pr.rel_gap.append(row["rel_gap"])
            pr.set_label = name
            n[name] += row["calls"]
    return out, n
