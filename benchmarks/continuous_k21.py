"""Continuous-time trajectory at the paper's K = 21: SDP paths side by side, and the
prototype of the fastest one (``solve_fast``) that reports/continuous_boundary also uses.

Every path solves the same optimum (problems/continuous_trajectory.py, module docstring):
- ``marginalised``: ϖ removed by the Schur complement (the paper), Clarabel's chordal decomposition;
- ``kept-clarabel``: ϖ kept, Clarabel on our clique cover (``solve --decompose``, 9–10 s when first measured);
- ``kept-ipm``: ϖ kept, our IPM on its own cover;
- ``kept-ipm-scaled``: as kept-ipm, after the block congruence X = D X′ D of ``block_scale``;
- ``kept-ipm-fast``: as kept-ipm-scaled at the tolerance FAST_TOL (``solve_fast``, the fastest path).
``independent`` (not a method: measured, no gain) leaves out constraints that are linear
combinations of the others (R7 at the three measured states is in the span of the primary
constraints and R1–R6): 22 instead of 23 iterations, and its Gram–Schmidt costs more than it saves.
Times: wall (the machine is shared, so also CPU time of the process, which with one BLAS thread is
what the solve costs on an idle core).  Log SVR on the marginalised X (``marginal_log_svr``).

Measured (results/continuous_k21.json; load 8–13, so CPU seconds): σ = 0.1, seeds 0–1, median CPU
marginalised 73.4 s, kept-clarabel 9.1 s, kept-ipm 3.5 s (AlmostSolved), kept-ipm-scaled 3.2 s
(AlmostSolved), kept-ipm-fast 2.5 s (Solved, 22–23 iterations); every one tight on both seeds.
On an idle machine (load 0.2, before the studies) kept-ipm took 2.4 s wall.  The σ sweep (seeds 0–4):
the fast path's IPM finishes at σ = 0.1 (4/5) and on 2 of 5 at σ = 0.0316, 0.316 and 1, never at
σ ≤ 0.01 (it stalls at a relative gap of 4e-5 … 1e-3: the WNOA terms that cancel in ⟨Q, X⟩ are
1e4–1e5 × the optimal cost there, beyond the IPM's accuracy); Clarabel's re-solve then makes it
11–16 s.  At ``--tol 1e-5`` the IPM finishes all 20 solves with σ ≥ 0.0316 in 1.8–3.2 s with the
same verdicts (``sweep_fastest_tol_1e-05``); its log SVR matches the IPM's at 1e-6 where both finish
and is up to 3 decades below Clarabel's re-solves at 1e-9, above 5 wherever those were tight.

    python benchmarks/continuous_k21.py [--seeds 0,1,2] [--methods …] [--sigmas 0.1] [--time-limit 120]
    python benchmarks/continuous_k21.py --sweep --seeds 0,1,2,3,4     # σ sweep, fastest path only
Writes benchmarks/results/continuous_k21.json.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_triangular

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from autotight import sdp  # noqa: E402
from autotight.io import jsonable, versions  # noqa: E402
from autotight.model import Constraint, Model  # noqa: E402
from autotight.problem import Instance, load  # noqa: E402
from autotight.sdp import SDPResult, SolverConfig, model_cover  # noqa: E402
from autotight.sdp.schur_ipm import solve_ipm  # noqa: E402
from autotight.threads import single_blas_thread  # noqa: E402
from problems import continuous_trajectory as ct  # noqa: E402

PROB = load("continuous_trajectory")
METHODS = ("marginalised", "kept-clarabel", "kept-ipm", "kept-ipm-scaled", "kept-ipm-fast")
#: relative size of a Gram-matrix pivot below which a constraint counts as a linear combination of
#: those before it (constraint vectors [svec A, b] normalised to unit length; rounding is ~1e-15)
INDEPENDENT_RTOL = 1e-9


def independent(constraints: Sequence[Constraint], rtol: float = INDEPENDENT_RTOL) -> list[Constraint]:
    """The constraints in order, leaving out each one whose [A, b] is a linear combination of those
    kept before it: a pivoted Cholesky of the Gram matrix of the normalised vectors (m × m, sparse
    products only).  The feasible set is unchanged; the SDP's Schur matrix becomes nonsingular."""
    rows = []
    for c in constraints:
        A = sp.coo_array(c.A)
        keep = A.row <= A.col
        v = np.concatenate([A.data[keep] * np.where(A.row[keep] == A.col[keep], 1.0, np.sqrt(2.0)), [c.b]])
        rows.append((A.row[keep], A.col[keep], v / np.linalg.norm(v)))
    N = constraints[0].A.shape[0]
    r = np.concatenate([np.full(len(v), i) for i, (_, _, v) in enumerate(rows)])
    col = np.concatenate([np.append(a * N + b, N * N) for a, b, _ in rows])
    M = sp.csr_array((np.concatenate([v for _, _, v in rows]), (r, col)), shape=(len(rows), N * N + 1))
    G = (M @ M.T).toarray()
    kept: list[int] = []
    L = np.zeros((len(rows), len(rows)))
    for i in range(len(rows)):  # Gram–Schmidt in the order given, on the Gram matrix
        li = solve_triangular(L[np.ix_(kept, kept)], G[kept, i], lower=True) if kept else np.zeros(0)
        resid = G[i, i] - li @ li
        if resid > rtol:
            L[i, kept] = li
            L[i, i] = np.sqrt(resid)
            kept.append(i)
    return [constraints[i] for i in kept]


