"""Trajectory discovery and the continuous-time tightness boundary (issue 4).

Parts (each appends to its own raw-result file under results/, so an interrupted run keeps what it did):

  discrete   `discover` on discrete_trajectory (per-factor learning, greedy tightening, reduction,
             held-out instances, comparison with the paper's R1–R3) → results/discrete.jsonl and
             results/discrete_K{K}_table.txt (the CLI table with the constraints as polynomials).
  boundary   continuous_trajectory over a grid of (K, σ, motion, seed): the SDP with
               paper   = primary + the paper's R1–R8,
               factors = primary + every candidate learned per factor (``learn(..., "factors")``),
               pairs2  = primary + every candidate learned per factor and over two consecutive motion
                         factors (``"factors,adjacent:motion+motion"``; only where K ≤ --pairs-max-k),
             judged against the best local solve → results/boundary.csv (one row per cell and set).
  reduce     `discover` on continuous_trajectory for the cells given by --cells (K:σ:motion) with
             per-factor groups → results/reduce.jsonl and results/reduce_*_table.txt.

Examples:
  .venv/bin/python reports/continuous_boundary/run_study.py --part discrete --K 10 20
  .venv/bin/python reports/continuous_boundary/run_study.py --part boundary --grid coarse
  .venv/bin/python reports/continuous_boundary/run_study.py --part reduce --cells 11:0.1:1 --heldout 3
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from autotight.discovery import discover, learn  # noqa: E402
from autotight.discovery.cli import table  # noqa: E402
from autotight.discovery.compare import paper_in_span  # noqa: E402
from autotight.io import jsonable  # noqa: E402
from autotight.problem import load  # noqa: E402
from autotight.run import local_search, solve_sdp  # noqa: E402
from autotight.sdp.result import SolverOptions  # noqa: E402
from autotight.threads import single_blas_thread  # noqa: E402
from autotight.tightness import judge  # noqa: E402

OUT = HERE / "results"


def versions() -> dict:
    out = {"python": platform.python_version(), "machine": platform.machine()}
    for pkg in ("autotight", "numpy", "scipy", "clarabel"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _append_jsonl(path: Path, rec: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(jsonable(rec), ensure_ascii=False) + "\n")


# ----------------------------------------------------------------------------- discrete discovery


def part_discrete(Ks: list[int], seed: int, heldout: int, sigma: float) -> None:
    prob = load("discrete_trajectory")
    for K in Ks:
        params = {"K": K, "sigma": sigma}
        t0 = time.perf_counter()
        res = discover(prob, params, seed, groups="factors", n_heldout=heldout)
        wall = time.perf_counter() - t0
        s = res.summary()
        s.update({"wall_s": wall, "versions": versions(), "groups": "factors"})
        _append_jsonl(OUT / "discrete.jsonl", s)
        txt = table(res)
        (OUT / f"discrete_K{K}_table.txt").write_text(txt + f"\n\nwall time {wall:.1f} s; times {s['times']}\n")
        print(txt)
        print(f"K={K}: wall {wall:.1f} s", flush=True)


# ----------------------------------------------------------------------------- continuous boundary

GRIDS = {
    # K sweep at the default σ and motion; σ and motion sweeps at K = 11; motion 0.3 at K = 17
    "coarse": ([(K, 0.1, 1.0) for K in (7, 11, 15, 17, 21)]
               + [(11, s, 1.0) for s in (0.01, 0.3, 1.0)]
               + [(11, 0.1, m) for m in (0.3, 2.0)]
               + [(17, 0.1, 0.3)]),
    "tiny": [(7, 0.1, 1.0)],
}

FIELDS = ["K", "sigma", "motion", "seed", "set", "n_constraints", "status", "tight", "rank_tight", "cost_tight",
          "log_svr", "sdp_cost", "best_local_cost", "rel_gap", "paper_in_span_max_residual", "n_rejected_heldout",
          "min_spectral_gap", "learn_s", "sdp_s", "local_s", "versions"]


@single_blas_thread
def boundary_cell(K: int, sigma: float, motion: float, seed: int, sets: list[str], pairs_max_k: int,
                  time_limit: float, retry: bool = False) -> list[dict]:
    prob = load("continuous_trajectory")
    params = prob.parse_params({"K": K, "sigma": sigma, "motion": motion})
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    rng = np.random.default_rng([seed, 1])
    t = time.perf_counter()
    loc = local_search(prob, inst, rng, 2)
    local_s = time.perf_counter() - t
    opts = SolverOptions(time_limit=time_limit)
    rows = []
    base = {"K": K, "sigma": sigma, "motion": motion, "seed": seed, "best_local_cost": loc.best.cost,
            "local_s": round(local_s, 2), "versions": json.dumps(versions())}
    for name in sets:
        row = dict(base, set=name)
        if name == "paper":
            extra = model.paper_constraints()
        else:
            groups = {"factors": "factors", "pairs2": "factors,adjacent:motion+motion"}[name]
            if name == "pairs2" and K > pairs_max_k:
                continue
            t = time.perf_counter()
            cat = learn(prob, inst, model, np.random.default_rng([seed, 2]), groups)
            row["learn_s"] = round(time.perf_counter() - t, 2)
            extra = cat.candidates()
            span = paper_in_span(cat)
            row["paper_in_span_max_residual"] = max(v["max_residual"] for v in span.values())
            row["n_rejected_heldout"] = len(cat.rejected())
            row["min_spectral_gap"] = min(g.gap_decades for g in cat.groups)
        cons = model.primary() + list(extra)
        t = time.perf_counter()
        res = solve_sdp(model, cons, options=opts)
        row["sdp_s"] = round(time.perf_counter() - t, 2)
        v = judge(res, loc.best.cost)
        row.update({"n_constraints": len(cons), "status": res.status, "tight": v.tight, "rank_tight": v.rank_tight,
                    "cost_tight": v.cost_tight, "log_svr": res.log_svr, "sdp_cost": res.primal_cost,
                    "rel_gap": v.rel_gap})
        rows.append(row)
        if retry and not res.usable:  # solver failure: retry with our own clique decomposition
            r2 = dict(row, set=name + "/own-cliques")
            t = time.perf_counter()
            res2 = solve_sdp(model, cons, options=opts, decompose=True)
            r2["sdp_s"] = round(time.perf_counter() - t, 2)
            v2 = judge(res2, loc.best.cost)
            r2.update({"status": res2.status, "tight": v2.tight, "rank_tight": v2.rank_tight,
                       "cost_tight": v2.cost_tight, "log_svr": res2.log_svr, "sdp_cost": res2.primal_cost,
                       "rel_gap": v2.rel_gap})
            rows.append(r2)
            print(f"   retry own cliques: {res2.status} logSVR={res2.log_svr:.2f} gap={v2.rel_gap:+.2e} "
                  f"tight={v2.tight} {r2['sdp_s']}s", flush=True)
        print(f"K={K} σ={sigma} motion={motion} seed={seed} {name:8s} n={len(cons):5d} {res.status:13s} "
              f"logSVR={res.log_svr:6.2f} gap={v.rel_gap:+.2e} tight={v.tight} sdp {row['sdp_s']}s "
              f"learn {row.get('learn_s', '-')}s", flush=True)
    return rows


def part_boundary(cells: list[tuple[int, float, float]], seeds: list[int], sets: list[str], pairs_max_k: int,
                  time_limit: float, retry: bool = False, csv_name: str = "boundary.csv") -> None:
    path = OUT / csv_name
    OUT.mkdir(parents=True, exist_ok=True)
    new = not path.exists()
    with path.open("a", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        if new:
            w.writeheader()
        for K, sigma, motion in cells:
            for seed in seeds:
                for row in boundary_cell(K, sigma, motion, seed, sets, pairs_max_k, time_limit, retry):
                    w.writerow(row)
                    f.flush()


# ----------------------------------------------------------------------------- reduction where tight


def part_reduce(cells: list[tuple[int, float, float]], seed: int, heldout: int, groups: str) -> None:
    prob = load("continuous_trajectory")
    for K, sigma, motion in cells:
        params = {"K": K, "sigma": sigma, "motion": motion}
        t0 = time.perf_counter()
        res = discover(prob, params, seed, groups=groups, n_heldout=heldout)
        wall = time.perf_counter() - t0
        s = res.summary()
        s.update({"wall_s": wall, "versions": versions(), "groups": groups})
        _append_jsonl(OUT / "reduce.jsonl", s)
        tag = f"K{K}_s{sigma}_m{motion}_{groups.replace(',', '+').replace(':', '-')}"
        txt = table(res)
        (OUT / f"reduce_{tag}_table.txt").write_text(txt + f"\n\nwall time {wall:.1f} s; times {s['times']}\n")
        print(txt)
        print(f"wall {wall:.1f} s", flush=True)


def part_tables() -> None:
    """Markdown tables from the raw results (for README.md)."""
    if (OUT / "discrete.jsonl").exists():
        print("| K | candidates (pairs) | rejected held-out | paper | discovered (pairs) | resembles | held-out tight "
              "(disc. / paper) | log SVR (primary) | wall s |")
        print("|---|---|---|---|---|---|---|---|---|")
        for line in (OUT / "discrete.jsonl").read_text().splitlines():
            d = json.loads(line)
            print(f"| {d['params']['K']} | {d['n_candidates']} ({d['n_candidate_pairs']}) | {d['n_rejected_heldout']} | "
                  f"{d['n_paper']} | {d['n_minimal']} ({d['n_minimal_pairs']}) | "
                  f"{', '.join(sorted(set(d['resembles'].values())))} | {d['heldout_tight_fraction']:.0%} / "
                  f"{d['paper_heldout_tight_fraction']:.0%} of {d['heldout_instances']} | {d['log_svr']:.2f} "
                  f"({d['log_svr_primary']:.2f}) | {d['wall_s']:.0f} |")
    for path in sorted(OUT.glob("boundary*.csv")):
        with path.open() as f:
            rows = list(csv.DictReader(f))
        print(f"\n{path.name}\n")
        print("| K | σ | motion | seed | set | #constraints | status | log SVR | rel. gap | tight | SDP s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['K']} | {r['sigma']} | {r['motion']} | {r['seed']} | {r['set']} | {r['n_constraints']} | "
                  f"{r['status']} | {float(r['log_svr']):.2f} | {float(r['rel_gap']):+.1e} | "
                  f"{'**yes**' if r['tight'] == 'True' else 'no'} | {r['sdp_s']} |")


def _cells(specs: list[str]) -> list[tuple[int, float, float]]:
    out = []
    for s in specs:
        K, sigma, motion = s.split(":")
        out.append((int(K), float(sigma), float(motion)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", required=True, choices=["discrete", "boundary", "reduce", "tables"])
    ap.add_argument("--K", type=int, nargs="+", default=[10, 20], help="discrete: K values")
    ap.add_argument("--sigma", type=float, default=0.1, help="discrete: σ")
    ap.add_argument("--seed", type=int, default=0, help="discrete/reduce: learning seed")
    ap.add_argument("--heldout", type=int, default=3, help="discrete/reduce: held-out instances")
    ap.add_argument("--grid", default=None, choices=sorted(GRIDS), help="boundary: a named grid of cells")
    ap.add_argument("--cells", nargs="*", default=[], help="boundary/reduce: cells K:σ:motion")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="boundary: seeds per cell")
    ap.add_argument("--sets", nargs="+", default=["paper", "factors", "pairs2"], help="boundary: constraint sets")
    ap.add_argument("--pairs-max-k", type=int, default=7, help="boundary: largest K for the pairs2 set")
    ap.add_argument("--time-limit", type=float, default=240.0, help="boundary: solver time limit per SDP (s)")
    ap.add_argument("--retry", action="store_true",
                    help="boundary: re-solve a failed SDP with our own clique decomposition (decompose=True)")
    ap.add_argument("--groups", default="factors", help="reduce: learning groups")
    ap.add_argument("--csv", default="boundary.csv", help="boundary: results file under results/")
    a = ap.parse_args()
    os.chdir(ROOT)
    t0 = time.perf_counter()
    if a.part == "discrete":
        part_discrete(a.K, a.seed, a.heldout, a.sigma)
    elif a.part == "boundary":
        cells = (GRIDS[a.grid] if a.grid else []) + _cells(a.cells)
        part_boundary(cells, a.seeds, a.sets, a.pairs_max_k, a.time_limit, a.retry, a.csv)
    elif a.part == "tables":
        part_tables()
    else:
        part_reduce(_cells(a.cells), a.seed, a.heldout, a.groups)
    print(f"part {a.part}: {time.perf_counter() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    main()
