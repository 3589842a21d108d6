"""The discovery engine against an older checkout, side by side in one run.

Each case runs the same CLI commands through both checkouts (``python -m autotight.cli``, fresh
processes, old then new, so the load of this shared machine falls on both alike): ``discover`` with
``--out``, then the case's follow-up (``check`` at the same points with 10 fresh instances and
``--min-fraction 0.9``, or ``solve`` at the size a carried set must reach).  Reported per side: the
discover wall time and CPU time (user + system of the process, less sensitive to other jobs on a shared
machine than the wall time), its exit code, the set's size, the follow-up's exit code (0: the handed-back
set passes) and times; the 1-minute load average before and after each command; and the ratios of the
discover times (new / old, wall and CPU).

The old side is a ``git worktree`` of ``--old-ref`` (default 9d4129a, the engine before the held-out
certificate, the shared held-out instances and the cheaper template fits), created on first use under /tmp.

    python benchmarks/discover.py [--cases pose10,pose_range,discrete,continuous,robust_wahba] [--seeds 0,1,2]
        [--old-ref 9d4129a]

Writes benchmarks/results/discover.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OLD_TREE = Path(tempfile.gettempdir()) / "autotight-discover-old-{ref}"

#: name → (discover arguments, follow-up arguments or None); "{out}" is the set file
CASES = {
    "pose10": (["discover", "pose_averaging"], None),  # the README's first command (M = 10 by default)
    "pose_range": (["discover", "pose_averaging", "-p", "M=5", "--sigmas", "0.01,0.1,1"],
                   ["check", "pose_averaging", "-p", "M=5", "--set", "{out}", "--sigmas", "0.01,0.1,1",
                    "--instances", "10", "--min-fraction", "0.9"]),
    # the defaults (K = 20, carried to the module's CARRY_TO K = 200), then the set at K = 1000
    "discrete": (["discover", "discrete_trajectory"],
                 ["solve", "discrete_trajectory", "-p", "K=1000", "--set", "{out}", "--solver", "ipm"]),
    # continuous time at the paper's K = 21: 517 columns, about 9 s an instance
    "continuous": (["discover", "continuous_trajectory"],
                   ["check", "continuous_trajectory", "--set", "{out}", "--instances", "10", "--min-fraction", "0.9"]),
    # the peer's robust Wahba (N = 4, TLS) at its defaults, cost-tight: the greedy takes every candidate pair
    "robust_wahba": (["discover", "robust_wahba", "--accept", "cost"],
                     ["check", "robust_wahba", "--set", "{out}", "--accept", "cost", "--instances", "10",
                      "--min-fraction", "0.9"]),
}


def old_tree(ref: str) -> Path:
    """A worktree of ``ref`` (created once)."""
    tree = Path(str(OLD_TREE).format(ref=ref))
    if not (tree / "autotight").is_dir():
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), ref], cwd=ROOT, check=True,
                       capture_output=True)
    return tree


def cli(checkout: Path, args: list[str]) -> tuple[int, float, float, list[float], str]:
    """(exit code, wall s, CPU s of the child, 1-minute load average before and after, output)."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "autotight.cli", *args], cwd=checkout, env=env,
                          capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return proc.returncode, wall, cpu, [load0, os.getloadavg()[0]], proc.stdout + proc.stderr


def n_pairs(path: Path) -> int | None:
    try:
        return len(json.loads(path.read_text(encoding="utf-8"))["pairs"])
    except (OSError, ValueError, KeyError):
        return None


def n_constraints(path: Path) -> int | None:
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
        return sum(len(v) for v in rec.get("constraints_by_factor", {}).values())
    except (OSError, ValueError):
        return None


def side(checkout: Path, case: str, seed: int, work: Path) -> dict:
    disc, follow = CASES[case]
    out = work / f"{checkout.name}-{case}-{seed}.json"
    code, wall, cpu, load, text = cli(checkout, [*disc, "--seed", str(seed), "--no-progress", "--out", str(out),
                                                 "--force"])
    rec = {"discover_exit": code, "discover_s": wall, "discover_cpu_s": cpu, "discover_load": load,
           "n_pairs": n_pairs(out), "n_constraints": n_constraints(out), "tail": text.strip().splitlines()[-3:]}
    if follow is not None and out.exists():
        fcode, fwall, fcpu, fload, ftext = cli(checkout, [a.replace("{out}", str(out)) for a in follow])
        rec |= {"follow_exit": fcode, "follow_s": fwall, "follow_cpu_s": fcpu, "follow_load": fload,
                "follow_tail": ftext.strip().splitlines()[-2:]}
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="pose10,pose_range")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--old-ref", default="9d4129a")
    ap.add_argument("--sides", default="old,new")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "discover.json"))
    a = ap.parse_args()
    trees = {"old": old_tree(a.old_ref) if "old" in a.sides else None, "new": ROOT}
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases.split(","):
            for seed in (int(s) for s in a.seeds.split(",")):
                row: dict = {"case": case, "seed": seed, "command": " ".join(CASES[case][0])}
                for name in a.sides.split(","):
                    row[name] = side(trees[name], case, seed, Path(tmp))
                    print(case, seed, name, {k: v for k, v in row[name].items() if "tail" not in k}, flush=True)
                if "old" in row and "new" in row:
                    row["ratio_new_old"] = row["new"]["discover_s"] / row["old"]["discover_s"]
                    row["cpu_ratio_new_old"] = row["new"]["discover_cpu_s"] / row["old"]["discover_cpu_s"]
                runs.append(row)
    new_ref = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             check=False).stdout.strip()
    res = {"command": "python benchmarks/discover.py " + " ".join(sys.argv[1:]), "old_ref": a.old_ref,
           "new_ref": new_ref, "load_average_at_end": os.getloadavg(), "cpus": os.cpu_count(), "runs": runs}
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