@dataclass
class FastSolve:
    """A solve of the ϖ-kept SDP by ``solve_fast``: the result (X unscaled, cost in the original
    units), the cover it was solved on, and the log SVR of the marginalised X."""

    res: SDPResult
    cliques: list[np.ndarray]
    log_svr_marginal: float
    cost: float
    wall_s: float
    cpu_s: float


#: the IPM's tolerance on the fast path: at 1e-7 (its floor) the K = 21 solves end with 6 iterations
#: that make no progress (AlmostSolved after 28–29); at 1e-6 they stop Solved after 22–23 at the same
#: iterate (costs within 4e-7 of the local optimum, dual within 6e-9), 25 % less time
FAST_TOL = 1e-6


def solve_fast(inst: Instance, model: Model, constraints: Sequence[Constraint], *, scale: bool = True,
               drop_dependent: bool = False, options: SolverConfig | None = None) -> FastSolve:
    """The IPM on the ϖ-kept model (instance with marginalize=False), on its own cover, optionally after
    the congruence X = D X′ D (D = ``ct.block_scale``) and without linearly dependent constraints.
    When the IPM ends unusable, Clarabel re-solves (its default tolerance, Clarabel's cover; counted)."""
    t, c0 = time.perf_counter(), time.process_time()
    cons = independent(constraints) if drop_dependent else list(constraints)
    cl, fallback = model_cover(model, cons, "ipm"), model_cover(model, cons, "clarabel")
    D = ct.block_scale(inst) if scale else np.ones(model.variables.N)
    Dm = sp.diags(D)
    Q = sp.csr_array(Dm @ model.Q @ Dm)
    cs = [Constraint(sp.csr_array(Dm @ c.A @ Dm), c.b, name=c.name, family=c.family) for c in cons]
    res = solve_ipm(Q, [c.A for c in cs], np.array([c.b for c in cs]), 1, cl, options or SolverConfig(tol=FAST_TOL))
    if not res.usable:  # as sdp.solve does, but Clarabel at its own default tolerance, not the IPM's
        first = f"ipm: {res.status} ({res.message.strip()}, {res.solve_time_s:.2f} s, counted in solve_time_s)"
        spent = res.solve_time_s + res.setup_time_s
        res = sdp.solve(Q, cs, cliques=fallback, config=SolverConfig(decompose=True, scale="none"))
        res.message, res.solve_time_s = f"{first}; solved again by {res.solver}: {res.status}", res.solve_time_s + spent
    used = cl if res.solver.endswith("ipm") else fallback
    cost = float("nan")
    if res.X is not None:
        res.X = res.X * np.outer(D, D)
        cost = float(np.sum(model.Q.multiply(res.X)))
    wall, cpu = time.perf_counter() - t, time.process_time() - c0
    msvr = ct.marginal_log_svr(inst, res.X, used) if res.usable else float("nan")
    return FastSolve(res, used, msvr, cost, wall, cpu)


