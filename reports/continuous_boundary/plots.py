"""Heatmaps and tables of the boundary study (run_study.py --part plots): per grid, the fraction of
tight trials per cell among the decided ones, annotated with the median log SVR on the marginalised X
and the largest relaxation gap; one CSV row per trial.

A trial is *undecided* (counted neither tight nor loose) when the solve did not converge: status
other than Solved/AlmostSolved, or an SDP cost above the best local cost by more than UNDECIDED_GAP
(a relaxation cannot exceed a feasible cost; measured up to 150× on failed solves)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

COLUMNS = ("part", "x_name", "x", "y_name", "y", "seed", "status", "solver", "iterations", "sdp_cpu_s", "sdp_wall_s",
           "sdp_cost", "sdp_dual_cost", "best_local_cost", "rel_gap", "log_svr_marginal", "log_svr_cliques",
           "rank_tight", "cost_tight", "tight", "undecided")


UNDECIDED_GAP = 1e-3


def undecided(r: dict) -> bool:
    return r["status"] not in ("Solved", "AlmostSolved") or not r["rel_gap"] >= -UNDECIDED_GAP


def load(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def write_csv(rows: list[dict], path: Path) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS + ("params", "versions"))
        for r in rows:
            (xn, yn), (x, y) = r["axes"], r["cell"]
            w.writerow([r["part"], xn, x, yn, y] + [r[k] for k in COLUMNS[5:-1]] + [undecided(r)]
                       + [json.dumps(r["params"]), json.dumps(r["versions"])])


def cell_table(rows: list[dict], xs: list, ys: list) -> dict[tuple, dict]:
    out = {}
    for x in xs:
        for y in ys:
            rs = [r for r in rows if r["cell"] == [x, y]]
            if rs:
                gaps = [r["rel_gap"] for r in rs if not undecided(r)] or [float("nan")]
                dec = [r for r in rs if not undecided(r)]
                out[(x, y)] = {"n": len(dec), "undecided": len(rs) - len(dec), "tight": sum(r["tight"] for r in dec),
                               "svr": float(np.median([r["log_svr_marginal"] for r in rs])),
                               "gap_max": float(np.max(gaps)), "cpu": float(np.median([r["sdp_cpu_s"] for r in rs]))}
    return out


def heatmap(rows: list[dict], grid: dict, title: str, xlabel: str, ylabel: str, path: Path, xfmt=str) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (_, xs), (_, ys) = grid["x"], grid["y"]
    cells = cell_table(rows, xs, ys)
    F = np.full((len(ys), len(xs)), np.nan)
    for (x, y), c in cells.items():
        F[ys.index(y), xs.index(x)] = c["tight"] / c["n"] if c["n"] else np.nan
    fig, ax = plt.subplots(figsize=(1.9 * len(xs) + 1.5, 1.2 * len(ys) + 1.2))
    im = ax.imshow(F, origin="lower", cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
    for (x, y), c in cells.items():
        und = f" (+{c['undecided']} undec.)" if c["undecided"] else ""
        ax.text(xs.index(x), ys.index(y), f"{c['tight']}/{c['n']}{und}\nSVR {c['svr']:.1f}\ngap {c['gap_max']:.0e}",
                ha="center", va="center", fontsize=7.5)
    ax.set_xticks(range(len(xs)), [xfmt(x) for x in xs])
    ax.set_yticks(range(len(ys)), [str(y) for y in ys])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, label="fraction tight (R1–R8), of decided trials")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return cells


def plot_all(here: Path, grids: dict) -> None:
    res = here / "results"
    labels = {
        "horizon": ("K = 21, arc, q_c = 1: fraction tight over (horizon, σ)",
                    "Δt (horizon 20·Δt s; yaw per step 0.3·Δt rad)", "σ", lambda x: f"{x:g} ({20 * x:g} s)"),
        "motion": ("K = 21, Δt = 0.1, σ = 0.1: fraction tight over (motion per step, q_c)",
                   "per-step rotation rad (translation m)", "q_c (prior stiffness 1/q_c)",
                   lambda x: f"{0.03 * x:.2g} ({0.1 * x:.2g})"),
        "motion316": ("K = 21, Δt = 0.1, σ = 0.316: fraction tight over (motion per step, q_c)",
                      "per-step rotation rad (translation m)", "q_c (prior stiffness 1/q_c)",
                      lambda x: f"{0.03 * x:.2g} ({0.1 * x:.2g})"),
    }
    summary = {}
    for part, grid in grids.items():
        rows = load(res / f"{part}.jsonl")
        if not rows:
            continue
        write_csv(rows, res / f"{part}.csv")
        title, xl, yl, fmt = labels[part]
        cells = heatmap(rows, grid, title, xl, yl, here / f"{part}.png", fmt)
        summary[part] = {f"{x}|{y}": c for (x, y), c in cells.items()}
        print(part)
        for (x, y), c in sorted(cells.items()):
            print(f"  {grid['x'][0]}={x:g} {grid['y'][0]}={y:g}: {c['tight']}/{c['n']} tight, {c['undecided']} undecided, median log SVR "
                  f"{c['svr']:.2f}, max gap {c['gap_max']:.1e}, median SDP {c['cpu']:.1f} s CPU")
    (res / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
