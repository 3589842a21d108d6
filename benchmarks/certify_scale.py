"""Benchmark: ``autotight certify`` against the full SDP (``autotight solve --solver ipm``) on long chains.

Per (K, seed): both commands run on the same instance (discrete trajectory, the set learned at K = 5,
``--set``), each as its own process under ``/usr/bin/time -v`` (a fresh process per size and command:
wall time and peak RSS of the whole command, generate, build, constraints and local solve included),
in alternating order (certify first on even runs).  Recorded: each command's exit status, verdict
(certify: certified and its relative bound; solve: outcome, certified and the relative bound of its
certificate), wall seconds, peak RSS, and the ratio certify / solve of wall time.  Sizes at which
the full SDP is out of reach here (``--no-sdp-above``, default 1000: at K = 10 000 the IPM needs about
10× K = 1000's memory and time, beyond this shared machine) record certify alone, with the reason.

Targets (issue of the certificate work): certify at K = 10 000 certified in ≤ 60 s and ≤ 4 GB; at
K = 1000 ≤ 1/10 of the full SDP's time; at K = 1000 both certified with relative bound ≤ 1e-6 on
seeds 0, 1, 2.  The machine is shared: the load average before and after each run is recorded.

Usage:  python benchmarks/certify_scale.py [--ks 100,1000,10000] [--seeds 0,1,2] [--seeds-large 0]
            [--out benchmarks/results/certify_scale.json]
(--seeds for K ≤ 1000, --seeds-large for larger K.)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import scipy

ROOT = Path(__file__).resolve().parent.parent
SET = "benchmarks/results/scale_set_discrete_K5.json"
TIMEOUT_S = 3600


def timed_command(args: list[str]) -> dict:
    """Run ``autotight ARGS --json`` under /usr/bin/time -v: exit status, wall s, peak RSS MB, its JSON."""
    exe = str(Path(sys.executable).parent / "autotight")
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(["/usr/bin/time", "-v", exe, *args, "--json"], cwd=ROOT, capture_output=True, text=True,
                           timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"returncode": None, "wall_s": time.perf_counter() - t0, "error": f"timeout after {TIMEOUT_S} s",
                "load_before": load_before, "load_after": os.getloadavg()[0]}
    wall = time.perf_counter() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    el = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", p.stderr)
    out = {"returncode": p.returncode, "wall_s": wall, "peak_rss_mb": int(rss.group(1)) / 1024 if rss else None,
           "time_v_elapsed": el.group(1) if el else None, "load_before": load_before, "load_after": os.getloadavg()[0]}
    try:
        out["json"] = json.loads(p.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        out["error"] = (p.stderr.strip().splitlines() or ["no output"])[-1][:500]
    return out


def certify_run(K: int, seed: int) -> dict:
    r = timed_command(["certify", "discrete_trajectory", "-p", f"K={K}", "--seed", str(seed), "--set", SET])
    j = r.pop("json", None)
    if j:
        r.update({k: j.get(k) for k in ("certified", "bound", "rel_bound", "argument", "method", "time_s", "message")})
        r["local_cost"] = j["local"]["cost"]
    return r


def solve_run(K: int, seed: int) -> dict:
    r = timed_command(["solve", "discrete_trajectory", "-p", f"K={K}", "--seed", str(seed), "--set", SET,
                       "--solver", "ipm"])
    j = r.pop("json", None)
    if j:
        c = j.get("certificate") or {}
        r.update({"outcome": j.get("outcome"), "certified": j.get("certified"), "status": j.get("status"),
                  "log_svr": j.get("log_svr"), "rel_bound": c.get("rel_bound"), "argument": c.get("argument"),
                  "local_cost": j.get("local_cost"), "times": j.get("times")})
    return r


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ks", default="100,1000,10000")
    ap.add_argument("--seeds", default="0,1,2", help="seeds at K ≤ 1000")
    ap.add_argument("--seeds-large", default="0", help="seeds above K = 1000")
    ap.add_argument("--no-sdp-above", type=int, default=1000, help="no full SDP above this K (out of reach here)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "certify_scale.json"))
    args = ap.parse_args()
    rows, i = [], 0
    load_start = os.getloadavg()

    def write() -> None:  # after every row, so that a long run leaves its results so far
        out = {"benchmark": "autotight certify against the full SDP (autotight solve --solver ipm), whole commands",
               "problem": "discrete_trajectory", "constraint_set": SET,
               "targets": {"K=10000": "certify certified, ≤ 60 s wall, ≤ 4 GB peak RSS (seed 0)",
                           "K=1000": "certify ≤ 1/10 of solve's wall time; both certified, relative bound ≤ 1e-6, "
                                     "seeds 0-2"},
               "command": "python benchmarks/certify_scale.py " + " ".join(
                   f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
               "rows": rows,
               "versions": {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__},
               "machine": {"cpus": os.cpu_count(), "load_avg_start": load_start, "load_avg_end": os.getloadavg()}}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1, default=float, ensure_ascii=False))

    for K in (int(k) for k in args.ks.split(",") if k):
        for seed in (int(s) for s in (args.seeds if K <= 1000 else args.seeds_large).split(",") if s):
            row = {"K": K, "seed": seed, "certify_first": i % 2 == 0}
            sdp = K <= args.no_sdp_above
            order = ("certify", "solve") if i % 2 == 0 or not sdp else ("solve", "certify")
            for what in order:
                if what == "certify":
                    row["certify"] = certify_run(K, seed)
                elif sdp:
                    row["solve"] = solve_run(K, seed)
            if not sdp:
                row["solve"] = {"skipped": f"the full SDP at K = {K} is out of reach on this machine (--no-sdp-above "
                                           f"{args.no_sdp_above}): about 10× the memory and time of K = 1000"}
            c, s = row["certify"], row["solve"]
            if "wall_s" in s and s.get("wall_s"):
                row["ratio_wall"] = c["wall_s"] / s["wall_s"]
                row["agree"] = bool(c.get("certified")) == (s.get("outcome") == "tight")
            i += 1
            rows.append(row)
            print(f"K={K} seed={seed}: certify {c.get('certified')} rel {c.get('rel_bound')} {c['wall_s']:.1f} s "
                  f"{c.get('peak_rss_mb') or 0:.0f} MB | solve {s.get('outcome', s.get('skipped', '')[:30])} "
                  f"certified {s.get('certified')} rel {s.get('rel_bound')} {s.get('wall_s', float('nan')):.1f} s "
                  f"{s.get('peak_rss_mb') or 0:.0f} MB | ratio {row.get('ratio_wall', float('nan')):.3f} "
                  f"load {c['load_before']:.1f}", flush=True)
            write()
    print("wrote", args.out)


if __name__ == "__main__":
    main()