# ----------------------------------------------------------------------------- the benchmark


def _record(inst: Instance, model: Model, res: SDPResult, cliques, cost: float, wall: float, cpu: float) -> dict:
    local = PROB.local_solve(inst, inst.truth)
    msvr = ct.marginal_log_svr(inst, res.X, cliques) if res.usable else float("nan")
    return {"status": res.status, "solver": res.solver, "iterations": res.iterations, "wall_s": wall, "cpu_s": cpu,
            "sdp_cost": cost, "sdp_dual_cost": res.dual_cost, "local_cost": local.cost,
            "rel_gap": (local.cost - cost) / abs(local.cost),
            "dual_gap": (local.cost - res.dual_cost) / abs(local.cost),
            "log_svr_cliques": res.log_svr, "log_svr_marginal": msvr, "N": model.variables.N,
            "message": res.message}


@single_blas_thread
def run_method(method: str, params: dict, seed: int, fast_tol: float = FAST_TOL) -> dict:
    """One solve of the paper's families (primary + R1–R8) by ``method``; times cover the whole
    SDP step (cover choice, scaling, solve) and not the build or the local solve."""
    from autotight.sdp.chordal import column_cliques

    inst = PROB.generate(dict(params, marginalize=method == "marginalised"), seed)
    model = PROB.build(inst)
    cons = model.primary() + model.paper_constraints()
    if method in ("kept-ipm-scaled", "kept-ipm-fast"):
        fs = solve_fast(inst, model, cons, options=SolverConfig(tol=1e-7 if method == "kept-ipm-scaled" else fast_tol))
        return _record(inst, model, fs.res, fs.cliques, fs.cost, fs.wall_s, fs.cpu_s)
    t, c0 = time.perf_counter(), time.process_time()
    if method == "marginalised":
        res = sdp.solve_model(model, cons, SolverConfig(scale="none"))
        cl = column_cliques(model.variables.N, [model.Q, *[c.A for c in cons]], always=[0])
    else:
        solver = "ipm" if method == "kept-ipm" else "clarabel"
        res = sdp.solve_model(model, cons, SolverConfig(backend=solver, decompose=True, scale="none"))
        cl = res.cliques
    wall, cpu = time.perf_counter() - t, time.process_time() - c0
    return _record(inst, model, res, cl, res.primal_cost, wall, cpu)


def _child(q, method: str, params: dict, seed: int, fast_tol: float) -> None:
    q.put(run_method(method, params, seed, fast_tol))


def bounded(method: str, params: dict, seed: int, time_limit: float, fast_tol: float = FAST_TOL) -> dict:
    """run_method in a child process, killed after time_limit wall seconds."""
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    proc = ctx.Process(target=_child, args=(q, method, params, seed, fast_tol))
    proc.start()
    try:
        out = q.get(timeout=time_limit)
    except Exception:  # queue.Empty: over the limit, or the child died
        out = {"status": f"killed after {time_limit:g} s" if proc.is_alive() else f"crashed (exit {proc.exitcode})",
               "wall_s": time_limit, "cpu_s": float("nan")}
    proc.terminate()
    proc.join()
    return dict(out, method=method, seed=seed, params=params)


