"""What the public-API refactor costs: `solve` and `discover` before and after, in the same run.

Both checkouts are run through their own CLI (`python -m autotight.cli … --json`, the one
interface that both versions share) in fresh processes, interleaved (before, after, before, …),
so that the load of this shared machine falls on both alike.  The figure is the ratio of the
medians (after / before) of the time the run itself reports (solve: build + local solves + SDP, the
stages both versions run; discover: its total), and of the process's wall time (which includes the
new verdict work: refinement, certificate).

The after side runs twice.  "after" is the refactored code with ``--scale none``: the same numerical
method as before, so its ratio is the refactor's own cost (target ≤ 1.1).  "after_scaled" is the default,
which also applies the block scaling X = D X' D of the verdict work (``autotight/sdp/scaling.py``): a
deliberate change of the SDP data that costs Clarabel a few iterations (rotation averaging 10 → 13,
discrete K = 20: 15 → 20) and buys the low-noise accuracy; its ratio is reported beside, not as the
refactor's.

    git worktree add /tmp/autotight-before b5513cf
    python benchmarks/refactor_cost.py --before /tmp/autotight-before [--repeats 5]

Prints and writes benchmarks/results/refactor_cost.json.
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

#: (name, CLI arguments, what the JSON reports as the run's own time)
CASES = [
    ("solve rotation_averaging M=10", ["solve", "rotation_averaging", "-p", "M=10", "--json"], "solve"),
    ("solve pose_averaging M=10", ["solve", "pose_averaging", "-p", "M=10", "--json"], "solve"),
    ("solve discrete_trajectory K=20", ["solve", "discrete_trajectory", "-p", "K=20", "--json"], "solve"),
    ("discover rotation_averaging M=5", ["discover", "rotation_averaging", "-p", "M=5", "--heldout", "2",
                                         "--json"], "discover"),
    ("discover pose_averaging M=5", ["discover", "pose_averaging", "-p", "M=5", "--heldout", "2", "--json"],
     "discover"),
    ("discover discrete_trajectory K=20", ["discover", "discrete_trajectory", "-p", "K=20", "--heldout", "0",
                                           "--no-carry", "--json"], "discover"),
]


#: the stages of a solve that both versions run: build, the local solves, the SDP.  The refactored pipeline
#: also refines the SDP's estimate, certifies the best point and judges by the bracket (the verdict
#: work, reported separately as ``extra_s``); the refactor itself is measured on the common stages.
COMMON = ("build_s", "local_s", "sdp_total_s")


def own_time(kind: str, rec: dict) -> float:
    """The run's own time: solve → its common stages (``COMMON``); discover → its total."""
    t = rec["times"]
    if kind == "discover":
        return float(t["total_s"])
    return float(sum(float(t.get(k, 0.0)) for k in COMMON))


#: side → (checkout attribute of the arguments, extra CLI arguments)
SIDES = {"before": ("before", []), "after": ("after", ["--scale", "none"]), "after_scaled": ("after", [])}


def run(checkout: Path, args: list[str]) -> tuple[float, float, dict]:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "autotight.cli", *args], cwd=checkout, env=env,
                          capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{checkout}: {' '.join(args)} failed:\n{proc.stderr[-2000:]}")
    rec = json.loads(proc.stdout.strip().splitlines()[-1])
    return wall, own_time("discover" if args[0] == "discover" else "solve", rec), rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="checkout of the commit before the refactor")
    ap.add_argument("--after", type=Path, default=ROOT, help="checkout after (default: this one)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "refactor_cost.json")
    a = ap.parse_args()
    rows = []
    for name, args, _ in CASES:
        t = {side: {"wall": [], "own": []} for side in SIDES}
        verdicts = {}
        for _ in range(a.repeats):
            for side, (which, extra) in SIDES.items():
                wall, own, rec = run(getattr(a, which), args + extra)
                t[side]["wall"].append(wall)
                t[side]["own"].append(own)
                verdicts[side] = rec.get("tight")
        med = {s: {k: float(np.median(v)) for k, v in d.items()} for s, d in t.items()}
        ratio = {f"ratio_{k}{suffix}": med[side][k] / med["before"][k] for k in ("own", "wall")
                 for side, suffix in (("after", ""), ("after_scaled", "_scaled"))}
        row = {"case": name, "command": "autotight " + " ".join(args), "median_s": med, **ratio,
               "tight": verdicts, "samples": t}
        rows.append(row)
        print(f"{name:<36} own {med['before']['own']:.3f} → {med['after']['own']:.3f} s (×{ratio['ratio_own']:.2f}; "
              f"scaled {med['after_scaled']['own']:.3f} s ×{ratio['ratio_own_scaled']:.2f})   wall "
              f"×{ratio['ratio_wall']:.2f} (scaled ×{ratio['ratio_wall_scaled']:.2f})   tight {verdicts}")
    load = os.getloadavg()
    from autotight.io import versions

    out = {"benchmark": "refactor_cost", "repeats": a.repeats, "before": str(a.before), "after": str(a.after),
           "compared_against": "the same commands on the checkout before the refactor, interleaved",
           "sides": {k: {"checkout": str(getattr(a, w)), "extra_args": e} for k, (w, e) in SIDES.items()},
           "target": "ratio_own (after --scale none / before) within 1.1; ratio_own_scaled is the default's",
           "load_average": load, "versions": versions(), "cases": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"load average {load[0]:.1f}; written {a.out}")


if __name__ == "__main__":
    main()
