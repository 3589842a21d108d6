"""Carried constraint sets at scale: a set learned at size 5 applied at sizes 10 … 1000.

Problems: discrete trajectory (size K, the default) and pose averaging (size M, ``--problem
pose_averaging``).  Every (size, route, seed) runs in a fresh subprocess (so that its peak RSS is
its own) and reports build, apply, SDP and total wall time, peak RSS (``resource.getrusage``, max
resident set), SDP status, log SVR and the verdict.  Routes: "template" (the set's templates
evaluated: ``ConstraintSet.apply``) and "relearn" (the pairs re-learned on every factor:
``DiscoveredSet.instantiate``, today's route before templates), the
latter at sizes ≤ 100.  Growth exponents are log(v(1000)/v(100))/log(10) for the template route (first
seed).  The SDP uses our IPM (``--solver ipm``); local search: from the ground truth only (n_random = 0).

    nice -n 19 python benchmarks/scale.py [--problem discrete_trajectory|pose_averaging] [--set FILE]
        [--sizes 10,30,100,300,1000] [--relearn 10,30,100] [--paper 100,300,1000] [--seeds 0]
        [--seeds-at 1000] [--retemplate PATH]
    nice -n 19 python benchmarks/scale.py --versus OLD_CHECKOUT [--problem …] [--sizes 100,1000,10000]
        [--new-only 10000] [--solver ipm|default] [--out FILE]

--versus: this checkout against another (e.g. a worktree of the commit before, with its own .venv): every
size solved by both, interleaved, each in a fresh process through ``autotight.solve`` (what ``autotight
solve -p SIZE=… --set FILE`` runs, one random local start), with per-stage times (``SolveResult.times``),
peak RSS, the outcome, the SDP cost and the load average; the summary holds the growth exponents between
consecutive sizes, the ratios new/old and the relative difference of the SDP costs.

--seeds: the instance seeds of every run; --seeds-at: sizes that run with every seed (the others with the
first; with --versus and no --seeds-at, every size runs every seed). Without --set the problem's default file
is used, and discovered at size 5, seed 0, when it is missing (another missing --set file is an error). --set
takes any set file of the problem (e.g. reports/sets/discrete_trajectory_range.json, saved without a template
for its factor type, so its "template" route re-learns every factor; ``--retemplate PATH`` learns its
templates again first, transport templates included), and the JSON records where it was learned
(``learned_at``). Writes benchmarks/results/scale.json (pose averaging: scale_pose_averaging.json) with the
versions and the load average around every run. """

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SIZE = {"discrete_trajectory": "K", "pose_averaging": "M"}  # each problem's size parameter
SETS = {"discrete_trajectory": HERE / "results" / "scale_set_discrete_K5.json",
        "pose_averaging": HERE / "results" / "scale_set_pose_M5.json"}
OUTS = {"discrete_trajectory": HERE / "results" / "scale.json",
        "pose_averaging": HERE / "results" / "scale_pose_averaging.json"}


def one(problem: str, K: int, route: str, set_path: str, seed: int) -> dict:
    """One run in this process (called in a fresh subprocess)."""
    import numpy as np

    from autotight.constraint_set import ConstraintSet
    from autotight.pipeline import solve_instance
    from autotight.problem import load
    from autotight.sdp.config import SolverConfig

    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    prob = load(problem)
    cs = ConstraintSet.load(set_path)
    inst = prob.generate(prob.parse_params({SIZE[problem]: K}), np.random.default_rng(seed))
    inst.seed = seed
    t1 = time.perf_counter()
    model = prob.build(inst)
    t2 = time.perf_counter()
    rng = np.random.default_rng([seed, 2])
    if route == "template":
        cons = cs.apply(prob, inst, model, rng)
    elif route == "paper":  # the hand-derived families: the same pipeline on a relaxation that is tight
        cons = model.paper_constraints()
    else:
        cons = cs.discovered.instantiate(prob, inst, rng, model=model)
    t3 = time.perf_counter()
    out = solve_instance(prob, inst, cons, config=SolverConfig(backend="ipm"), model=model, n_random=0)
    t4 = time.perf_counter()
    return {"K": K, "route": route, "seed": seed, "N": model.variables.N, "n_constraints": out.n_constraints,
            "n_set_constraints": len(cons), "generate_s": t1 - t0, "build_s": t2 - t1, "apply_s": t3 - t2,
            "sdp_s": out.times["sdp_total_s"], "sdp_solve_s": out.times["sdp_solve_s"],
            "apply_over_sdp": (t3 - t2) / out.times["sdp_total_s"],
            "local_s": out.times["local_s"], "refine_s": out.times["refine_s"], "total_s": t4 - t0,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "import_rss_mb": rss0 / 1024, "status": out.sdp.status, "log_svr": out.log_svr,
            "outcome": out.outcome, "tight": out.tight, "verdict": out.verdict.reason}


