"""Our IPM's iterations with the compiled per-block kernels against the base commit's, on the same SDP.

The change (``autotight/sdp/schur_kernel.py``, used by ``schur_ipm`` from ``COMPILED_MIN_BLOCKS`` blocks
on): the Schur complement's assembly, the step length, and the band's scaling and full storage by numba
kernels instead of a numpy loop over the blocks.  The SDP is the one that
``autotight solve discrete_trajectory -p K=1000 --set benchmarks/results/scale_set_discrete_K5.json
--solver ipm`` hands to ``schur_ipm.solve_blocks`` (captured from that call in this process: the
pipeline up to the SDP, then stopped), saved once.  Each side then solves it in a fresh process with one
BLAS thread, interleaved (base, new, base, new, …) so that the load of this shared machine falls on both
alike: "base" imports ``schur_ipm.py`` of the base commit (``git show BASE:…`` written to a temporary
file and loaded as a module of this checkout's ``autotight.sdp``), "new" this checkout's.  The new
side's processes find numba's compiled kernels in its cache (``NUMBA_CACHE_DIR``, filled by a first run
that is reported separately as ``cold``: the compilation a fresh install pays once).

Reported: per side the status, iterations, costs and residuals (of the first run: the runs are
deterministic), the solve times (median, all), the time per iteration, and the ratio new / base; the
differences of the costs.

    python benchmarks/ipm_iteration.py [--K 1000] [--base be1acad] [--repeats 2] [--search nt]

Prints and writes benchmarks/results/ipm_iteration.json.
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
SET = ROOT / "benchmarks" / "results" / "scale_set_discrete_K5.json"

SOLVE = """
import importlib.util, json, sys, time
t0 = time.perf_counter()
import numpy as np, scipy.sparse as sp
import autotight.sdp
base = sys.argv[2]
if base:
    spec = importlib.util.spec_from_file_location("autotight.sdp._schur_ipm_base", base)
    schur_ipm = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = schur_ipm
    spec.loader.exec_module(schur_ipm)
else:
    from autotight.sdp import schur_ipm
d = np.load(sys.argv[1])
F = sp.csc_matrix((d["data"], d["indices"], d["indptr"]), shape=tuple(d["shape"]))
t1 = time.perf_counter()
s = schur_ipm.solve_blocks(F, d["c"], d["g"], [int(n) for n in d["sizes"]], tol=float(d["tol"]),
                           max_iter=int(d["max_iter"]), search=sys.argv[3])
t2 = time.perf_counter()
print(json.dumps({"module": schur_ipm.__file__, "status": s.status, "iterations": s.iterations,
                  "solve_s": t2 - t1, "process_s": t2 - t0, "gap": s.gap, "pinf": s.pinf, "dinf": s.dinf,
                  "pobj": s.pobj, "dobj": s.dobj, "message": s.message}))
