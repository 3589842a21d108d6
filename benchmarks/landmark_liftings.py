"""Where is Shor not tight on the landmark problems, and does discovery tighten it?

For each case (problem, d, lifting, σ): solve the SDP with the primary constraints on seeds
0 … n−1 and judge it against the best local solution (truth + 2 random starts).  A seed whose SDP
is rank d but cheaper than every local solution is re-checked: the local solver is started from
the SDP's recovered estimate; if that reaches the SDP cost the relaxation was tight and only the
local solver was trapped (classified "local trapped", not a failure of the relaxation); if instead
some recovered C_k has det −1, the rank-d solution is a reflection (classified "reflection").

On the first ``--discover`` genuinely non-tight seeds, ``discover`` runs (groups "factors", 10
held-out instances) and the result — pairs, constraint count, the readable polynomials of one
pose, held-out tight fraction, or "not tightenable with this lifting" — goes to
``OUT/findings.json`` and ``OUT/findings.md``.  Sets that tighten their learning instance are
saved as ``OUT/sets/<case>_seed<N>.json`` (usable with ``autotight report --discovered``).

    .venv/bin/python benchmarks/landmark_liftings.py --out reports/landmark_liftings
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from autotight.discovery import discover
from autotight.discovery.discovered import constraint_record
from autotight.io import jsonable
from autotight.problem import load
from autotight.pipeline import local_search
from autotight.sdp import solve_model
from autotight.tightness import judge, relative_gap

CASES = [(p, d, lift, s) for p, s in (("pose_graph", 1.0), ("landmark_slam", 1.0))
         for d in (2, 3) for lift in ("matrix", "vector")]


def scan(prob, params: dict, seeds: range) -> list[dict]:
    """Primary-only verdict per seed, with trapped local solves told apart."""
    rows = []
    for s in seeds:
        inst = prob.generate(params, s)
        model = prob.build(inst)
        res = solve_model(model, model.primary())
        loc = local_search(prob, inst, np.random.default_rng([s, 1]), 2)
        v = judge(res, loc.best.cost)
        kind = "tight" if v.tight else "not tight"
        best = loc.best.cost
        if not v.tight and v.rank_tight and res.Theta is not None and res.primal_cost < best:
            est = prob.recover(inst, res.Theta)
            ref = prob.local_solve(inst, est)
            if judge(res, min(best, ref.cost)).tight:
                kind, best = "local trapped", ref.cost
            elif np.min(est["det_raw"]) < 0:
                kind = "reflection"  # rank d, but some C_k has det −1: the relaxation ignores handedness
        rows.append({"seed": s, "verdict": kind, "log_svr": res.log_svr, "sdp_cost": res.primal_cost,
                     "best_local_cost": best, "rel_gap": relative_gap(res.primal_cost, best)})
    return rows


def run_discovery(prob, params: dict, seed: int, sets_dir: Path, tag: str) -> dict:
    t = time.perf_counter()
    res = discover(prob, params, seed, n_heldout=10)
    s = res.record()
    first = res.points[0]
    held = first.heldout
    primary = next(e for e in res.log if e["stage"] == "primary" and e["seed"] == res.example.seed)
    s |= {"message": first.messages[0] or res.validation["message"], "n_minimal": s["n_constraints"],
          "heldout_tight_fraction": None if held is None else held.fraction,
          "heldout_instances": 0 if held is None else len(held.seeds), "log_svr_primary": primary["log_svr"],
          "log_svr": (res.example.tight_result or res.example.last).log_svr}
    first_pose = {}
    for c in res.constraints:  # one pose's / one factor's polynomials (the others are the same by identity)
        key = (c.factor or "").rsplit("_", 1)[0]
        if first_pose.setdefault(key, c.factor) == c.factor:
            rec = constraint_record(c, res.model)
            s.setdefault("readable", []).append(f"[{c.factor}] {rec['readable']}")
    if res.tight and res.discovered.pairs:
        sets_dir.mkdir(parents=True, exist_ok=True)
        res.discovered.save(sets_dir / f"{tag}_seed{seed}.json", res.model, res.constraints, {"summary": s})
    s["wall_s"] = time.perf_counter() - t
    return s


def save_catalogue(name: str, params: dict, seed: int, types: list[str], path: Path) -> int:
    """Every learned (new) identity of the given factor types on one instance, saved as a discovered set.

    The irreducible set of one instance is specific to it at high noise; the whole catalogue of a
    factor type (e.g. all handedness and row relations of a pose) carries over much better.
    """
    from dataclasses import asdict

    from autotight.discovery import DiscoveredSet, LearnOptions, learn

    prob = load(name)
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    cat = learn(prob, inst, model, np.random.default_rng([seed, 1]), types=types)
    pairs = sorted(cat.by_pair())
    ds = DiscoveredSet(prob.name, prob.parse_params(params), seed, pairs, asdict(LearnOptions()),
                       {"note": f"all learned identities of {types}, not reduced"})
    path.parent.mkdir(parents=True, exist_ok=True)
    ds.save(path, model, cat.candidates())
    return len(pairs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="reports/landmark_liftings")
    ap.add_argument("--seeds", type=int, default=10, help="seeds scanned per case (default 10)")
    ap.add_argument("--discover", type=int, default=3, help="non-tight seeds per case run through discovery")
    ap.add_argument("--catalogue-only", action="store_true",
                    help="only save sets/landmark_slam_d3_vector_catalogue.json (all learned pose identities)")
    args = ap.parse_args()
    out = Path(args.out)
    n = save_catalogue("landmark_slam", {"dim": 3, "lifting": "vector", "sigma": 1.0}, 4, ["pose"],
                       out / "sets" / "landmark_slam_d3_vector_catalogue.json")
    print(f"catalogue: {n} pose identities saved", flush=True)
    if args.catalogue_only:
        return
    findings = []
    for name, d, lift, sigma in CASES:
        prob = load(name)
        params = {"dim": d, "lifting": lift, "sigma": sigma}
        tag = f"{name}_d{d}_{lift}_s{sigma:g}"
        rows = scan(prob, params, range(args.seeds))
        bad = [r["seed"] for r in rows if r["verdict"] in ("not tight", "reflection")]
        case = {"case": tag, "problem": name, "params": params, "scan": rows,
                "primary_tight": sum(r["verdict"] == "tight" for r in rows),
                "local_trapped": sum(r["verdict"] == "local trapped" for r in rows),
                "reflection": sum(r["verdict"] == "reflection" for r in rows),
                "not_tight": bad, "discovery": []}
        print(f"{tag}: primary tight {case['primary_tight']}/{len(rows)}, local trapped {case['local_trapped']}, "
              f"of which reflections {case['reflection']}, not tight {bad}", flush=True)
        for seed in bad[:args.discover]:
            s = run_discovery(prob, params, seed, out / "sets", tag)
            case["discovery"].append(s)
            print(f"  seed {seed}: {'TIGHT' if s['tight'] else 'NOT TIGHT'} ({s['message']}); "
                  f"pairs {s['pairs']}, {s['n_minimal']} constraints, held-out {s['heldout_tight_fraction']}",
                  flush=True)
            for line in s.get("readable", []):
                print("    " + line)
        findings.append(case)
    out.mkdir(parents=True, exist_ok=True)
    (out / "findings.json").write_text(json.dumps(jsonable(findings), indent=1, ensure_ascii=False))
    (out / "findings.md").write_text(markdown(findings), encoding="utf-8")


def markdown(findings: list[dict]) -> str:
    lines = ["| case | primary tight (of seeds) | local trapped / reflection | seed | discovery | pairs "
             "| constraints | held-out tight | polynomials (one pose) |", "|" + "---|" * 9]
    for c in findings:
        n = len(c["scan"])
        head = f"| {c['case']} | {c['primary_tight']}/{n} | {c['local_trapped']} / {c['reflection']} "
        if not c["discovery"]:
            lines.append(head + "| — | (no non-tight seed) | | | | |")
        for s in c["discovery"]:
            frac = s["heldout_tight_fraction"]
            frac = "—" if frac is None or frac != frac else f"{frac:.0%} of {s['heldout_instances']}"
            verdict = "tight" if s["tight"] else ("not tightenable with this lifting"
                                                  if "not tightenable" in s["message"] else s["message"])
            polys = "<br>".join(s.get("readable", [])) or "—"
            lines.append(head + f"| {s['seed']} | {verdict} (log SVR {s['log_svr_primary']:.1f} → "
                         f"{s['log_svr']:.1f}) | {', '.join(s['pairs']) or '—'} | {s['n_minimal']} | {frac} | "
                         f"{polys} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
