"""Benchmark: certifying a local solution (``autotight.certify``) against solving the full SDP.

Per instance (same run, interleaved: certify first on even instances, the SDPs first on odd ones):
- the local solution x̂: ``problem.local_solve`` from the ground truth (not timed);
- ``certify``: ``certify_model(model, constraints, lift(x̂), tol/floor of Criteria())``, time of the
  whole call (clique cover, clique program, the barrier method of ``autotight.certify``, polish,
  sparse certified λ_min, trace bound);
- ``sdp``: ``sdp.solve_model`` with the default backend (Clarabel, its chordal decomposition), wall time
  of the whole call, judged by ``tightness.judge`` with the data (the verdict certify must agree with);
- ``sdp_ipm``: ``sdp.solve_model with SolverConfig(backend="ipm")`` (our clique IPM, the fastest full solve we have),
wall.
Settings: pose averaging M = 10 with the paper set and with the primary set only (not tight: the
negative case), discrete K = 20 and K = 100 with the paper set.  Verdicts agree when (certified) == (the full SDP's
verdict is "tight"), for both full solves.  Target:
certify ≤ 1/5 of the full SDP's time at discrete K = 20 and K = 100.  The machine is
shared, so ratios are reported on CPU time (process time; every solve is single-threaded) as well as
on wall time, with the load average before and after each instance.

Scale (``--set FILE --ks 100,1000,…``): discrete trajectory at each K with a saved set (e.g. the one
learned at K = 5, benchmarks/results/scale_set_discrete_K5.json), certify against our clique IPM only
(Clarabel's decomposition is the slow path there: > 12 CPU-minutes and 7.6 GB at K = 1000), seeds
0 … --seeds-scale − 1; the peak RSS of the process is recorded after each instance.

Whole commands (generate, build, constraints, local solve included) per size in fresh processes, up to
K = 10 000: benchmarks/certify_scale.py.

Usage:  python benchmarks/certify.py [--seeds 5] [--seeds-k100 2] [--out benchmarks/results/certify.json]
        python benchmarks/certify.py --set benchmarks/results/scale_set_discrete_K5.json --ks 100,1000
            --seeds-scale 1 --out benchmarks/results/certify_scale_inprocess.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import time
from pathlib import Path

import clarabel
import numpy as np
import scipy

from autotight.certifier import certify_model
from autotight.problem import load
from autotight.constraint_set import named as constraint_set
from autotight.sdp import SolverConfig, solve_model
from autotight.tightness import Criteria, judge


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def one(problem: str, params: dict, seed: int, certify_first: bool, set_name: str = "paper",
        clarabel: bool = True) -> dict:
    """One instance, certify and the full SDPs in the order ``certify_first`` says; set_name: "paper",
    "primary" or a saved set's path; clarabel: also time the default backend (else IPM only)."""
    p = load(problem)
    inst = p.generate(params, seed=seed)
    model = p.build(inst)
    if set_name in ("paper", "primary"):
        cons = constraint_set(model, set_name)
    else:
        from autotight.constraint_set import ConstraintSet, resolve
        from autotight.pipeline import seeds

        cons = resolve(ConstraintSet.load(set_name), p, inst, model, seeds(seed).constraints())
    loc = p.local_solve(inst, inst.truth)
    x = p.lift(inst, loc.state)
    runs = {}

    def do_certify():
        crit = Criteria()
        runs["certify"] = timed(lambda: certify_model(model, cons, x, tol=crit.gap_tol,
                                                      floor=crit.cost_atol / crit.gap_tol))

    def do_sdp():
        runs["sdp_ipm"] = timed(lambda: solve_model(model, cons, SolverConfig(backend="ipm")))
        runs["sdp"] = timed(lambda: solve_model(model, cons)) if clarabel else runs["sdp_ipm"]

    load_before = os.getloadavg()[0]
    for f in ((do_certify, do_sdp) if certify_first else (do_sdp, do_certify)):
        f()
    cert, tc, cc = runs["certify"]
    res, ts, cs = runs["sdp"]
    res_ipm, ti, ci = runs["sdp_ipm"]
    v = judge(res, loc.cost, Criteria(), Q=model.Q, constraints=cons)
    v_ipm = judge(res_ipm, loc.cost, Criteria(), Q=model.Q, constraints=cons)
    return {"problem": problem, "params": params, "constraint_set": set_name, "seed": seed, "N": model.variables.N,
            "m": len(cons),
            "local_cost": loc.cost, "certified": cert.certified, "certify_bound": cert.bound,
            "certify_rel_bound": cert.rel_bound, "certify_lambda_min": cert.lambda_min, "certify_method": cert.method,
            "certify_wall_s": tc, "certify_cpu_s": cc,
            "sdp_status": res.status, "sdp_verdict": v.outcome, "sdp_log_svr": res.log_svr, "sdp_wall_s": ts,
            "sdp_cpu_s": cs, "sdp_ipm_status": res_ipm.status, "sdp_ipm_verdict": v_ipm.outcome, "sdp_ipm_wall_s": ti,
            "sdp_ipm_cpu_s": ci, "agree": cert.certified == (v.outcome == "tight") == (v_ipm.outcome == "tight"),
            "ratio_wall": tc / ts, "ratio_wall_ipm": tc / ti, "ratio_cpu": cc / cs, "ratio_cpu_ipm": cc / ci,
            "certify_first": certify_first, "load_before": load_before, "load_after": os.getloadavg()[0],
            "certify_argument": cert.argument, "sdp_backends": "clarabel and ipm" if clarabel else "ipm only",
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="instances per setting (pose averaging, K = 20)")
    ap.add_argument("--seeds-k100", type=int, default=2, help="instances at K = 100")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "certify.json"))
    ap.add_argument("--set", default=None, help="a saved set for discrete trajectory at --ks (scale mode)")
    ap.add_argument("--ks", default="", help="comma-separated K of the scale mode (with --set)")
    ap.add_argument("--seeds-scale", type=int, default=1, help="instances per K in the scale mode")
    args = ap.parse_args()
    if args.set:
        settings = [("discrete_trajectory", {"K": int(k)}, args.seeds_scale, args.set) for k in args.ks.split(",") if k]
    else:
        settings = [("pose_averaging", {"M": 10}, args.seeds, "paper"),
                    ("pose_averaging", {"M": 10}, args.seeds, "primary"),
                    ("discrete_trajectory", {"K": 20}, args.seeds, "paper"),
                    ("discrete_trajectory", {"K": 100}, args.seeds_k100, "paper")]
    rows, i = [], 0
    load_start = os.getloadavg()
    for problem, params, n, set_name in settings:
        for seed in range(n):
            r = one(problem, params, seed, certify_first=i % 2 == 0, set_name=set_name, clarabel=not args.set)
            i += 1
            rows.append(r)
            print(f"{problem} {params} {set_name} seed {seed}: "
                  f"certify cpu {r['certify_cpu_s']:.2f} s ({r['certified']}, "
                  f"bound {r['certify_rel_bound']:.1e}) | SDP {r['sdp_cpu_s']:.2f} s ({r['sdp_verdict']}) "
                  f"| IPM {r['sdp_ipm_cpu_s']:.2f} s ({r['sdp_ipm_verdict']}) | cpu ratio {r['ratio_cpu']:.3f} "
                  f"(vs IPM {r['ratio_cpu_ipm']:.3f}) wall ratio {r['ratio_wall']:.3f} agree={r['agree']} "
                  f"load {r['load_before']:.1f}", flush=True)
    summary = {}
    for problem, params, _, set_name in settings:
        sel = [r for r in rows if r["problem"] == problem and r["params"] == params and r["constraint_set"] == set_name]
        key = f"{problem} {json.dumps(params)} {set_name}"
        summary[key] = {"n": len(sel), "all_agree": all(r["agree"] for r in sel),
                        "certified": sum(r["certified"] for r in sel),
                        "median_certify_s": statistics.median(r["certify_wall_s"] for r in sel),
                        "median_sdp_s": statistics.median(r["sdp_wall_s"] for r in sel),
                        "median_sdp_ipm_s": statistics.median(r["sdp_ipm_wall_s"] for r in sel),
                        "median_ratio": statistics.median(r["ratio_wall"] for r in sel),
                        "median_ratio_vs_ipm": statistics.median(r["ratio_wall_ipm"] for r in sel),
                        "median_certify_cpu_s": statistics.median(r["certify_cpu_s"] for r in sel),
                        "median_sdp_cpu_s": statistics.median(r["sdp_cpu_s"] for r in sel),
                        "median_sdp_ipm_cpu_s": statistics.median(r["sdp_ipm_cpu_s"] for r in sel),
                        "median_ratio_cpu": statistics.median(r["ratio_cpu"] for r in sel),
                        "max_ratio_cpu": max(r["ratio_cpu"] for r in sel),
                        "median_ratio_cpu_vs_ipm": statistics.median(r["ratio_cpu_ipm"] for r in sel)}
        print(key, summary[key])
    out = {"benchmark": "certify vs full SDP",
           "target": ("certify ≤ 1/10 of the full SDP's (IPM) time at K = 1000, certified at K = 10 000 in ≤ 60 s"
                      if args.set else "certify time ≤ 1/5 of the full SDP's at discrete K = 20 and K = 100, "
                                       "same verdict on every instance"),
           "command": "python benchmarks/certify.py " + " ".join(
               f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if v not in (None, "")),
           "method": "autotight.certify: phase-I barrier Newton on the clique blocks (see its docstring)",
           "compared_against": {"sdp": "sdp.solve_model default (Clarabel, chordal decomposition), "
                                       "judged by tightness.judge",
                                "sdp_ipm": "sdp.solve_model with SolverConfig(backend='ipm')"},
           "constraint_sets": "paper (tight) and, at pose averaging, primary (not tight: both must say so)",
           "local_solution": "local_solve from the ground truth", "seeds": "0 … n−1",
           "summary": summary, "rows": rows,
           "versions": {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
                        "clarabel": getattr(clarabel, "__version__", "?")},
           "machine": {"cpus": os.cpu_count(), "load_avg_start": load_start, "load_avg_end": os.getloadavg()}}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1, default=float))
    print("wrote", args.out)


if __name__ == "__main__":
    main()
