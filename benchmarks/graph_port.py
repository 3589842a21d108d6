"""A problem on the factor-graph layer against the hand-written module it replaced, in the same run.

Problems: rotation_averaging (its measurement factors one by one, with auxiliary blocks), pose_averaging
(one factor family) and discrete_trajectory (two families, the odometry's factors on consecutive poses; its size
is K, the number of poses).  Each side runs in a fresh process with its own checkout first on sys.path, interleaved
(before, after, before, …) so that the load of this shared machine falls on both alike: ``build`` on a fresh
instance (seed 0; the layer caches its graph per instance object, so a fresh one is built each time), then
``local_solve`` from the truth and from one random state (seed 1), and the layer's derived solver
(``layer_local_solve``) likewise when the module keeps its own.  Reported per M: the medians over
repeats of each time, the costs and iterations (the two sides must agree: relative cost difference), and
the ratio after / before of each median.  The size (``--M``) is M, or K for discrete_trajectory.

    git worktree add --detach /tmp/autotight-before <commit before the port>
    python benchmarks/graph_port.py --problem pose_averaging --before /tmp/autotight-before [--repeats 3] \
        [--M 10,100,1000]

Prints, and writes the problem's entry of benchmarks/results/graph_port.json (the other problems' entries kept).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: run in the child process: argv = [checkout, problem, M]; prints one JSON line
CHILD = r"""
import importlib, json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
ra = importlib.import_module("problems." + sys.argv[2])
M = int(sys.argv[3])
params = {"rotation_averaging": {"M": M, "sigma": 0.1, "anisotropy": 1.0},
          "pose_averaging": {"M": M, "sigma": 0.1, "scale": 1.0},
          "discrete_trajectory": {"K": M, "sigma": 0.1, "speed": 1.0, "turn_rate": 0.3, "climb": 0.1}}[sys.argv[2]]
inst = ra.generate(params, np.random.default_rng(0))
t = time.perf_counter(); ra.build(inst); build = time.perf_counter() - t
start = ra.random_state(inst, np.random.default_rng(1))
out = {"where": ra.__file__, "build_s": build}
for name, init in (("truth", dict(inst.truth)), ("random", start)):
    t = time.perf_counter(); r = ra.local_solve(inst, init); out[f"local_{name}_s"] = time.perf_counter() - t
    out[f"cost_{name}"], out[f"iterations_{name}"] = float(r.cost), int(r.iterations)
    if hasattr(ra, "layer_local_solve"):  # a module that keeps its own solver: the layer's derived one too
        t = time.perf_counter(); r = ra.layer_local_solve(inst, init)
        out[f"layer_local_{name}_s"] = time.perf_counter() - t
        out[f"layer_cost_{name}"], out[f"layer_iterations_{name}"] = float(r.cost), int(r.iterations)
print(json.dumps(out))
"""

TIMES = ("build_s", "local_truth_s", "local_random_s")


PROBLEMS = ("rotation_averaging", "pose_averaging", "discrete_trajectory")


def run(checkout: Path, problem: str, M: int) -> dict:
    p = subprocess.run([sys.executable, "-c", CHILD, str(checkout), problem, str(M)], capture_output=True, text=True,
                       check=True, cwd="/")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problem", choices=PROBLEMS, default="rotation_averaging")
    ap.add_argument("--before", type=Path, required=True, help="checkout with the hand-written module")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--M", default="10,100,1000", help="comma-separated sizes (measurements M, or poses K)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "graph_port.json")
    a = ap.parse_args()
    cases = []
    for M in (int(m) for m in a.M.split(",")):
        runs: dict[str, list[dict]] = {"before": [], "after": []}
        for _ in range(a.repeats):
            runs["before"].append(run(a.before.resolve(), a.problem, M))
            runs["after"].append(run(ROOT, a.problem, M))
        med = {side: {k: float(np.median([r[k] for r in rs])) for k in TIMES} for side, rs in runs.items()}
        b, f = runs["before"][0], runs["after"][0]
        case = {"M": M, "median_s": med, "ratio_after_before": {k: med["after"][k] / med["before"][k] for k in TIMES},
                "iterations": {s: [runs[s][0]["iterations_truth"], runs[s][0]["iterations_random"]] for s in runs},
                "rel_cost_diff": {k: abs(f[f"cost_{k}"] - b[f"cost_{k}"]) / abs(b[f"cost_{k}"])
                                  for k in ("truth", "random")},
                "runs": runs}
        layer = [k for k in runs["after"][0] if k.startswith("layer_local_")]
        if layer:  # the derived solver against the hand-written module's
            lmed = {k: float(np.median([r[k] for r in runs["after"]])) for k in layer}
            case["layer_local_solve"] = {
                "median_s": lmed, "ratio_to_before": {k: lmed[k] / med["before"][k[len("layer_"):]] for k in layer},
                "iterations": [f["layer_iterations_truth"], f["layer_iterations_random"]],
                "rel_cost_diff": {k: abs(f[f"layer_cost_{k}"] - b[f"cost_{k}"]) / abs(b[f"cost_{k}"])
                                  for k in ("truth", "random")}}
        cases.append(case)
        print(json.dumps({k: v for k, v in case.items() if k != "runs"}))
    saved = json.loads(a.out.read_text()) if a.out.exists() else {}
    if "cases" in saved:  # the file of rotation averaging alone
        saved = {"problems": {"rotation_averaging": {k: saved[k] for k in ("repeats", "before", "cases")}}}
    problems = saved.get("problems", {})
    problems[a.problem] = {"repeats": a.repeats, "before": str(a.before), "cases": cases}
    a.out.write_text(json.dumps({"benchmark": "graph_port", "problems": problems}, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
