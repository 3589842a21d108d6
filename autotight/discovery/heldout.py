"""Held-out validation of a discovered set: fresh instances per point, solved in parallel.

Each held-out instance is independent: generated from its seed, solved with every set through
``autotight.evaluate`` (one model and local search shared by the sets; a learned set is instantiated on it
first, failing to is a failure of the instance, as in ``check``).  The instances run where ``report``'s trials run
(``autotight.parallel.execute``: in process, joblib processes with ``jobs`` > 1, or a Dask
cluster at ``scheduler``), and the results are put back in instance order, so the outcome does not
depend on where they ran.  Counting is ``check``'s (``autotight.check.PointResult``): undecided instances
are left out of the fraction, and a point passes when tight / (instances − undecided) ≥ min_fraction.

With ``shortcut`` an instance whose local solution's certificate proves the set tight
(``shortcut.certified_tight``: cost and rank, by exact tests) is counted tight without the full SDP;
every other instance is solved as above, so an instance that fails is always one the full SDP judged.
The set's constraints are checked on the instance's feasible points (``validity.check_valid``) either way.
An SDP solved by an iterative backend ends at the first iterate whose bracket proves the set not tight
(``pipeline.EarlyGapSettled``): the outcome a finished solve gives, at a fraction of its iterations (a failing
instance's P, log SVR and reason are then its iterate's).

With ``stop_hopeless`` (one set; True, or per point) a point's batch ends at the first instance, in seed
order, after which the point cannot pass any more whatever the rest would give (``hopeless``): its later
instances are not solved, and results that a parallel worker finished beyond that instance are dropped, so
the batch is the same prefix of seeds wherever it ran.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..check import PointResult
from ..constraint_set import ConstraintsLike
from ..errors import ParameterError
from ..evaluate import evaluate, summary
from .shortcut import certified_tight
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


#: columns of the largest held-out point from which ``auto_jobs`` runs the held-out instances in local worker
#: processes: one solve there takes seconds (discrete trajectory K = 200, N = 4795: 2-5 s), which repays a worker's
#: start (imports and compiled kernels, about 2 s once per run); below it one process is as fast or faster (pose
#: averaging M = 10: 40 held-out instances in 1.8 s)
AUTO_JOBS_MIN_N = 1000


#: seconds per held-out instance, measured on a batch run in this process, from which ``jobs_after`` moves the
#: later batches to worker processes: the SDP's columns alone do not tell the cost (continuous time K = 21, N = 517:
#: about 9 s an instance; pose averaging M = 10, N = 73: 0.05 s), and a worker's start (about 2 s, once per run) is
#: repaid within a batch of such instances
AUTO_JOBS_MIN_S = 1.0


def _workers(prob: Problem) -> int:
    """Every CPU this process may use (``parallel.usable_cpus``) when a worker can load ``prob`` (a registered
    name or a module file), else 1."""
    from ..parallel import usable_cpus

    cpus = usable_cpus()
    return 1 if cpus < 2 or (registered_name(prob) is None and prob.path is None) else cpus


def auto_jobs(prob: Problem, points: Sequence[Mapping[str, Any]]) -> int:
    """The held-out workers when the caller gave none: ``_workers`` when the largest of ``points`` (full
    parameters) has an SDP of at least ``AUTO_JOBS_MIN_N`` columns (one instance built at seed 0); else 1.
    Results do not depend on it (``solve_batch``)."""
    workers = _workers(prob)
    if workers < 2 or not points:
        return 1
    N = max(prob.build(prob.generate(dict(p), 0)).variables.N for p in points)
    return workers if N >= AUTO_JOBS_MIN_N else 1


def jobs_after(prob: Problem, seconds_per_instance: float) -> int:
    """The held-out workers for the later batches of a discovery that chose them itself and ran a batch in this
    process at ``seconds_per_instance``: ``_workers`` from ``AUTO_JOBS_MIN_S`` on, else 1.  Results do not depend
    on it (``solve_batch``)."""
    return _workers(prob) if seconds_per_instance >= AUTO_JOBS_MIN_S else 1


def solve_one(ref: Problem | str, params: dict[str, Any], seed: int, sets: Mapping[str, ConstraintsLike],
              criteria: Criteria, config: SolverConfig, n_random: int,
              shortcut: bool = False) -> dict[str, dict[str, Any]]:
    """One held-out instance solved with every set: {set name: ``evaluate.summary`` row (outcome, log SVR,
    reason, …)} (``shortcut``: the module docstring; such a row has status "certified", log SVR NaN and no
    solver call)."""
    prob = load(ref)
    ev = evaluate(prob, params, seed, sets, config=config, criteria=criteria, n_random=n_random,
                  shortcut=certified_tight if shortcut else None, raise_unbounded=False, settle_early=True)
    return {name: summary(r) for name, r in ev.results.items()}


def _indexed(key: tuple[int, int], ref: Any, params: dict[str, Any], seed: int, sets: Any, criteria: Criteria,
             config: SolverConfig, n_random: int, shortcut: bool) -> tuple[tuple[int, int], dict[str, dict[str, Any]]]:
    return key, solve_one(ref, params, seed, sets, criteria, config, n_random, shortcut)


def hopeless(outcomes: Sequence[str], planned: int, min_fraction: float) -> bool:
    """True when a batch of ``planned`` instances whose first ones ended with ``outcomes`` cannot pass at
    ``min_fraction`` (``check``'s rule: tight / (instances − undecided)) whatever the others end with: the best
    case, every other instance tight, (T + R) / (T + F + R) is below ``min_fraction``."""
    tight, failed = outcomes.count("tight"), outcomes.count("not tight")
    rest = planned - len(outcomes)
    best = tight + rest
    return failed > 0 and best < (min_fraction - 1e-12) * (best + failed)


def _per_point(name: str, flag: bool | Sequence[bool], n: int) -> list[bool]:
    flags = [bool(flag)] * n if isinstance(flag, bool) else [bool(b) for b in flag]
    if len(flags) != n:
        raise ParameterError(f"{name} has {len(flags)} entries for {n} points")
    return flags


def solve_batch(prob: Problem, sets: Mapping[str, ConstraintsLike], points: Sequence[tuple[dict, dict]],
                batch: Sequence[Sequence[int]], *, min_fraction: float, criteria: Criteria, config: SolverConfig,
                n_random: int = 1, jobs: int = 1, scheduler: Any = None, shortcut: bool | Sequence[bool] = False,
                stop_hopeless: bool | Sequence[bool] = False) -> tuple[dict[str, list[PointResult]], dict[str, int]]:
    """Solve the seeds ``batch[i]`` at point i with every set (``shortcut``, ``stop_hopeless``: the module
    docstring; each True, or per point); the sets of one instance share its generation, model and local search.
    Returns {set name: [PointResult per point]} (instances in seed order) and {set name: SDP solver calls}."""
    from ..parallel import execute

    stops, shortcuts = _per_point("stop_hopeless", stop_hopeless, len(batch)), _per_point("shortcut", shortcut,
                                                                                          len(batch))
    if any(stops) and len(sets) != 1:
        raise ParameterError("stop_hopeless needs exactly one set")
    local = jobs == 1 and scheduler is None
    ref = problem_ref(prob, local)
    calls = [((i, t), ref, points[i][0], s, dict(sets), criteria, config, n_random, shortcuts[i])
             for i, seeds_ in enumerate(batch) for t, s in enumerate(seeds_)]
    done: dict[tuple[int, int], dict[str, dict[str, Any]]] = {}
    end = [len(b) for b in batch]  # per point: the instances that count (a prefix of its seeds)

    def wanted() -> Iterator[tuple]:  # read lazily (in process, joblib): a hopeless point's rest is skipped
        return (c for c in calls if c[0][1] < end[c[0][0]])

    for key, rows in execute(_indexed, wanted() if any(stops) else calls, jobs=jobs, scheduler=scheduler):
        done[key] = rows
        i = key[0]
        if not stops[i] or key[1] >= end[i]:
            continue
        outcomes: list[str] = []
        for t in range(end[i]):  # the known prefix of point i, in seed order
            if (i, t) not in done:
                break
            outcomes.append(next(iter(done[(i, t)].values()))["outcome"])
            if hopeless(outcomes, len(batch[i]), min_fraction):
                end[i] = t + 1
                break
    out = {name: [PointResult(full, varied, min_fraction) for full, varied in points] for name in sets}
    n = {name: 0 for name in sets}
    for key, _, _, s, *_ in calls:
        if key[1] >= end[key[0]]:
            continue
        for name, row in done[key].items():
            pr = out[name][key[0]]
            pr.add(s, row)
            pr.set_label = name
            n[name] += row["calls"]
    return out, n
