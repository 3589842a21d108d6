"""Discovery on pose averaging (M = 10) and robust pose averaging (M = 6, 1 outlier, σ = 0.05, cost-tight):
time breakdown, and AutoTight's reduction measured in the same run on the same candidates.

AutoTight-style: solve with every learned candidate, sort the pairs by dual multiplier size
(largest first), keep the shortest tight prefix found by adding one pair at a time
(``reduce.shortest_tight_prefix``).  Ours: greedy tightening by violation + block reduction +
irreducibility verification.  Solves count every solver call (retries included).
Robust pose averaging is compared with AutoTight's published rPPR row (1771 → 925, cost-tight, 148 s).
Prints and writes benchmarks/results/discover.json.

    python benchmarks/discover.py [--M 10] [--seed 0] [--robust-groups SPEC] [--skip-robust]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from autotight.discovery import discover
from autotight.discovery.oracle import Oracle
from autotight.discovery.reduce import shortest_tight_prefix
from autotight.io import jsonable, versions
from autotight.problem import load
from autotight.pipeline import local_search
from autotight.threads import single_blas_thread
from autotight.tightness import Criteria


@single_blas_thread
def autotight_style(problem: str, params: dict, seed: int, groups="factors", criteria: Criteria = Criteria()) -> dict:
    """Learn (the same rng stream as ``discover``, so the same candidates), solve with all, shortest tight prefix."""
    prob = load(problem)
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    from autotight.discovery import learn

    rng = np.random.default_rng([seed, 1])
    loc = local_search(prob, inst, rng, 2)
    t0 = time.perf_counter()
    cat = learn(prob, inst, model, rng, groups)
    pairs = cat.by_pair()
    oracle = Oracle(model, pairs, loc.best.cost, criteria)
    t1 = time.perf_counter()
    v, res = oracle.solve(list(pairs), stage="all")
    prefix, n_prefix = shortest_tight_prefix(oracle, list(pairs), res) if oracle.ok(v) else (list(pairs), 0)
    t2 = time.perf_counter()
    return {"tight_with_all": oracle.ok(v), "status_with_all": res.status, "n_candidate_pairs": len(pairs),
            "n_candidates": sum(len(c) for c in pairs.values()), "n_pairs": len(prefix),
            "n_constraints": sum(len(pairs[p]) for p in prefix), "n_solves": oracle.n_solves,
            "sdp_s": oracle.solve_time_s, "learn_s": t1 - t0, "reduce_s": t2 - t1, "total_s": t2 - t0}


def robust(seed: int, groups: str | None) -> dict:
    """Robust pose averaging, cost acceptance: ours (discover, no held-out) against AutoTight's rule."""
    params = {"M": 6, "sigma": 0.05, "outlier_rate": 1 / 6}
    crit = Criteria(accept="cost")
    t = time.perf_counter()
    ours = discover("robust_pose_averaging", params, seed, groups=groups, criteria=crit, n_heldout=0, compare=False)
    wall = time.perf_counter() - t
    used = groups if groups is not None else load("robust_pose_averaging").module.DEFAULT_GROUPS
    ref = autotight_style("robust_pose_averaging", params, seed, used, crit)
    s = ours.summary()
    return {"params": params, "groups": used, "accept": "cost",
            "ours": {"tight": ours.tight, "final_rel_gap": s["final_rel_gap"], "final_status": s["final_status"],
                     "n_candidates": s["n_candidates"], "n_greedy_pairs": s["n_greedy_pairs"],
                     "n_pairs": len(ours.discovered.pairs), "n_constraints": len(ours.constraints),
                     "reduced": s["minimal_is_reduced"], "irreducible": s["irreducible"],
                     "n_solves": ours.n_solves, "sdp_s": ours.times["sdp_s"],
                     "reduce_s": ours.times["reduce_s"], "total_s": wall, "explanation": s["explanation"]},
            "autotight_style": ref,
            "autotight_published_rPPR": {"n_candidates": 1771, "n_constraints": 925, "cost_tight": True,
                                         "total_s": 148, "reduce_s": 136.7}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--M", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "discover.json"))
    ap.add_argument("--robust-groups", default=None, help="learning groups for robust pose averaging "
                    "(default: the module's DEFAULT_GROUPS)")
    ap.add_argument("--skip-robust", action="store_true")
    a = ap.parse_args()
    params = {"M": a.M, "sigma": 0.1}
    t = time.perf_counter()
    ours = discover("pose_averaging", params, a.seed, n_heldout=0, compare=False)
    wall = time.perf_counter() - t
    ref = autotight_style("pose_averaging", params, a.seed)
    tm = ours.times
    out = {
        "benchmark": "discover pose_averaging", "params": params, "seed": a.seed, "versions": versions(),
        "ours": {"tight": ours.tight, "n_pairs": len(ours.discovered.pairs), "n_constraints": len(ours.constraints),
                 "n_solves": ours.n_solves, "irreducible": bool(ours.reduction and ours.reduction.irreducible),
                 "breakdown_s": {"sampling": tm["sampling_s"], "nullspace": tm["nullspace_s"],
                                 "sdp_solves": tm["sdp_s"], "tighten": tm["tighten_s"], "reduction": tm["reduce_s"],
                                 "local": tm["local_s"]},
                 "total_s": wall},
        "autotight_style": ref,
        "target": "total < 10 s; fewer SDP solves than AutoTight-style and a set no larger",
        "ratios": {"solves_ours_over_ref": ours.n_solves / ref["n_solves"],
                   "constraints_ours_over_ref": len(ours.constraints) / max(ref["n_constraints"], 1),
                   "time_ours_over_ref": wall / ref["total_s"]},
    }
    out["meets_target"] = bool(wall < 10 and ours.n_solves < ref["n_solves"]
                               and len(ours.constraints) <= ref["n_constraints"])
    if not a.skip_robust:
        out["robust_pose_averaging"] = robust(a.seed, a.robust_groups)
    out["load_average"] = list(os.getloadavg())
    print(json.dumps(jsonable(out), indent=1))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(jsonable(out), indent=1) + "\n")


if __name__ == "__main__":
    main()
