"""Run a sweep into a folder: skip done trials, run the rest on a backend, save each as it finishes."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import AbstractSet, Any, Callable, Sequence

from tqdm import tqdm

from ..set_file import check_set_file
from ..constraint_set import ConstraintSet
from ..problem import Problem
from ..outpaths import LOCK_NAME, check_folder, folder_lock, writing
from ..parallel import connect, execute
from .spec import ReportError, SweepSpec
from .store import CSV_NAME, ERROR, META_NAME, STATUSES, Store, is_error
from ..pipeline import has_marginal
from .trial import columns, error_keys, run_trial

DISCOVERED_NAME = "discovered.json"


@dataclass
class SweepSummary:
    """How many trials the sweep has, had before this run, computed now, and how many failed."""

    out: Path
    total: int
    done_before: int
    computed: int
    failed: int

    @property
    def complete(self) -> bool:
        return self.done_before + self.computed >= self.total


def run_sweep(spec: SweepSpec, out: str | Path, *, jobs: int = 1, scheduler: Any = None, limit: int | None = None,
              redo: Sequence[str] = (), progress: bool = True,
              log: Callable[[str], None] = lambda msg: None) -> SweepSummary:
    """Compute the trials of ``spec`` missing from ``out`` (at most ``limit`` of them); ``log`` gets notes.

    redo: solver statuses whose saved trials are dropped first and computed again ("Error": every
    failed trial).  Before any work: the folder is checked (``outpaths.check_folder``,
    ``Store.precheck``) and the scheduler reached.  While running, ``out/.lock`` is held.  A run that
    created ``out`` and saved no trial leaves no folder behind (only a discovered set it computed).
    ReportError when every trial of the sweep failed (the first trial's error)."""
    if jobs < 1:
        raise ReportError(f"--jobs {jobs}: need at least 1 worker")
    if limit is not None and limit < 0:
        raise ReportError(f"--limit {limit}: must be ≥ 0")
    out = check_folder(out)
    store = Store(out)
    store.precheck(spec.identity())
    check_redo(redo, store.saved_statuses())
    backend = "dask" if scheduler is not None else ("joblib" if jobs > 1 else "serial")
    created = not out.exists()
    kept = not created  # whether the folder stays on an error: it existed, or holds a successful trial
    try:
        with connect(scheduler) as client, folder_lock(out):
            problem = spec.load()
            discovered, disc_id = prepare_discovered(spec, problem, out, log)
            saved_sets, files_id = prepare_files(spec, problem)
            if discovered is not None:
                saved_sets["discovered"] = discovered
            identity = dict(spec.identity(), discovered=disc_id) | ({"files": files_id} if files_id else {})
            done = store.open(identity, columns(error_keys(problem, spec), has_marginal(problem)),
                              spec.sets, spec.trials, info={"description": problem.description, "source": spec.source},
                              run_info={"backend": backend, "jobs": jobs, "command": f"{spec.command()} --out {out}"},
                              redo=redo)
            if store.dropped:
                log(f"re-running {store.dropped} saved trial(s) with status {', '.join(redo)}")
            if store.added_columns:
                log(f"note: columns added since the last run, empty for the trials saved before: "
                    f"{', '.join(store.added_columns)}")
            if store.version_changes:
                log(f"note: package versions changed since the last run ({', '.join(store.version_changes)}); "
                    f"each run's versions are in {store.meta_path}")
            tasks = spec.tasks()
            missing = [k for k in tasks if k not in done]
            pending = missing if limit is None else missing[:limit]
            before = len(tasks) - len(missing)
            computed = failed = 0
            with tqdm(total=len(tasks), initial=before, disable=None if progress else True, unit="trial",
                      desc=problem.name, dynamic_ncols=True) as bar:
                calls = [(spec, i, t, saved_sets) for i, t in pending]
                for res in execute(run_trial, calls, jobs=jobs, scheduler=client):
                    store.append(res.rows)
                    computed += 1
                    bad = is_error(res.rows[0]["status"])
                    failed += bad
                    kept |= not bad
                    bar.update()
            summary = SweepSummary(out, len(tasks), before, computed, failed)
            if computed and failed == computed:
                first = store.first_error_if_all_failed()
                if first is not None:  # no figures from nothing: the error, and a new folder is removed
                    raise ReportError(f"every trial failed; the first: {first}")
            if summary.complete:
                store.finalize()
            return summary
    except BaseException:
        if not kept:
            _remove_new_folder(out)
        raise


def check_redo(redo: Sequence[str], saved: AbstractSet[str] = frozenset()) -> None:
    """Every ``--redo`` entry is a solver status, a status saved in the folder, or "Error" (every failed trial)."""
    bad = [r for r in redo if r not in STATUSES and r != ERROR and r not in saved]
    if bad:
        raise ReportError(f"--redo {','.join(bad)}: not a solver status; use some of {', '.join(STATUSES)} "
                          "or Error (every failed trial)")


def _remove_new_folder(out: Path) -> None:
    """Remove what this run wrote into the folder it created, but a discovered set it computed (work kept);
    a rerun then starts afresh."""
    for name in (META_NAME, CSV_NAME, LOCK_NAME):
        (out / name).unlink(missing_ok=True)
    for tmp in out.glob(".*.tmp"):
        tmp.unlink(missing_ok=True)
    try:
        out.rmdir()
    except OSError:  # not empty: the discovered set stays for the next run
        pass


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_set(path: Path, problem: Problem, what: str) -> ConstraintSet:
    """A saved constraint set for ``problem`` (one-line errors for a missing or foreign file)."""
    if not path.is_file():
        raise ReportError(f"no constraint-set file {path}")
    check_set_file(path, what)
    cs = ConstraintSet.load(path)
    if cs.problem != problem.name:
        raise ReportError(f"{path} is a constraint set for {cs.problem}, not {problem.name}")
    return cs


def prepare_files(spec: SweepSpec, problem: Problem) -> tuple[dict[str, ConstraintSet], dict[str, Any]]:
    """The saved sets of ``file:PATH`` in ``--sets`` by name, and their identities (file, sha256)."""
    sets, ids = {}, {}
    for name, p in spec.files:
        path = Path(p)
        sets[name] = load_set(path, problem, f"--sets file:{p}")
        ids[name] = {"file": path.name, "sha256": _sha256(path)}
    return sets, ids


def prepare_discovered(spec: SweepSpec, problem: Problem, out: Path,
                       log: Callable[[str], None] = lambda msg: None) -> tuple[Any, dict[str, Any] | None]:
    """The discovered set (loaded from ``spec.discovered``, from ``out``, or by running discovery) and its identity."""
    if "discovered" not in spec.sets:
        return None, None
    path = Path(spec.discovered) if spec.discovered else None
    if path is not None and not path.is_file():
        raise ReportError(f"no discovered-set file {path}")
    from ..api import discover
    from ..discovery import DiscoveredSet
    if path is not None:
        check_set_file(path, "--discovered")
        ds = DiscoveredSet.load(path)
        if getattr(ds, "problem", problem.name) != problem.name:
            raise ReportError(f"{path} is a discovered set for {ds.problem}, not {problem.name}")
        return ConstraintSet(ds), {"file": path.name, "sha256": _sha256(path)}
    saved = out / DISCOVERED_NAME
    if not saved.is_file():
        params = problem.parse_params(spec.params)  # σ at the problem's default
        log(f"running discovery for {problem.name} at {params} (seed {spec.seed}); saving it to {saved}")
        # the report's set is selected and validated at its own parameters (no META.carry_to hint)
        res = discover(problem, params, seed=spec.seed, criteria=spec.criteria, solver=spec.solver_config(),
                       carry_to={})
        with writing(saved):
            res.save(saved)
    return ConstraintSet(DiscoveredSet.load(saved)), {"source": "discover", "seed": spec.seed, "sha256": _sha256(saved)}
