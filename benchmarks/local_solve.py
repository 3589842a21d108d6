"""The local solvers (Gauss-Newton) before and after vectorising their residuals, in the same run.

The change: ``linearize`` of discrete trajectory, pose averaging and robust pose averaging evaluates
the residuals and Jacobians of all factors of a type in one pass (``lie.residuals_se3``,
``lie.residuals_se3_binary``), and pose averaging's weight is sparse instead of a dense 6M × 6M
matrix.  Each side runs ``local_solve`` in a fresh process with its own checkout on sys.path,
interleaved (before, after, before, …) so that the load of this shared machine falls on both alike,
from the true state and from one random state (seed 1) of the same instance (seed 0).  Reported per
case: time (median over repeats), cost and iterations, the ratio after / before of the times and
the relative cost difference (the two must agree); per process, the peak RSS over both solves and
the peak before them (instance generated, imports done).

    git worktree add --detach /tmp/autotight-before <commit before the change>
    python benchmarks/local_solve.py --before /tmp/autotight-before [--repeats 2]

Prints and writes benchmarks/results/local_solve.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = (("discrete_trajectory", {"K": 100}), ("discrete_trajectory", {"K": 300}), ("pose_averaging", {"M": 1000}))

SOLVE = """
import json, resource, sys, time
import numpy as np
from autotight import lie
from autotight.problem import load
prob = load(sys.argv[1])
inst = prob.generate(prob.parse_params(json.loads(sys.argv[2])), np.random.default_rng(0))
starts = {"truth": inst.truth, "random": prob.random_state(inst, np.random.default_rng(1))}
out = {"module": lie.__file__, "rss_before_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
for start, init in starts.items():
    t = time.perf_counter()
    r = prob.local_solve(inst, init)
    out[start] = {"time_s": time.perf_counter() - t, "cost": r.cost, "iterations": r.iterations}
out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def run(src: Path, problem: str, params: dict) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", SOLVE, problem, json.dumps(params)], env=env, cwd=src,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="a checkout of the commit before the change")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    sides = {"before": Path(args.before).resolve(), "after": ROOT}
    rows = []
    for problem, params in CASES:
        runs: dict[str, list[dict]] = {s: [] for s in sides}
        for _ in range(args.repeats):
            for side, src in sides.items():
                runs[side].append(run(src, problem, params))
        for start in ("truth", "random"):
            row: dict = {"problem": problem, "params": params, "start": start}
            for side, rs in runs.items():
                row[side] = {**rs[0][start], "time_s": float(np.median([r[start]["time_s"] for r in rs])),
                             "times_s": [r[start]["time_s"] for r in rs], "module": rs[0]["module"],
                             "peak_rss_mb": max(r["peak_rss_mb"] for r in rs),
                             "rss_before_mb": max(r["rss_before_mb"] for r in rs)}
            b, a = row["before"], row["after"]
            row["time_ratio_after_before"] = a["time_s"] / b["time_s"]
            row["cost_rel_diff"] = abs(a["cost"] - b["cost"]) / max(abs(b["cost"]), 1e-300)
            rows.append(row)
            print(f"{problem} {params} from {start}: before {b['time_s']:.2f} s ({b['iterations']} it, "
                  f"peak RSS {b['peak_rss_mb']:.0f} MB), after {a['time_s']:.2f} s ({a['iterations']} it, "
                  f"{a['peak_rss_mb']:.0f} MB); ratio {row['time_ratio_after_before']:.3f}, "
                  f"cost difference {row['cost_rel_diff']:.1e}", flush=True)
    res = {"benchmark": "local_solve", "seed": 0, "random_start_seed": 1,
           "compared_against": "the local solvers before the change (--before checkout), same instances, "
                               "interleaved fresh processes",
           "repeats": args.repeats, "rows": rows, "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg()),
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "command": f"python benchmarks/local_solve.py --before {args.before} --repeats {args.repeats}"}
    out = ROOT / "benchmarks" / "results" / "local_solve.json"
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
