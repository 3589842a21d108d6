"""Speed-up of ``autotight report`` with 2 joblib workers over 1, on this machine, same sweep side by side.

Each repeat runs the same sweep (rotation averaging, M = 10, 4 noise levels) into fresh folders:
  serial       --jobs 1 (in-process, the baseline);
  joblib2_cold --jobs 2 with the loky workers started from scratch (what one CLI run sees);
  joblib2_warm --jobs 2 again, workers already running (the per-trial throughput).
Only the sweep is timed (not the figures).  The per-trial results of all three are checked to be
identical.  ``concurrency`` = Σ per-trial wall time / sweep wall time: how many trials ran at once
on average (≈ 2 for two busy workers even when other load on the machine slows each trial).
Prints and writes benchmarks/results/report_parallel.json.

    python benchmarks/report_parallel.py [--trials 10] [--repeats 3] [--M 10]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import pandas as pd

from autotight.io import jsonable, versions
from autotight.problem import load
from autotight.report.spec import make_spec
from autotight.report.store import load_trials
from autotight.report.sweep import run_sweep
from autotight.report.trial import TIME_COLUMNS

SIGMAS = "0.001,0.01,0.1,1"


def _timed(spec, out: Path, jobs: int) -> float:
    t = time.perf_counter()
    s = run_sweep(spec, out, jobs=jobs, progress=False)
    dt = time.perf_counter() - t
    assert s.complete and s.computed == s.total, s
    return dt


def _det(out: Path) -> pd.DataFrame:
    df = load_trials(out)
    return df[[c for c in df.columns if c not in TIME_COLUMNS]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per noise level (default 10)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--M", type=int, default=10)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "report_parallel.json"))
    a = ap.parse_args()
    from joblib.externals.loky import get_reusable_executor

    spec = make_spec(load("rotation_averaging"), "rotation_averaging", {"M": a.M}, sigmas=SIGMAS, trials=a.trials,
                     sets="primary")
    n = len(spec.tasks())
    times: dict[str, list[float]] = {"serial": [], "joblib2_cold": [], "joblib2_warm": []}
    concurrency: dict[str, list[float]] = {k: [] for k in times}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.repeats):
            get_reusable_executor().shutdown(wait=True)
            for mode, jobs in (("serial", 1), ("joblib2_cold", 2), ("joblib2_warm", 2)):
                out = Path(tmp) / f"{mode}_{r}"
                times[mode].append(_timed(spec, out, jobs))
                per_trial = load_trials(out).drop_duplicates(["sigma_index", "trial"])["trial_time_s"].sum()
                concurrency[mode].append(per_trial / times[mode][-1])
                print(f"repeat {r}: {mode:13s} {times[mode][-1]:6.2f} s  ({n} trials)", flush=True)
            ref = _det(Path(tmp) / f"serial_{r}")
            for mode in ("joblib2_cold", "joblib2_warm"):
                pd.testing.assert_frame_equal(_det(Path(tmp) / f"{mode}_{r}"), ref)
    med = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "benchmark": "autotight report: 2 joblib (loky) workers vs 1 (in-process), same sweep, medians of repeats",
        "sweep": {"problem": spec.problem, "params": spec.params, "sigmas": spec.sigmas, "trials_per_sigma": a.trials,
                  "sets": spec.sets, "n_trials": n},
        "compared_against": "serial: --jobs 1 in the same process, same sweep, run alternately with the 2-worker runs",
        "seconds": times, "median_s": med,
        "speedup_cold": med["serial"] / med["joblib2_cold"], "speedup_warm": med["serial"] / med["joblib2_warm"],
        "trials_per_s": {k: n / v for k, v in med.items()},
        "concurrency": {k: statistics.median(v) for k, v in concurrency.items()},
        "results_identical_across_backends": True,
        "machine": {"cpus": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)),
                    "loadavg_before": load_before, "loadavg_after": os.getloadavg()},
        "versions": versions(),
    }
    print(f"median: serial {med['serial']:.2f} s, 2 workers {med['joblib2_cold']:.2f} s cold / "
          f"{med['joblib2_warm']:.2f} s warm → speed-up {result['speedup_cold']:.2f}× cold, "
          f"{result['speedup_warm']:.2f}× warm (load average before {load_before[0]:.1f})")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(jsonable(result), indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
