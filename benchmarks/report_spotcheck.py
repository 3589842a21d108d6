"""Re-run a sample of a committed report's trials with the current code and compare them with its trials.csv.

A committed report is regenerated in full with the command its report.md names; this script is the cheap
check of whether a change moves any of its results.  It re-runs ``--per-sigma`` trials at every noise level
(the first ones, which a partial run would also compute) and compares outcomes, verdict flags and the
deterministic numbers (costs, bounds: relative 1e-6), writing one JSON with every difference found.

    python benchmarks/report_spotcheck.py reports/pose_averaging --per-sigma 2

``--retried`` re-runs instead every trial with a row that made more than one SDP attempt (``sdp_attempts``):
the trials a change of the re-solve policy can move.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from autotight.report.spec import SweepSpec
from autotight.report.sweep import DISCOVERED_NAME, prepare_files
from autotight.report.trial import run_trial
from autotight.tightness import Criteria

FLAGS = ["status", "outcome", "tight", "rank_tight", "cost_tight", "certified"]
NUMBERS = ["sdp_cost", "upper_bound", "sdp_lower_bound", "local_cost_truth"]


def spec_of(folder: Path) -> SweepSpec:
    """The sweep of a report folder, from its meta.json (saved sets are looked up beside reports/)."""
    m = json.loads((folder / "meta.json").read_text())
    root = folder.resolve().parents[1]
    files = tuple((name, str(root / "reports" / "sets" / v["file"])) for name, v in (m.get("files") or {}).items())
    disc = folder / DISCOVERED_NAME
    return SweepSpec(m["problem"], m["params"], tuple(m["sigmas"]), 1, tuple(m["sets"]), m["seed"], m["trap_rtol"],
                     Criteria(**m["criteria"]), m["solver"], m["decompose"],
                     str(disc) if "discovered" in m["sets"] else None, files, m.get("source", ""))


def compare(saved: pd.DataFrame, rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        s = saved[(saved.sigma_index == r["sigma_index"]) & (saved.trial == r["trial"])
                  & (saved.constraint_set == r["constraint_set"])]
        if len(s) != 1:
            out.append({"row": (r["sigma_index"], r["trial"], r["constraint_set"]), "missing": True})
            continue
        s = s.iloc[0]
        for k in FLAGS:
            a, b = s.get(k), r.get(k)
            if not (pd.isna(a) and (b is None or (isinstance(b, float) and np.isnan(b)))) and str(a) != str(b):
                out.append({"row": (r["sigma_index"], r["trial"], r["constraint_set"]), "column": k,
                            "saved": str(a), "now": str(b)})
        for k in NUMBERS:
            a, b = float(s.get(k, np.nan)), float(r.get(k, np.nan) if r.get(k) is not None else np.nan)
            if np.isfinite(a) and np.isfinite(b) and abs(a - b) > 1e-6 * max(abs(a), abs(b), 1e-9):
                out.append({"row": (r["sigma_index"], r["trial"], r["constraint_set"]), "column": k,
                            "saved": a, "now": b})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--per-sigma", type=int, default=2)
    ap.add_argument("--retried", action="store_true",
                    help="re-run every trial with a row of more than one SDP attempt instead of the first ones")
    ap.add_argument("--json", type=Path, default=None, help="where to write the result (default: print only)")
    a = ap.parse_args()
    spec = spec_of(a.folder)
    saved = pd.read_csv(a.folder / "trials.csv")
    problem = spec.load()
    sets, _ = prepare_files(spec, problem)
    if spec.discovered:
        from autotight.constraint_set import ConstraintSet

        sets["discovered"] = ConstraintSet.load(spec.discovered)
    t0 = time.perf_counter()
    diffs, n = [], 0
    if a.retried:
        picked = saved[saved.sdp_attempts > 1][["sigma_index", "trial"]].drop_duplicates()
        trials = sorted((int(i), int(t)) for i, t in picked.itertuples(index=False))
    else:
        trials = [(i, t) for t in range(a.per_sigma) for i in range(len(spec.sigmas))]
    for i, t in trials:
        rows = run_trial(spec, i, t, sets).rows
        n += len(rows)
        d = compare(saved, rows)
        diffs += d
        print(f"σ = {spec.sigmas[i]:g}, trial {t}: {len(rows)} rows, {len(d)} differences", flush=True)
    result = {"report": str(a.folder), "trials": "retried" if a.retried else f"first {a.per_sigma} per σ",
              "rows_compared": n, "differences": diffs,
              "elapsed_s": time.perf_counter() - t0}
    print(json.dumps(result, indent=1, default=str))
    if a.json:
        a.json.write_text(json.dumps(result, indent=1, default=str))


if __name__ == "__main__":
    main()