def _summary(runs: list[dict]) -> dict:
    ok = [r for r in runs if "sdp_cost" in r]
    med = lambda k: float(np.median([r[k] for r in ok])) if ok else float("nan")  # noqa: E731
    tight = [bool(r["log_svr_marginal"] >= 5 and r["rel_gap"] <= 1e-4) for r in ok]
    return {"median_wall_s": float(np.median([r["wall_s"] for r in runs])), "median_cpu_s": med("cpu_s"),
            "status": sorted({r["status"] for r in runs}), "solver": sorted({r.get("solver", "") for r in ok}),
            "median_iterations": med("iterations"), "tight": f"{sum(tight)}/{len(runs)}",
            "log_svr_marginal": [r["log_svr_marginal"] for r in ok], "rel_gap_max": max((abs(r["rel_gap"]) for r in ok),
                                                                                       default=float("nan"))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--sigmas", default="0.1")
    ap.add_argument("--sweep", action="store_true",
                    help="the fastest path only, over --sigmas (default: the paper's 7)")
    ap.add_argument("--time-limit", type=float, default=150.0)
    ap.add_argument("--tol", type=float, default=FAST_TOL, help="the IPM's tolerance on the fastest path")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "continuous_k21.json"))
    a = ap.parse_args()
    seeds = [int(x) for x in a.seeds.split(",")]
    out_path = Path(a.out)
    res = json.loads(out_path.read_text()) if out_path.is_file() else {}
    res.update({"benchmark": "continuous_k21", "problem": "continuous_trajectory",
                "params": {"K": 21, "preset": "paper"},
                "constraints": "primary + R1–R8", "versions": versions(), "load_avg_start": os.getloadavg(),
                "note": "cpu_s: CPU time of the solving process (one BLAS thread), what the solve costs on an idle "
                        "core; wall_s on a machine shared with other jobs"})
    def save() -> None:  # after every run: an interrupted benchmark keeps what it measured
        res["load_avg_end"] = os.getloadavg()
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(json.dumps(jsonable(res), indent=1) + "\n")

    if a.sweep:
        sigmas = [0.001, 0.00316, 0.01, 0.0316, 0.1, 0.316, 1.0] if a.sigmas == "0.1" else \
            [float(x) for x in a.sigmas.split(",")]
        runs_by: dict[str, list[dict]] = {str(sig): [] for sig in sigmas}
        key = "sweep_fastest" if a.tol == FAST_TOL else f"sweep_fastest_tol_{a.tol:g}"
        res[key] = {"method": "kept-ipm-fast", "ipm_tol": a.tol, "seeds": seeds, "by_sigma": {}}
        for s in seeds:  # seed-major: an interrupted sweep still covers every σ
            for sig in sigmas:
                runs_by[str(sig)].append(bounded("kept-ipm-fast", {"K": 21, "sigma": sig}, s, a.time_limit, a.tol))
                r = runs_by[str(sig)][-1]
                print("sweep σ", sig, s, r["status"], r.get("solver"), f"cpu {r.get('cpu_s', float('nan')):.2f}",
                      f"svr {r.get('log_svr_marginal', float('nan')):.2f} "
                      f"gap {r.get('rel_gap', float('nan')):.1e}", flush=True)
                res[key]["by_sigma"] = {k: dict(_summary(v), runs=v) for k, v in runs_by.items() if v}
                save()
    else:
        methods = a.methods.split(",")
        for sig in [float(x) for x in a.sigmas.split(",")]:
            runs: dict[str, list[dict]] = {m: [] for m in methods}
            for s in seeds:  # methods interleaved, so load changes hit every method alike
                for m in methods:
                    runs[m].append(bounded(m, {"K": 21, "sigma": sig}, s, a.time_limit))
                    r = runs[m][-1]
                    print(m, sig, s, r["status"], f"wall {r['wall_s']:.2f} cpu {r.get('cpu_s', float('nan')):.2f}",
                          f"svr {r.get('log_svr_marginal', float('nan')):.2f}", flush=True)
                    res[f"methods_sigma_{sig:g}"] = {m: dict(_summary(rs), runs=rs) for m, rs in runs.items() if rs}
                    save()


if __name__ == "__main__":
    main()
