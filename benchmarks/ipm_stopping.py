"""Our IPM's stopping rule before and after, on the same block programs, in the same run.

The change (``autotight/sdp/schur_ipm.py``): relative residuals in the ∞-norm instead of the 2-norm
over all rows (which grows like √M at a fixed accuracy per row), and a stall clock that counts neither
a best residual creeping down by < 10 % nor the jitter of a measure already within tol.  Discrete
trajectory, paper set, σ = 0.1, seed 0: the block program (``clique_program`` on the IPM's cover,
unscaled data) is built once per K by this checkout and saved; each side then solves it with its own
``schur_ipm.solve_blocks`` in a fresh process, interleaved (before, after, before, …) so that the load of
this shared machine falls on both alike.  Reported per K: status, iterations, the final relative
residuals, the solve time (median over repeats) and the ratio after / before.

    git worktree add --detach /tmp/autotight-before 512a18f
    python benchmarks/ipm_stopping.py --before /tmp/autotight-before [--sizes 100,300,1000] [--repeats 2]

Prints and writes benchmarks/results/ipm_stopping.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

SOLVE = """
import json, sys, time
import numpy as np, scipy.sparse as sp
from autotight.sdp import schur_ipm
d = np.load(sys.argv[1])
F = sp.csc_matrix((d["data"], d["indices"], d["indptr"]), shape=tuple(d["shape"]))
t = time.perf_counter()
s = schur_ipm.solve_blocks(F, d["c"], d["g"], [int(n) for n in d["sizes"]], tol=1e-7)
print(json.dumps({"module": schur_ipm.__file__, "status": s.status, "iterations": s.iterations,
                  "time_s": time.perf_counter() - t, "gap": s.gap, "pinf": s.pinf, "dinf": s.dinf,
                  "pobj": s.pobj, "message": s.message}))
"""


def build(K: int, path: Path) -> dict:
    """The block program of discrete trajectory K (paper set, σ = 0.1, seed 0) on the IPM's cover."""
    import scipy.sparse as sp

    from autotight.problem import load
    from autotight.sdp.clique_program import clique_program
    from autotight.sdp.covers import CliqueCovers

    prob = load("discrete_trajectory")
    model = prob.build(prob.generate(prob.parse_params({"K": K}), np.random.default_rng(0)))
    cons = model.primary() + model.paper_constraints()
    V = model.variables
    Q, As = sp.csr_array(model.Q), [sp.csr_array(c.A) for c in cons]
    cover = CliqueCovers(Q, As, model.d, [V.sizes[n] for n in V.names], model.clique_indices()).choose("ipm")
    prog = clique_program(Q, As, np.array([c.b for c in cons]), cover)
    F = sp.csc_matrix(prog.F)
    np.savez(path, data=F.data, indices=F.indices, indptr=F.indptr, shape=np.array(F.shape), c=prog.c, g=prog.g,
             sizes=np.array(prog.sizes))
    return {"N": int(Q.shape[0]), "constraints": len(cons), "rows": int(F.shape[1]), "blocks": len(prog.sizes)}


def run(src: Path, prog: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    # cwd = src: `python -c` puts the working directory first on sys.path
    out = subprocess.run([sys.executable, "-c", SOLVE, str(prog)], env=env, cwd=src, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="a checkout of the commit before the change")
    ap.add_argument("--sizes", default="100,300,1000")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    sizes = [int(k) for k in args.sizes.split(",")]
    sides = {"before": Path(args.before).resolve(), "after": ROOT}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for K in sizes:
            path = Path(tmp) / f"K{K}.npz"
            info = build(K, path)
            runs: dict[str, list[dict]] = {s: [] for s in sides}
            for _ in range(args.repeats):
                for side, src in sides.items():
                    runs[side].append(run(src, path))
            row = {"K": K, **info}
            for side, rs in runs.items():
                row[side] = {**rs[0], "time_s": float(np.median([r["time_s"] for r in rs])),
                             "times_s": [r["time_s"] for r in rs]}
            row["time_ratio_after_before"] = row["after"]["time_s"] / row["before"]["time_s"]
            rows.append(row)
            b, a = row["before"], row["after"]
            print(f"K = {K}: before {b['status']} {b['iterations']} it {b['time_s']:.1f} s (pinf {b['pinf']:.1e}); "
                  f"after {a['status']} {a['iterations']} it {a['time_s']:.1f} s (pinf {a['pinf']:.1e}); "
                  f"ratio {row['time_ratio_after_before']:.2f}", flush=True)
    res = {"benchmark": "ipm_stopping", "problem": "discrete_trajectory", "set": "paper", "sigma": 0.1, "seed": 0,
           "compared_against": "the IPM before the change (--before checkout), same block programs, interleaved",
           "repeats": args.repeats, "rows": rows, "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg()),
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "command": f"python benchmarks/ipm_stopping.py --before {args.before} --sizes {args.sizes} "
                      f"--repeats {args.repeats}"}
    out = ROOT / "benchmarks" / "results" / "ipm_stopping.json"
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
