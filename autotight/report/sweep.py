"""Run a sweep into a folder: skip done trials, run the rest on a backend, save each as it finishes."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from tqdm import tqdm

from ..constraint_set import ConstraintSet
from ..problem import Problem
from .backends import execute
from .spec import ReportError, SweepSpec
from .store import Store
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

    redo: solver statuses whose saved trials are dropped first and computed again."""
    if jobs < 1:
        raise ReportError(f"--jobs {jobs}: need at least 1 worker")
    if limit is not None and limit < 0:
        raise ReportError(f"--limit {limit}: must be ≥ 0")
    out = Path(out)
    problem = spec.load()
    discovered, disc_id = prepare_discovered(spec, problem, out, log)
    store = Store(out)
    backend = "dask" if scheduler is not None else ("joblib" if jobs > 1 else "serial")
    done = store.open(dict(spec.identity(), discovered=disc_id), columns(error_keys(problem, spec)), spec.sets,
                      spec.trials, info={"description": problem.description, "source": spec.source},
                      run_info={"backend": backend, "jobs": jobs, "command": f"{spec.command()} --out {out}"},
                      redo=redo)
    if store.dropped:
        log(f"re-running {store.dropped} saved trial(s) with status {', '.join(redo)}")
    if store.version_changes:
        log(f"note: package versions changed since the last run ({', '.join(store.version_changes)}); "
            f"each run's versions are in {store.meta_path}")
    tasks = spec.tasks()
    missing = [k for k in tasks if k not in done]
    pending = missing if limit is None else missing[:limit]
    before = len(tasks) - len(missing)
    computed = failed = 0
    with tqdm(total=len(tasks), initial=before, disable=None if progress else True, unit="trial", desc=problem.name,
              dynamic_ncols=True) as bar:
        calls = [(spec, i, t, discovered) for i, t in pending]
        for res in execute(run_trial, calls, jobs=jobs, scheduler=scheduler):
            store.append(res.rows)
            computed += 1
            failed += str(res.rows[0]["status"]).startswith("Error")
            bar.update()
    summary = SweepSummary(out, len(tasks), before, computed, failed)
    if summary.complete:
        store.finalize()
    return summary


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def prepare_discovered(spec: SweepSpec, problem: Problem, out: Path,
                       log: Callable[[str], None] = lambda msg: None) -> tuple[Any, dict[str, Any] | None]:
    """The discovered set (loaded from ``spec.discovered``, from ``out``, or by running discovery) and its identity."""
    if "discovered" not in spec.sets:
        return None, None
    path = Path(spec.discovered) if spec.discovered else None
    if path is not None and not path.is_file():
        raise ReportError(f"no discovered-set file {path}")
    from ..discovery import DiscoveredSet, discover
    if path is not None:
        ds = DiscoveredSet.load(path)
        if getattr(ds, "problem", problem.name) != problem.name:
            raise ReportError(f"{path} is a discovered set for {ds.problem}, not {problem.name}")
        return ConstraintSet(ds), {"file": path.name, "sha256": _sha256(path)}
    saved = out / DISCOVERED_NAME
    if not saved.is_file():
        params = problem.parse_params(spec.params)  # σ at the problem's default
        log(f"running discovery for {problem.name} at {params} (seed {spec.seed}); saving it to {saved}")
        res = discover(problem, params, seed=spec.seed, criteria=spec.criteria)
        out.mkdir(parents=True, exist_ok=True)
        res.discovered.save(saved, res.model, res.constraints, {"summary": res.summary()})
    return ConstraintSet(DiscoveredSet.load(saved)), {"source": "discover", "seed": spec.seed, "sha256": _sha256(saved)}