def run_child(problem: str, K: int, route: str, set_path: str, seed: int, timeout: float) -> dict:
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    try:
        p = subprocess.run([sys.executable, __file__, "--problem", problem, "--one", str(K), "--route", route,
                            "--set", set_path, "--seeds", str(seed)], capture_output=True, text=True, env=env,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"K": K, "route": route, "seed": seed, "error": f"timeout after {timeout:g} s"}
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        rec = {"K": K, "route": route, "seed": seed, "error": child_error(p)}
    else:
        rec = json.loads(p.stdout.strip().splitlines()[-1])
    return rec | {"process_wall_s": wall, "loadavg_before": load0, "loadavg_after": os.getloadavg()}


def child_error(p: subprocess.CompletedProcess) -> str:
    """The last line of a failed child's stderr, or the signal that ended it (SIGKILL: most likely the kernel's
    out-of-memory killer, which leaves no message)."""
    if p.returncode < 0:
        sig = signal.Signals(-p.returncode).name
        return f"killed by {sig}" + (" (out of memory?)" if sig == "SIGKILL" else "")
    return (p.stderr.strip().splitlines() or [f"exit code {p.returncode}, no message"])[-1]


def exponent(rows: list[dict], key: str, a: int = 100, b: int = 1000) -> float | None:
    import math

    va = next((r.get(key) for r in rows if r["K"] == a and key in r), None)  # "K": the size, for any problem
    vb = next((r.get(key) for r in rows if r["K"] == b and key in r), None)
    if not va or not vb:
        return None
    return math.log(vb / va) / math.log(b / a)


def ensure_set(problem: str, path: Path) -> None:
    """Discover the problem's default set at size 5 when its file is missing; another missing file is an
    error (it would be filled with a set other than its name says)."""
    if path.exists():
        return
    if path.resolve() != SETS[problem].resolve():
        raise SystemExit(f"no set file at {path}")
    autotight("discover", problem, "-p", f"{SIZE[problem]}=5", "--no-progress", "--out", str(path), quiet=True)


def autotight(*args: str, quiet: bool = False) -> None:
    """Run the CLI of this checkout in a subprocess (raises when it fails)."""
    subprocess.run([sys.executable, "-m", "autotight.cli", *args], check=True,
                   env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.DEVNULL if quiet else None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="discrete_trajectory", choices=sorted(SIZE))
    ap.add_argument("--set", default=None, help="default: the problem's file in benchmarks/results/")
    ap.add_argument("--sizes", default="10,30,100,300,1000")
    ap.add_argument("--relearn", default="10,30,100")
    ap.add_argument("--paper", default="", help="sizes also run with the paper families (a tight relaxation)")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--seeds-at", default="", help="sizes that run with every seed (the others: the first)")
    ap.add_argument("--retemplate", default=None, metavar="PATH",
                    help="first learn the set's templates again into PATH (`autotight templates SET --out PATH`: "
                         "e.g. transport templates for a set saved without them) and run with that file")
    ap.add_argument("--timeout", type=float, default=1800.0)
    ap.add_argument("--out", default=None, help="default: benchmarks/results/scale.json (discrete), "
                                                "scale_pose_averaging.json (pose)")
    ap.add_argument("--versus", default=None, metavar="DIR",
                    help="compare with the checkout at DIR (its .venv's python): every size and seed solved by both, "
                         "interleaved, each in a fresh process, through `autotight solve`'s API (n_random 1)")
    ap.add_argument("--solver", default="ipm", help="with --versus: the backend of both ('default': each one's own)")
    ap.add_argument("--new-only", default="", help="with --versus: sizes run by this checkout only")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--route", default="template", help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.set = args.set or str(SETS[args.problem])
    args.out = args.out or str(OUTS[args.problem])
    seeds = [int(s) for s in args.seeds.split(",") if s]
    if args.one is not None:
        print(json.dumps(one(args.problem, args.one, args.route, args.set, seeds[0])))
        return
    if args.versus:
        versus(args)
        return
    ensure_set(args.problem, Path(args.set))
    if args.retemplate:
        autotight("templates", args.set, "--out", args.retemplate, "--force")
        args.set = args.retemplate
    rows = []
    every = {int(k) for k in args.seeds_at.split(",") if k}
    jobs = [(int(k), route, s) for route, sizes in (("template", args.sizes), ("relearn", args.relearn),
                                                    ("paper", args.paper))
            for k in sizes.split(",") if k for s in (seeds if int(k) in every else seeds[:1])]
    print(f"{SIZE[args.problem]:>5} {'route':>8} {'seed':>4} {'build':>7} {'apply':>8} {'SDP':>8} {'total':>8} "
          f"{'RSS MB':>7} {'status':>12} {'logSVR':>7} {'outcome':>10}  load")
    for K, route, seed in jobs:
        r = run_child(args.problem, K, route, args.set, seed, args.timeout)
        rows.append(r)
        if "error" in r:
            print(f"{K:>5} {route:>8} {seed:>4}  error: {r['error']}")
        else:
            print(f"{K:>5} {route:>8} {seed:>4} {r['build_s']:7.2f} {r['apply_s']:8.3f} {r['sdp_s']:8.2f} "
                  f"{r['total_s']:8.2f} {r['peak_rss_mb']:7.0f} {r['status']:>12} {r['log_svr']:7.2f} "
                  f"{r['outcome']:>10}  {r['loadavg_before'][0]:.1f}", flush=True)
        write(args, rows, {})  # after every run: a partial table survives an interrupted benchmark
    write(args, rows, growth_of(rows))


