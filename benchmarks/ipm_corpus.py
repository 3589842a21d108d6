"""Our IPM before and after a change, on the block programs of the shipped problems, in the same run.

The corpus: rotation, pose averaging and discrete trajectory at their defaults with σ ∈ {0.1, 1, 0.001, 0},
continuous trajectory at σ = 0.1 and 0.001, robust pose averaging, anisotropic rotation averaging,
discrete trajectory K = 100 and 300 and pose averaging M = 100 with the sets learned at K = 5 and M = 5,
seeds 0 and 1, and discrete trajectory K = 1000 on seeds 0–2 (``--large``: also pose averaging M = 1000).
For each, the block program that ``autotight solve … --solver ipm`` hands the IPM first (the scaled
frame, the IPM's cover) is captured by this checkout and saved; each side then solves it with its own
``schur_ipm.solve_blocks`` (and its retry of a stalled solve, ``IPMBackend.retries``, where it has one:
the time then includes both solves) in a fresh process, interleaved (before, after) so that the load of this
shared machine falls on both alike.  Reported per program and in total: status, iterations, the final
relative residuals, the objective, the solve time and the ratio after / before.

    git worktree add --detach /tmp/autotight-before <commit>
    python benchmarks/ipm_corpus.py --before /tmp/autotight-before [--large] [--only SUBSTRING]

Prints and writes benchmarks/results/ipm_corpus.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SET_D = str(ROOT / "benchmarks" / "results" / "scale_set_discrete_K5.json")
SET_P = str(ROOT / "benchmarks" / "results" / "scale_set_pose_M5.json")

SOLVE = """
import json, sys, time
import numpy as np, scipy.sparse as sp
from autotight.sdp import schur_ipm
d = np.load(sys.argv[1])
F = sp.csc_matrix((d["data"], d["indices"], d["indptr"]), shape=tuple(d["shape"]))
t = time.perf_counter()
args = (F, d["c"], d["g"], [int(n) for n in d["sizes"]])
s = schur_ipm.solve_blocks(*args, tol=float(d["tol"]), max_iter=int(d["max_iter"]))
retried = False
if s.status in getattr(schur_ipm, "RETRY_STATUSES", ()):  # IPMBackend.retries, as the SDP layer applies it
    r = schur_ipm.solve_blocks(*args, tol=float(d["tol"]), max_iter=int(d["max_iter"]),
                               step_fraction=schur_ipm.RETRY_STEP_FRACTION)
    retried = True
    if r.status == "Solved" or s.status not in ("Solved", "AlmostSolved"):
        s = r
print(json.dumps({"module": schur_ipm.__file__, "status": s.status, "iterations": s.iterations, "retried": retried,
                  "time_s": time.perf_counter() - t, "gap": s.gap, "pinf": s.pinf, "dinf": s.dinf,
                  "pobj": s.pobj, "dobj": s.dobj, "message": s.message}))
"""


def cases(large: bool) -> list[list[str]]:
    """``autotight solve`` arguments of the corpus (module docstring)."""
    out = []
    for seed in ("0", "1"):
        for s in ("0.1", "1", "0.001", "0"):
            out += [[p, "-p", f"sigma={s}", "--seed", seed]
                    for p in ("rotation_averaging", "pose_averaging", "discrete_trajectory")]
        out += [["continuous_trajectory", "--seed", seed],
                ["continuous_trajectory", "-p", "sigma=0.001", "--seed", seed],
                ["robust_pose_averaging", "--seed", seed],
                ["rotation_averaging", "-p", "anisotropy=100", "--seed", seed]]
        out += [["discrete_trajectory", "-p", f"K={K}", "-p", f"sigma={s}", "--set", SET_D, "--seed", seed]
                for K in (100, 300) for s in ("0.1", "0.001", "1")]
        out.append(["pose_averaging", "-p", "M=100", "--set", SET_P, "--seed", seed])
    out += [["discrete_trajectory", "-p", "K=1000", "--set", SET_D, "--seed", seed] for seed in ("0", "1", "2")]
    if large:
        out.append(["pose_averaging", "-p", "M=1000", "--set", SET_P, "--seed", "0"])
    return out


class _Captured(Exception):
    pass


def capture(args: list[str], path: Path) -> None:
    """Save the first block program that ``autotight solve ARGS --solver ipm`` gives the IPM."""
    import scipy.sparse as sp

    from autotight.cli.main import main
    from autotight.sdp import schur_ipm

    solve = schur_ipm.solve_blocks

    def save(F, c, g, sizes, *, tol=1e-7, max_iter=100, **_):
        F = sp.csc_matrix(F)
        np.savez(path, data=F.data, indices=F.indices, indptr=F.indptr, shape=np.array(F.shape), c=c, g=g,
                 sizes=np.array(sizes), tol=tol, max_iter=max_iter)
        raise _Captured

    schur_ipm.solve_blocks = save
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            main(["solve", *args, "--solver", "ipm"])
    except _Captured:
        pass
    finally:
        schur_ipm.solve_blocks = solve
    if not path.exists():
        raise RuntimeError(f"no block program reached the IPM for: {' '.join(args)}")


def run(src: Path, prog: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    # cwd = src: `python -c` puts the working directory first on sys.path
    out = subprocess.run([sys.executable, "-c", SOLVE, str(prog)], env=env, cwd=src, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(rows: list[dict], side: str) -> dict:
    status = collections.Counter(r[side]["status"] for r in rows)
    return {"status": dict(status), "iterations": sum(r[side]["iterations"] for r in rows),
            "time_s": sum(r[side]["time_s"] for r in rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="a checkout of the commit before the change")
    ap.add_argument("--large", action="store_true", help="also pose averaging M = 1000")
    ap.add_argument("--only", default=None, help="only the cases whose arguments contain this text")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ipm_corpus.json"),
                    help="the JSON file written (default benchmarks/results/ipm_corpus.json)")
    args = ap.parse_args()
    sides = {"before": Path(args.before).resolve(), "after": ROOT}
    rows = []
    todo = [c for c in cases(args.large) if args.only is None or args.only in " ".join(c)]
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(todo):
            path = Path(tmp) / f"case{i}.npz"
            capture(case, path)
            row: dict = {"case": " ".join(case).replace(str(ROOT) + "/", "")}
            for side, src in sides.items():
                row[side] = run(src, path)
            b, a = row["before"], row["after"]
            row["time_ratio_after_before"] = a["time_s"] / b["time_s"]
            row["pobj_rel_diff"] = abs(a["pobj"] - b["pobj"]) / max(abs(b["pobj"]), 1e-12)
            rows.append(row)
            print(f"{row['case']}: before {b['status']} {b['iterations']} it {b['time_s']:.2f} s gap {b['gap']:.1e}; "
                  f"after {a['status']} {a['iterations']} it {a['time_s']:.2f} s gap {a['gap']:.1e}", flush=True)
    total = {side: summary(rows, side) for side in sides}
    total["time_ratio_after_before"] = total["after"]["time_s"] / total["before"]["time_s"]
    print(f"before: {total['before']}\nafter: {total['after']}\ntime ratio {total['time_ratio_after_before']:.2f}")
    res = {"benchmark": "ipm_corpus",
           "compared_against": "the IPM before the change (--before checkout), same block programs, interleaved",
           "rows": rows, "total": total, "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg()),
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "command": "python benchmarks/ipm_corpus.py --before BEFORE" + (" --large" if args.large else "")
                      + (f" --only {args.only}" if args.only else "")
                      + (f" --out {args.out}" if Path(args.out).name != "ipm_corpus.json" else "")}
    out = Path(args.out)
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
