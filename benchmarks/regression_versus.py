"""The regression set through the CLI, this checkout against another, interleaved.

Each case runs ``autotight solve NAME PARAMS --json`` in a fresh process under ``/usr/bin/time`` (wall, user +
sys CPU, peak RSS), this checkout then the other (``--versus DIR``, its own ``.venv``), ``--reps`` times; the
outcome, solver and SDP cost come from the JSON.  At discrete K = 100 the other checkout runs with
``--solver ipm`` (its default, Clarabel's chordal path, took 80–150 s): the verdict this checkout's default
must match.

    nice -n 10 python benchmarks/regression_versus.py --versus DIR [--reps 2] [--cases "rotation_averaging" …]
        [--out benchmarks/results/regression_versus.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASES = [("rotation_averaging", []), ("pose_averaging", ["-p", "M=10"]), ("discrete_trajectory", ["-p", "K=20"]),
         ("continuous_trajectory", ["-p", "K=21"]), ("discrete_trajectory", ["-p", "K=100"])]
OLD_EXTRA = {"discrete_trajectory -p K=100": ["--solver", "ipm"]}


def key(name: str, params: list[str]) -> str:
    return " ".join([name, *params])


def run(root: Path, name: str, params: list[str], extra: list[str]) -> dict:
    cmd = ["nice", "-n", "10", "/usr/bin/time", "-f", "TIME %e %U %S %M", str(root / ".venv" / "bin" / "autotight"),
           "solve", name, *params, "--json", *extra]
    load = os.getloadavg()[0]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=root)
    t = [line for line in p.stderr.splitlines() if line.startswith("TIME")][-1].split()
    try:
        rec = json.loads(p.stdout)
    except json.JSONDecodeError:
        rec = {"error": p.stderr.strip().splitlines()[-2:]}
    return {"wall_s": float(t[1]), "cpu_s": float(t[2]) + float(t[3]), "peak_rss_mb": int(t[4]) / 1024, "load": load,
            **{k: rec.get(k) for k in ("outcome", "tight", "sdp_cost", "solver", "status", "times", "error")}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--versus", required=True, metavar="DIR")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--cases", nargs="*", default=None, help='e.g. "discrete_trajectory -p K=20" (default: all)')
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "regression_versus.json"))
    args = ap.parse_args()
    rows = []
    for name, params in CASES:
        if args.cases and key(name, params) not in args.cases:
            continue
        for rep in range(args.reps):
            for version, root in (("new", ROOT), ("old", Path(args.versus).resolve())):
                extra = OLD_EXTRA.get(key(name, params), []) if version == "old" else []
                row = {"problem": name, "params": params, "version": version, "rep": rep, "extra": extra,
                       **run(root, name, params, extra)}
                rows.append(row)
                print(json.dumps({k: row[k] for k in ("problem", "params", "version", "wall_s", "cpu_s", "outcome",
                                                      "sdp_cost", "solver")}), flush=True)
                Path(args.out).write_text(json.dumps({"benchmark": "regression_versus", "versus": args.versus,
                                                      "rows": rows}, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
