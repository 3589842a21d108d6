"""Where is Shor not tight on the landmark problems, and does discovery tighten it?

For each case (problem, d, lifting, σ = 1):

1. **Scan.** ``autotight.solve`` with the primary constraints on seeds 0 … n−1 (its verdict: local solves from
   the truth and a random start, and the local solve refined from the SDP's estimate, so a trapped local
   solver is not counted against the relaxation).  A not-tight seed whose SDP is rank d but some recovered
   C_k has det −1 is a **reflection** (O(d) instead of SO(d)); the others are **not tight** (rank > d).
2. **Discover** with the defaults a user types (``autotight.discover(problem, params)``, seed 0: the closed
   loop trains, validates on fresh held-out instances and takes failures in), saved as ``OUT/sets/<case>.json``
   when it is tight on its training instances.
3. **Carry** to the scan's failing seeds: each solved with the discovered set and with the whole learned
   catalogue of the factors (every identity the learner found on discovery's example instance, not reduced).

Writes ``OUT/findings.json`` (every figure, with the versions) and ``OUT/findings.md`` (the table).

    python benchmarks/landmark_liftings.py --out reports/landmark_liftings
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from autotight import api
from autotight.constraint_set import ConstraintSet
from autotight.discovery.discovered import DiscoveredSet, constraint_record
from autotight.io import jsonable, versions
from autotight.problem import Problem, load

CASES = [(p, d, lift, 1.0) for p in ("pose_graph", "landmark_slam") for d in (2, 3) for lift in ("matrix", "vector")]


def classify(res: Any) -> str:
    """"tight", "undecided", "reflection" (rank d, some recovered C_k with det −1) or "not tight"."""
    if res.outcome != "not tight":
        return res.outcome
    det = (res.estimate or {}).get("det_raw")
    return "reflection" if res.verdict.rank_tight and det is not None and np.min(det) < 0 else "not tight"


def scan(prob: Problem, params: dict[str, Any], seeds: range) -> list[dict[str, Any]]:
    """Primary-only verdict per seed (``classify``)."""
    rows = []
    for s in seeds:
        res = api.solve(prob, params, s, constraints="primary")
        rows.append({"seed": s, "verdict": classify(res), "log_svr": res.sdp.log_svr, "upper": res.upper,
                     "sdp_cost": res.sdp.primal_cost, "reason": res.verdict.reason})
    return rows


def readable_per_type(res: Any) -> list[str]:
    """The set's polynomials on the first factor of each factor type (the others are the same identities)."""
    first: dict[str, str | None] = {}
    out = []
    for c in res.constraints:
        key = (c.factor or "").rsplit("_", 1)[0]
        if first.setdefault(key, c.factor) == c.factor:
            out.append(f"[{c.factor}] {constraint_record(c, res.model)['readable']}")
    return out


def catalogue(prob: Problem, params: dict[str, Any], res: Any) -> ConstraintSet | None:
    """Every learned identity of discovery's example instance (its catalog), as a set; None without one."""
    cat = res.catalog
    if cat is None:
        return None
    pairs = sorted(cat.by_pair())
    return ConstraintSet(DiscoveredSet(prob.name, prob.parse_params(params), res.seed, pairs,
                                       res.discovered.learn_options, {"note": "every learned identity, not reduced"},
                                       res.discovered.groups)) if pairs else None


def run_discovery(prob: Problem, params: dict[str, Any], sets_dir: Path, tag: str) -> tuple[dict[str, Any], Any]:
    t = time.perf_counter()
    res = api.discover(prob, params)
    rec = res.record()
    s = {"tight": res.tight, "validated": res.validated, "message": res.validation["message"],
         "pairs": rec["pairs"], "n_pairs": rec["n_pairs"], "n_constraints": rec["n_constraints"],
         "n_candidate_pairs": rec["n_candidate_pairs"],
         "n_trained": sum(len(p["train_seeds"]) for p in rec["points"]),
         "heldout": [p["heldout"] for p in rec["points"]], "readable": readable_per_type(res),
         "n_solves": rec["n_solves"], "wall_s": time.perf_counter() - t}
    if res.tight and res.pairs:
        sets_dir.mkdir(parents=True, exist_ok=True)
        s["set_file"] = str(res.save(sets_dir / f"{tag}.json", replace=True))
    return s, res