def growth_of(rows: list[dict]) -> dict:
    growth = {}
    for route in ("template", "paper"):
        first = rows[0]["seed"] if rows else 0
        sel = [r for r in rows if r["route"] == route and "error" not in r and r["seed"] == first]
        for r in sel:
            r["rss_over_import_mb"] = r["peak_rss_mb"] - r["import_rss_mb"]
        growth[route] = {k: exponent(sel, k) for k in ("total_s", "sdp_s", "build_s", "apply_s", "peak_rss_mb",
                                                        "rss_over_import_mb")}
        print(f"growth exponents K = 100 → 1000 ({route} route):",
              {k: (None if v is None else round(v, 3)) for k, v in growth[route].items()})
    return growth


def learned_at(path: str, size: str) -> dict:
    """The set file's learning size (and its range, for a set discovered over one, and the carry-over plan
    that chose where it was selected and checked)."""
    obj = json.loads(Path(path).read_text(encoding="utf-8"))
    out = {size: obj.get("params", {}).get(size)}
    over = obj.get("info", {}).get("range", {}).get("over")
    carry = obj.get("info", {}).get("carry")
    return out | ({"range": over} if over else {}) | ({"carry": carry} if carry else {})


def write(args: argparse.Namespace, rows: list[dict], growth: dict) -> None:
    from autotight.io import versions

    obj = {"benchmark": "scale", "problem": args.problem, "size_param": SIZE[args.problem],
           "set": Path(args.set).name, "learned_at": learned_at(args.set, SIZE[args.problem]), "solver": "ipm",
           "n_random": 0,
           "seeds": args.seeds, "seeds_at": args.seeds_at, "rows": rows,
           "command": "python benchmarks/scale.py " + " ".join(sys.argv[1:]),
           "growth_exponents_100_1000": growth, "targets": {"time": 1.15, "memory": 1.1},
           "versions": versions(), "cpu_count": os.cpu_count(), "loadavg_end": os.getloadavg()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(obj, indent=1, default=str), encoding="utf-8")
    if growth:
        print(f"wrote {args.out}")


# ----------------------------------------------------------------------------- this checkout against another


