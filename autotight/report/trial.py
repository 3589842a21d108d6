"""One trial of a sweep: a fresh instance, local solves, and the SDP with every constraint set.

Runs in a worker; returns rows (one per constraint set) and writes nothing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Sequence, cast

import numpy as np
from threadpoolctl import threadpool_limits

from ..errors import AutotightError
from ..evaluate import evaluate_instance
from ..pipeline import SolveResult, has_marginal, is_trapped
from ..problem import Instance, Problem
from .spec import SweepSpec, trial_seeds
from .store import ERROR

KEY = ("sigma_index", "trial")
BASE_COLUMNS = ("problem", "sigma_index", "sigma", "trial", "seed", "constraint_set", "n_constraints", "status",
                "outcome", "tight", "rank_tight", "cost_tight", "log_svr", "sdp_cost", "sdp_dual_cost",
                "sdp_dual_raw", "sdp_lower_bound", "sdp_accuracy", "sdp_tolerance", "rel_gap", "upper_bound",
                "refined_cost",
                "sdp_attempts", "undecided", "certified", "cert_rel_bound", "sdp_beats_local",
                "local_cost_truth", "local_cost_random", "local_converged_truth", "local_converged_random",
                "global_cost", "trapped")
TIME_COLUMNS = ("sdp_time_s", "sdp_setup_s", "local_truth_time_s", "local_random_time_s", "build_time_s",
                "trial_time_s")
TAIL_COLUMNS = ("verdict",)
ERROR_PREFIXES = ("err_sdp_", "err_truth_", "err_random_")


def columns(error_keys: Sequence[str], marginal: bool = False) -> list[str]:
    """CSV columns for a problem whose ``errors`` returns ``error_keys``; ``marginal``: the module
    defines ``marginal_log_svr``, so each row also holds ``log_svr_marginal`` (log SVR of the
    module's reduced X, e.g. continuous time's marginalised X, whatever formulation was solved)."""
    errs = [p + k for p in ERROR_PREFIXES for k in error_keys]
    extra = ("log_svr_marginal",) if marginal else ()
    return [*BASE_COLUMNS, *extra, *errs, *TIME_COLUMNS, *TAIL_COLUMNS]



def error_keys(problem: Problem, spec: SweepSpec) -> list[str]:
    """Names of the problem's estimation errors (from the ground truth of the first trial's instance)."""
    seed, _, _ = trial_seeds(spec.seed, 0, 0)
    inst = problem.generate(dict(spec.params, sigma=spec.sigmas[0]), seed)
    return list(problem.errors(inst, inst.truth))


@dataclass
class TrialResult:
    key: tuple[int, int]
    rows: list[dict[str, Any]]


def run_trial(spec: SweepSpec, sigma_index: int, trial: int, discovered: Any = None) -> TrialResult:
    """Trial ``(sigma_index, trial)`` of ``spec``, BLAS limited to one thread; failures become rows.
    ``discovered``: the learned and saved constraint sets by set name (``sweep.prepare_files``)."""
    with threadpool_limits(limits=1):
        t0 = time.perf_counter()
        problem = spec.load()
        try:
            rows = _solve(problem, spec, sigma_index, trial, discovered)
        except (AutotightError, ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
            msg = f"{ERROR}: {type(e).__name__}: {e}".splitlines()[0]
            seed, _, _ = trial_seeds(spec.seed, sigma_index, trial)
            rows = [_row(problem, spec, sigma_index, trial, seed, s, status=msg) for s in spec.sets]
        dt = time.perf_counter() - t0
        for r in rows:
            r["trial_time_s"] = dt
        return TrialResult((sigma_index, trial), rows)


def _row(problem: Problem, spec: SweepSpec, i: int, t: int, seed: int, set_name: str, **kw: Any) -> dict[str, Any]:
    return {"problem": problem.name, "sigma_index": i, "sigma": spec.sigmas[i], "trial": t, "seed": seed,
            "constraint_set": set_name, **kw}


def _errors(problem: Problem, inst: Instance, state: dict | None, prefix: str) -> dict[str, float]:
    if state is None:
        return {}
    return {prefix + k: v for k, v in problem.errors(inst, state).items()}


def _solve(problem: Problem, spec: SweepSpec, i: int, t: int, discovered: Any) -> list[dict[str, Any]]:
    """Every constraint set of ``spec`` on trial (i, t)'s instance, through ``autotight.evaluate`` (one build
    and one local search shared by the sets; the local starts draw from the trial's ``rng_local``, a learned
    set from its ``rng_disc``, ``spec.trial_seeds``)."""
    seed, rng_local, rng_disc = trial_seeds(spec.seed, i, t)
    t0 = time.perf_counter()
    inst = problem.generate(dict(spec.params, sigma=spec.sigmas[i]), seed)
    generate_s = time.perf_counter() - t0
    sets = {name: discovered[name] if discovered and name in discovered else name for name in spec.sets}
    # an error, a failed instantiation of a learned set included, fails the whole trial (``run_trial``)
    ev = evaluate_instance(problem, inst, sets, config=spec.solver_config(), criteria=spec.criteria,
                           rng_local=rng_local, rng_constraints=rng_disc, n_random=1, catch_instantiate=False)
    loc = ev.local
    truth, rand = loc.from_truth, loc.from_random[0]
    common = {"local_cost_truth": truth.cost, "local_cost_random": rand.cost,
              "local_converged_truth": truth.converged, "local_converged_random": rand.converged,
              "local_truth_time_s": truth.time_s, "local_random_time_s": rand.time_s,
              "build_time_s": generate_s + ev.times["build_s"],
              **_errors(problem, inst, truth.state, "err_truth_"), **_errors(problem, inst, rand.state, "err_random_")}
    rows, uppers = [], []
    for name, result in ev.results.items():
        out = cast(SolveResult, result)  # without a shortcut, and an instantiation failure raised: always solved
        res, verdict = out.sdp, out.verdict
        uppers.append(out.upper)
        errs = {"err_sdp_" + k: v for k, v in out.errors_sdp.items()}
        rows.append(_row(problem, spec, i, t, seed, name, n_constraints=out.n_constraints, status=res.status,
                         outcome=out.outcome, tight=verdict.tight, rank_tight=verdict.rank_tight,
                         cost_tight=verdict.cost_tight, log_svr=res.log_svr, sdp_cost=res.primal_cost,
                         sdp_dual_cost=res.dual_cost, sdp_dual_raw=res.dual_cost_raw,
                         sdp_lower_bound=verdict.lower, sdp_accuracy=verdict.accuracy,
                         sdp_tolerance=verdict.tolerance,
                         rel_gap=verdict.rel_gap, upper_bound=out.upper,
                         refined_cost=None if out.refined is None else out.refined.cost,
                         sdp_attempts=len(out.attempts), undecided=verdict.undecided,
                         certified=None if out.certificate is None else out.certificate.certified,
                         cert_rel_bound=None if out.certificate is None else out.certificate.rel_bound,
                         sdp_beats_local=out.sdp_beats_local,
                         **({"log_svr_marginal": out.log_svr_marginal} if has_marginal(problem) else {}),
                         sdp_time_s=res.solve_time_s, sdp_setup_s=res.setup_time_s,
                         verdict=verdict.reason, **common, **errs))
    finite = [c for c in (truth.cost, rand.cost, *uppers) if np.isfinite(c)]
    global_cost = min(finite) if finite else float("nan")
    trapped = is_trapped(rand.cost, global_cost, spec.trap_rtol, spec.criteria.cost_floor)
    for r in rows:
        r["global_cost"], r["trapped"] = global_cost, trapped
    return rows
