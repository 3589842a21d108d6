"""Figures in the style of the paper's Figs. 3, 5, 8, 11: trapped fraction and log SVR box plots against σ.

Every σ axis is logarithmic; every function writes one PNG and returns its path.  Figures are
built as ``matplotlib.figure.Figure`` objects (Agg canvas), never through pyplot's global state.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from ..outpaths import writing
from .store import solved_rows

COLORS = {"primary": "tab:blue", "paper": "tab:orange", "discovered": "tab:green"}
LOG_SVR_CAP = 16.0
"""An infinite log SVR (λ₂ ≤ 0) is drawn at this height."""
DPI = 130


def _color(name: str) -> str:
    return COLORS.get(name, "tab:gray")


def _sigma_axis(ax: Axes, sigmas: Sequence[float]) -> None:
    ax.set_xscale("log")
    lo, hi = min(sigmas), max(sigmas)
    pad = _group_width(sigmas)
    ax.set_xlim(lo / 10 ** pad, hi * 10 ** pad)
    ax.set_xlabel("noise level σ")
    ax.grid(True, which="major", alpha=0.3)


def _group_width(sigmas: Sequence[float]) -> float:
    """Width of one σ group in decades: 0.7 of the closest spacing (0.5 for a single σ)."""
    logs = np.log10(sorted(sigmas))
    return 0.7 * float(np.min(np.diff(logs))) if len(logs) > 1 else 0.5


def _per_trial(df: pd.DataFrame) -> pd.DataFrame:
    """One row per trial (the local-solve columns are the same in every set's row)."""
    return df.drop_duplicates(["sigma_index", "trial"])


def _figure(width: float, height: float) -> tuple[Figure, Axes]:
    fig = Figure(figsize=(width, height))
    return fig, fig.subplots()


def _save(fig: Figure, path: Path) -> Path:
    """Save to a temporary file in the same folder, then rename: never a half-written figure."""
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with writing(path):
            fig.savefig(tmp, dpi=DPI, format="png")
            os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def trapped(df: pd.DataFrame, sigmas: Sequence[float], path: Path, trap_rtol: float) -> Path:
    """Fraction of random-start local solves trapped above the global cost, with 95 % Wilson intervals."""
    trials = _per_trial(df[solved_rows(df)])
    fig, ax = _figure(5.6, 3.8)
    xs, p, lo, hi = [], [], [], []
    for i, s in enumerate(sigmas):
        t = trials[trials["sigma_index"] == i]["trapped"]
        if len(t):
            k, n = int(t.sum()), len(t)
            a, b = _wilson(k, n)
            # max(0, ·): at k = n the interval can end a rounding error below k/n
            xs.append(s); p.append(k / n); lo.append(max(0.0, k / n - a)); hi.append(max(0.0, b - k / n))
    ax.errorbar(xs, p, yerr=[lo, hi], fmt="o-", color="tab:red", capsize=3, lw=1.5, ms=5,
                label="random start")
    _sigma_axis(ax, sigmas)
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("fraction of local solves trapped")
    ax.set_title(f"Local solver from a random start\n(trapped: cost > global by more than {trap_rtol:g} relative)",
                 fontsize=9)
    return _save(fig, path)


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def log_svr(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str], path: Path,
            rank_line: float = 5.0) -> Path:
    """Box plots of log SVR against σ, one box per constraint set, with the rank-d line."""
    fig, ax = _figure(6.4, 4.0)
    group = _group_width(sigmas)
    w = group / len(sets)
    capped = False
    for k, name in enumerate(sets):
        sub = df[df["constraint_set"] == name]
        data, lo_e, hi_e = [], [], []
        for i, s in enumerate(sigmas):
            v = sub[sub["sigma_index"] == i]["log_svr"].to_numpy(float)
            v = v[~np.isnan(v)]
            capped |= bool(np.isinf(v).any())
            v = np.clip(v, -LOG_SVR_CAP, LOG_SVR_CAP)
            if not v.size:
                continue
            c = np.log10(s) + (k - (len(sets) - 1) / 2) * w
            data.append(v); lo_e.append(10 ** (c - 0.42 * w)); hi_e.append(10 ** (c + 0.42 * w))
        if not data:
            continue
        lo_a, hi_a = np.array(lo_e), np.array(hi_e)
        bp = ax.boxplot(data, positions=(lo_a + hi_a) / 2, widths=hi_a - lo_a, patch_artist=True,
                        manage_ticks=False, flierprops={"markersize": 3, "markeredgecolor": _color(name)},
                        medianprops={"color": "black"})
        for box in bp["boxes"]:
            box.set_facecolor(_color(name))
            box.set_alpha(0.75)
        ax.plot([], [], "s", color=_color(name), label=name)
    ax.axhline(rank_line, color="tab:red", ls="--", lw=1.2, label=f"rank d (log SVR = {rank_line:g})")
    lo, hi = ax.get_ylim()
    ax.set_ylim(min(0.0, lo), max(hi, rank_line + 1.0))
    _sigma_axis(ax, sigmas)
    ax.set_ylabel("log SVR  (log₁₀ of eigenvalue ratio)")
    title = "Rank of the SDP solution per constraint set"
    if capped:
        title += f"\n(infinite log SVR drawn at {LOG_SVR_CAP:g})"
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.17), ncol=len(sets) + 1, frameon=False)
    return _save(fig, path)