def solve_one(problem: str, size: int, set_path: str, seed: int, solver: str) -> dict:
    """``autotight solve PROBLEM -p SIZE=size --set set_path --seed seed [--solver solver]`` in this process,
    through the public API only (it runs against older checkouts too): its times, peak RSS and result."""
    t0 = time.perf_counter()
    import autotight as at
    from autotight.constraint_set import ConstraintSet

    config = at.SolverConfig() if solver == "default" else at.SolverConfig(backend=solver)
    r = at.solve(problem, {SIZE[problem]: size}, seed, constraints=ConstraintSet.load(set_path), solver=config)
    return {"size": size, "seed": seed, "N": r.sdp.X.shape[0] if r.sdp.X is not None else None,
            "n_constraints": r.n_constraints, "solver": r.sdp.solver, "status": r.sdp.status,
            "outcome": r.outcome, "tight": r.tight, "log_svr": r.log_svr, "sdp_cost": r.sdp.primal_cost,
            "certified": None if r.certificate is None else bool(r.certificate.certified),
            "sdp_dual_cost": r.sdp.dual_cost, "upper_bound": r.upper, "times": r.times,
            "total_s": time.perf_counter() - t0, "cpu_s": time.process_time(),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def versus_child(root: Path, python: str, problem: str, size: int, set_path: str, seed: int, solver: str,
                 timeout: float) -> dict:
    """``solve_one`` in a fresh process of the checkout at ``root`` (its own interpreter ``python``)."""
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    code = (f"import sys, json; sys.path.insert(0, {str(HERE)!r}); import scale; "
            f"print(json.dumps(scale.solve_one({problem!r}, {size}, {set_path!r}, {seed}, {solver!r}), default=str))")
    try:
        p = subprocess.run(["nice", "-n", "10", python, "-c", code], capture_output=True, text=True,
                           env=dict(os.environ, PYTHONPATH=str(root)), cwd=str(root), timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"size": size, "seed": seed, "error": f"timeout after {timeout:g} s"}
    rec = ({"error": child_error(p)} if p.returncode != 0
           else json.loads(p.stdout.strip().splitlines()[-1]))
    return {"size": size, "seed": seed} | rec | {"process_wall_s": time.perf_counter() - t0, "loadavg_before": load0,
                                                 "loadavg_after": os.getloadavg()}


def versus(args: argparse.Namespace) -> None:
    """Every (size, seed) solved by this checkout and by ``--versus`` (the commit before), interleaved (this one
    first, then the other, size by size), each in a fresh process; growth exponents of each between
    consecutive sizes, the ratio new/old of every time (``cpu_s``: the child's CPU time, the fairer figure on a
    shared machine) and the relative difference of the SDP costs."""
    import math

    old_root = Path(args.versus).resolve()
    old_python = str(old_root / ".venv" / "bin" / "python") if (old_root / ".venv").exists() else sys.executable
    sizes = [int(k) for k in args.sizes.split(",") if k]
    skip_old = {int(k) for k in args.new_only.split(",") if k}
    seeds = [int(s) for s in args.seeds.split(",") if s]
    every = {int(k) for k in args.seeds_at.split(",") if k}
    rows: list[dict] = []
    for size in sizes:
        for seed in (seeds if not every or size in every else seeds[:1]):
            for version, root, python in (("new", ROOT, sys.executable), ("old", old_root, old_python)):
                if version == "old" and size in skip_old:
                    continue
                r = versus_child(root, python, args.problem, size, args.set, seed, args.solver, args.timeout)
                r["version"] = version
                rows.append(r)
                t = r.get("times", {})
                print(f"{version:>3} {SIZE[args.problem]}={size:<6} seed {seed}  " + (
                    f"error: {r['error']}" if "error" in r else
                    f"total {r['total_s']:7.1f} s  build {t.get('build_s', 0):6.2f}  local {t.get('local_s', 0):6.2f}  "
                    f"SDP {t.get('sdp_total_s', 0):7.2f}  refine {t.get('refine_s', 0):6.2f}  RSS "
                    f"{r['peak_rss_mb']:6.0f} MB  {r['outcome']}  cost {r['sdp_cost']:.10g}")
                    + f"  load {r['loadavg_before'][0]:.1f}", flush=True)
                write_versus(args, rows, {})
    summary: dict = {"growth": {}, "pairs": []}
    for version in ("new", "old"):
        ok = {r["size"]: r for r in rows if r["version"] == version and "error" not in r and r["seed"] == seeds[0]}
        summary["growth"][version] = {f"{a}->{b}": {k: math.log(ok[b][k] / ok[a][k]) / math.log(b / a)
                                                   for k in ("total_s", "peak_rss_mb")}
                                      for a, b in zip(sizes, sizes[1:]) if a in ok and b in ok}
    for size in sizes:
        for seed in seeds:
            new = next((r for r in rows if r["version"] == "new" and r["size"] == size and r["seed"] == seed), None)
            old = next((r for r in rows if r["version"] == "old" and r["size"] == size and r["seed"] == seed), None)
            if not new or not old or "error" in new or "error" in old:
                continue
            keys = [k for k in new["times"] if k in old["times"] and old["times"][k]]
            summary["pairs"].append({
                "size": size, "seed": seed, "same_outcome": new["outcome"] == old["outcome"],
                "sdp_cost_rel_diff": abs(new["sdp_cost"] - old["sdp_cost"]) / max(abs(old["sdp_cost"]), 1e-300),
                "ratio_total": new["total_s"] / old["total_s"], "ratio_rss": new["peak_rss_mb"] / old["peak_rss_mb"],
                "ratio_cpu": new["cpu_s"] / old["cpu_s"] if new.get("cpu_s") and old.get("cpu_s") else None,
                "ratio_times": {k: new["times"][k] / old["times"][k] for k in keys}})
    print(json.dumps(summary, indent=1))
    write_versus(args, rows, summary)


def write_versus(args: argparse.Namespace, rows: list[dict], summary: dict) -> None:
    from autotight.io import versions

    obj = {"benchmark": "scale_versus", "problem": args.problem, "size_param": SIZE[args.problem],
           "set": Path(args.set).name, "solver": args.solver, "versus": str(args.versus), "seeds": args.seeds,
           "command": "python benchmarks/scale.py " + " ".join(sys.argv[1:]), "rows": rows, "summary": summary,
           "versions": versions(), "cpu_count": os.cpu_count(), "loadavg_end": os.getloadavg()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(obj, indent=1, default=str), encoding="utf-8")


if __name__ == "__main__":
    main()