def carry(prob: Problem, params: dict[str, Any], seeds: list[int], sets: dict[str, ConstraintSet | None]
          ) -> dict[str, list[dict[str, Any]]]:
    """Per set (None: not available), each seed's verdict with it."""
    return {name: [{"seed": s, "verdict": classify(api.solve(prob, params, s, constraints=cs))} for s in seeds]
            for name, cs in sets.items() if cs is not None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="reports/landmark_liftings")
    ap.add_argument("--seeds", type=int, default=10, help="seeds scanned per case (default 10)")
    args = ap.parse_args()
    out = Path(args.out)
    t0 = time.perf_counter()
    findings = []
    for name, d, lift, sigma in CASES:
        prob = load(name)
        params = {"dim": d, "lifting": lift, "sigma": sigma}
        tag = f"{name}_d{d}_{lift}_s{sigma:g}"
        rows = scan(prob, params, range(args.seeds))
        bad = [r["seed"] for r in rows if r["verdict"] in ("not tight", "reflection")]
        disc, res = run_discovery(prob, params, out / "sets", tag)
        sets = {"discovered": res.constraint_set if res.tight else None, "catalogue": catalogue(prob, params, res)}
        case = {"case": tag, "problem": name, "params": params, "scan": rows,
                "primary_tight": sum(r["verdict"] == "tight" for r in rows),
                "reflection": sum(r["verdict"] == "reflection" for r in rows),
                "undecided": sum(r["verdict"] == "undecided" for r in rows), "not_tight": bad,
                "discovery": disc, "carry": carry(prob, params, bad, sets),
                "n_catalogue_pairs": len(sets["catalogue"].discovered.pairs) if sets["catalogue"] else 0}
        findings.append(case)
        print(summary_line(case), flush=True)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"command": f"python benchmarks/landmark_liftings.py --out {args.out} --seeds {args.seeds}",
            "wall_s": time.perf_counter() - t0, "versions": versions()}
    (out / "findings.json").write_text(json.dumps(jsonable({"meta": meta, "cases": findings}), indent=1,
                                                  ensure_ascii=False))
    (out / "findings.md").write_text(markdown(findings, meta), encoding="utf-8")


def _tight_of(rows: list[dict[str, Any]] | None) -> str:
    return "—" if rows is None else f"{sum(r['verdict'] == 'tight' for r in rows)}/{len(rows)}"


def _heldout(disc: dict[str, Any]) -> str:
    h = [p for p in disc["heldout"] if p]
    return ", ".join(f"{p['tight']} of {p['instances']}" + (f" (+{p['undecided']} undecided)" if p["undecided"]
                                                            else "") for p in h) or "—"


def summary_line(c: dict[str, Any]) -> str:
    disc = c["discovery"]
    return (f"{c['case']}: primary tight {c['primary_tight']}/{len(c['scan'])} (reflections {c['reflection']}, "
            f"not tight {c['not_tight']}); discovery {'tight' if disc['tight'] else 'NOT TIGHT'}, validated "
            f"{disc['validated']}, {disc['n_pairs']} pairs ({disc['n_constraints']} constraints), held-out "
            f"{_heldout(disc)}, {disc['wall_s']:.0f} s; failing seeds tight with the set "
            f"{_tight_of(c['carry'].get('discovered'))}, with the catalogue {_tight_of(c['carry'].get('catalogue'))}")


def markdown(findings: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    lines = [f"Generated by `{meta['command']}` ({meta['wall_s']:.0f} s; versions in findings.json).", "",
             "| case | primary tight (of seeds) | reflection / rank > d / undecided | discovery (defaults) "
             "| pairs (constraints) | held-out tight | failing seeds tight: set / catalogue (pairs) "
             "| polynomials (one factor per type) |", "|" + "---|" * 8]
    for c in findings:
        n, disc = len(c["scan"]), c["discovery"]
        rank = len(c["not_tight"]) - c["reflection"]
        verdict = ("validated" if disc["validated"] else "validation failed" if disc["tight"]
                   else "not tight on training") + f" ({disc['n_trained']} training instances, {disc['wall_s']:.0f} s)"
        polys = "<br>".join(disc["readable"]) or "—"
        lines.append(f"| {c['case']} | {c['primary_tight']}/{n} | {c['reflection']} / {rank} / {c['undecided']} "
                     f"| {verdict} | {disc['n_pairs']} ({disc['n_constraints']}) | {_heldout(disc)} "
                     f"| {_tight_of(c['carry'].get('discovered'))} / {_tight_of(c['carry'].get('catalogue'))} "
                     f"({c['n_catalogue_pairs']}) | {polys} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