def tight(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str], path: Path) -> Path:
    """Fraction of trials judged tight (rank d and cost gap) per constraint set."""
    fig, ax = _figure(5.6, 3.8)
    for name in sets:
        sub = df[df["constraint_set"] == name]
        frac = [sub[sub["sigma_index"] == i]["tight"].mean() for i in range(len(sigmas))]
        ax.plot(sigmas, frac, "o-", color=_color(name), label=name, ms=5)
    _sigma_axis(ax, sigmas)
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("fraction of SDP solves tight")
    ax.set_title("Tight: rank d and the cost bracket [dual cost, best feasible cost] closed", fontsize=9)
    ax.legend(fontsize=8, loc="best")
    return _save(fig, path)


def times(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str], path: Path) -> Path:
    """Median solve times against σ (shaded: interquartile range): SDP per set, local solver."""
    fig, ax = _figure(5.6, 3.8)
    trials = _per_trial(df)
    series = [(f"SDP, {n}", df[df["constraint_set"] == n], "sdp_time_s", _color(n), "-") for n in sets]
    series += [("local, from truth", trials, "local_truth_time_s", "tab:gray", "--"),
               ("local, random start", trials, "local_random_time_s", "tab:red", ":")]
    for label, sub, col, color, ls in series:
        q = np.array([_quartiles(sub[sub["sigma_index"] == i][col]) for i in range(len(sigmas))])
        ax.plot(sigmas, q[:, 1], marker="o", ms=4, color=color, ls=ls, label=label)
        ax.fill_between(sigmas, q[:, 0], q[:, 2], color=color, alpha=0.15, lw=0)
    _sigma_axis(ax, sigmas)
    ax.set_yscale("log")
    ax.set_ylabel("solve time (s)")
    ax.set_title("Median solve time (shaded: 25–75 %)", fontsize=9)
    ax.legend(fontsize=8, loc="best")
    return _save(fig, path)


def _quartiles(values: pd.Series) -> np.ndarray:
    v = values.to_numpy(float)
    v = v[np.isfinite(v)]
    return np.percentile(v, [25, 50, 75]) if v.size else np.full(3, np.nan)


def make_all(df: pd.DataFrame, sigmas: Sequence[float], sets: Sequence[str], out: Path, *,
             trap_rtol: float, rank_line: float) -> dict[str, Path]:
    """Every figure, keyed by name."""
    return {"trapped": trapped(df, sigmas, out / "trapped.png", trap_rtol),
            "log_svr": log_svr(df, sigmas, sets, out / "log_svr.png", rank_line),
            "tight": tight(df, sigmas, sets, out / "tight.png"),
            "times": times(df, sigmas, sets, out / "times.png")}