"""


class _Captured(Exception):
    """Raised by the stand-in of ``solve_blocks`` once it has saved its arguments."""


def build(K: int, set_path: Path, seed: int, path: Path) -> dict:
    """Save the block SDP that ``autotight solve discrete_trajectory -p K=K --set set_path --solver ipm``
    (seed ``seed``) passes to ``schur_ipm.solve_blocks``; the pipeline stops there."""
    import scipy.sparse as sp

    import autotight as at
    from autotight.constraint_set import ConstraintSet
    from autotight.sdp import schur_ipm

    def capture(F, c, g, sizes, **kw):
        F = sp.csc_matrix(F)
        np.savez(path, data=F.data, indices=F.indices, indptr=F.indptr, shape=np.array(F.shape), c=c, g=g,
                 sizes=np.array(sizes), tol=kw["tol"], max_iter=kw["max_iter"])
        raise _Captured

    real = schur_ipm.solve_blocks
    schur_ipm.solve_blocks = capture
    try:
        at.solve("discrete_trajectory", {"K": K}, seed, constraints=ConstraintSet.load(str(set_path)),
                 solver=at.SolverConfig(backend="ipm"))
    except _Captured:
        pass
    finally:
        schur_ipm.solve_blocks = real
    if not path.exists():
        raise SystemExit("the pipeline did not reach the IPM")
    d = np.load(path)
    return {"rows": int(d["shape"][1]), "blocks": int(d["sizes"].size), "block_sizes": sorted(set(d["sizes"].tolist())),
            "svec_length": int(d["shape"][0]), "tol": float(d["tol"])}


def run(prog: Path, base_module: str, search: str, cache: str) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
    out = subprocess.run(["nice", "-n", "10", sys.executable, "-c", SOLVE, str(prog), base_module, search], env=env,
                         cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(rs: list[dict]) -> dict:
    times = [r["solve_s"] for r in rs]
    first = rs[0]
    return {**{k: first[k] for k in ("status", "iterations", "pobj", "dobj", "gap", "pinf", "dinf", "message")},
            "solve_s": float(np.median(times)), "solve_times_s": times,
            "per_iteration_s": float(np.median(times)) / max(first["iterations"], 1),
            "process_times_s": [r["process_s"] for r in rs],
            "identical_runs": all((r["pobj"], r["iterations"]) == (first["pobj"], first["iterations"]) for r in rs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--K", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--base", default="be1acad", help="the commit whose schur_ipm.py is the base")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--search", default="nt", choices=["nt", "hkm"])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base_src = Path(tmp) / "schur_ipm_base.py"
        base_src.write_text(subprocess.run(["git", "show", f"{args.base}:autotight/sdp/schur_ipm.py"], cwd=ROOT,
                                           capture_output=True, text=True, check=True).stdout)
        prog = Path(tmp) / "sdp.npz"
        t = time.perf_counter()
        info = build(args.K, SET, args.seed, prog)
        print(f"K = {args.K}: {info['blocks']} blocks, {info['rows']} rows (built in {time.perf_counter() - t:.1f} s)",
              flush=True)
        cache = str(Path(tmp) / "numba_cache")
        cold = run(prog, "", args.search, cache)  # compiles the kernels into the empty cache
        print(f"new, cold cache: {cold['status']} {cold['iterations']} it, {cold['solve_s']:.1f} s", flush=True)
        runs: dict[str, list[dict]] = {"base": [], "new": []}
        for _ in range(args.repeats):
            for side in runs:
                r = run(prog, str(base_src) if side == "base" else "", args.search, cache)
                runs[side].append(r)
                print(f"{side}: {r['status']} {r['iterations']} it, pobj {r['pobj']:.12g}, {r['solve_s']:.1f} s",
                      flush=True)
    base, new = summary(runs["base"]), summary(runs["new"])
    scale = max(abs(base["pobj"]), abs(base["dobj"]), 1e-300)
    res = {"benchmark": "ipm_iteration", "problem": "discrete_trajectory", "K": args.K, "seed": args.seed,
           "set": SET.name, "search": args.search, "base_commit": args.base, **info,
           "base": base, "new": new, "new_cold_cache": {k: cold[k] for k in ("status", "iterations", "solve_s",
                                                                              "process_s", "pobj")},
           "ratio_new_base": new["solve_s"] / base["solve_s"],
           "ratio_per_iteration_new_base": new["per_iteration_s"] / base["per_iteration_s"],
           "pobj_rel_diff": abs(new["pobj"] - base["pobj"]) / scale,
           "dobj_rel_diff": abs(new["dobj"] - base["dobj"]) / scale,
           "repeats": args.repeats, "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg()),
           "date": time.strftime("%Y-%m-%d %H:%M"),
           "command": f"python benchmarks/ipm_iteration.py --K {args.K} --seed {args.seed} --base {args.base} "
                      f"--repeats {args.repeats} --search {args.search}"}
    import numba

    from autotight.io import versions

    res["versions"] = {**versions(), "numba": numba.__version__}
    print(f"solve: base {base['solve_s']:.1f} s ({base['iterations']} it), new {new['solve_s']:.1f} s "
          f"({new['iterations']} it): ratio {res['ratio_new_base']:.2f}, per iteration "
          f"{res['ratio_per_iteration_new_base']:.2f}; pobj rel diff {res['pobj_rel_diff']:.1e}, "
          f"dobj {res['dobj_rel_diff']:.1e}")
    name = "ipm_iteration.json" if args.search == "nt" else f"ipm_iteration_{args.search}.json"
    out = ROOT / "benchmarks" / "results" / name
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
