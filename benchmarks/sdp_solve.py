"""Benchmark: the Shor SDP of rotation averaging, direct sparse Clarabel vs a plain cvxpy model.

Both methods solve the same SDP (primary constraints, M measurements, σ = 0.1) in the same run,
with interleaved repetitions (the order alternates every repetition):

- direct: ``autotight.sdp.solve`` (Clarabel called with sparse data, dual form, one PSD cone);
- cvxpy:  ``X = cp.Variable((N, N), PSD=True)``, one ``cp.trace(A @ X) == b`` per constraint,
  ``cp.Minimize(cp.trace(Q @ X))``, solver CLARABEL with the direct path's tolerances.

Two times per solve:
- ``full``: the whole call: for direct, ``sdp.solve`` (sparse data, Clarabel set-up, solve,
  eigen-decomposition of X); for cvxpy, building the cvxpy problem, canonicalisation and solve;
- ``solve``: the solver's iterations only (direct: wall time of ``solver.solve()``;
  cvxpy: ``problem.solver_stats.solve_time`` as reported by Clarabel).

The cvxpy model runs in a separate worker process (spawned once per size, warmed up before the
first timed solve) so that one that exceeds ``--cvxpy-timeout`` seconds or ``--cvxpy-mem-gb`` of
address space can be stopped and reported; its remaining repetitions are then skipped.  After a
time-out the ratio is reported as a lower bound (time limit / direct median); after a crash
(e.g. Clarabel's allocation failing: the plain model hides the aggregate sparsity, so the
N = 310 PSD cone at M = 100 needs a dense (N(N+1)/2)² KKT block, 18.6 GB) no ratio is given.
A third time, ``cpu``, is the process CPU time of the full call: on a loaded shared machine it
is the better guide to what the code costs; the load average is recorded alongside.

Target: direct path under 0.1 s median (full call, wall time) at M = 10; the paper
reports 0.35 s with MATLAB cvx + MOSEK.  Both BLAS pools are limited to one thread.

Usage:  python benchmarks/sdp_solve.py [--reps 7] [--sizes 10 100] [--out PATH]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
TARGET_S = 0.1
PAPER_MOSEK_S = 0.35
PROBLEM = "rotation_averaging"


def _instance(M: int, sigma: float, seed: int):
    from autotight.problem import load

    prob = load(PROBLEM)
    inst = prob.generate({"M": M, "sigma": sigma}, seed)
    t0 = time.perf_counter()
    model = prob.build(inst)
    cons = model.primary()
    return model, cons, time.perf_counter() - t0


def _clarabel_settings() -> dict[str, Any]:
    """The settings the direct path uses (autotight.sdp.clarabel_direct.clarabel_settings, default options)."""
    from autotight.sdp import SolverConfig

    o = SolverConfig()
    return {"tol_gap_abs": o.tol, "tol_gap_rel": o.tol, "tol_feas": o.tol, "tol_ktratio": max(o.tol, 1e-8),
            "max_iter": o.max_iter, "max_threads": o.threads}


def solve_direct(model, cons) -> dict[str, Any]:
    from autotight import sdp

    c0, t0 = time.process_time(), time.perf_counter()
    res = sdp.solve(model.Q, cons, d=model.d)
    full, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"full_s": full, "cpu_s": cpu, "solve_s": res.solve_time_s, "status": res.status, "cost": res.primal_cost,
            "log_svr": res.log_svr}


def solve_cvxpy_plain(model, cons) -> dict[str, Any]:
    import cvxpy as cp

    c0, t0 = time.process_time(), time.perf_counter()
    N = model.variables.N
    X = cp.Variable((N, N), PSD=True)
    constraints = [cp.trace(c.A @ X) == c.b for c in cons]
    problem = cp.Problem(cp.Minimize(cp.trace(model.Q @ X)), constraints)
    problem.solve(solver="CLARABEL", **_clarabel_settings())
    full, cpu = time.perf_counter() - t0, time.process_time() - c0
    stats = problem.solver_stats
    return {"full_s": full, "cpu_s": cpu,
            "solve_s": float(stats.solve_time) if stats.solve_time is not None else float("nan"),
            "status": str(problem.status), "cost": float(problem.value) if problem.value is not None else float("nan"),
            "compile_s": float(problem.compilation_time or float("nan"))}


def _worker(conn, M: int, sigma: float, seed: int, mem_bytes: int, stderr_path: str) -> None:
    """Child process: warm up, then answer each request with one timed plain-cvxpy solve."""
    import warnings

    warnings.filterwarnings("ignore")
    # the solver's own last words (e.g. a failed allocation in Clarabel's Rust core) go to a file
    fd = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(fd, 2)
    if mem_bytes > 0:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (mem_bytes, mem_bytes))
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")  # as in the parent: one BLAS thread
    try:
        m2, c2, _ = _instance(2, sigma, seed)
        solve_cvxpy_plain(m2, c2)  # warm-up: imports, first-call overheads
        model, cons, _ = _instance(M, sigma, seed)
        conn.send({"ready": True})
        while conn.recv() == "solve":
            conn.send(solve_cvxpy_plain(model, cons))
    except (BrokenPipeError, EOFError):  # the parent has gone: nothing to report to
        return
    except MemoryError:
        conn.send({"error": f"MemoryError (address space limited to {mem_bytes / 2**30:.1f} GiB)"})
    except Exception as e:  # report, the parent records it
        conn.send({"error": f"{type(e).__name__}: {e}".splitlines()[0]})


class CvxpyWorker:
    def __init__(self, M: int, sigma: float, seed: int, timeout: float, mem_gb: float):
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        fd, self.stderr_path = tempfile.mkstemp(prefix="sdp_solve_cvxpy_", suffix=".stderr")
        os.close(fd)
        self.proc = ctx.Process(target=_worker, args=(child, M, sigma, seed, int(mem_gb * 2**30), self.stderr_path),
                                daemon=True)
        self.proc.start()
        self.timeout = timeout
        self.failure: str | None = None
        msg = self._recv(600.0, "warm-up")
        if msg is not None and "error" in msg:
            self._fail(msg["error"])

    def _fail(self, why: str) -> None:
        self.failure = why
        self.stop()

    def _recv(self, timeout: float, what: str) -> dict | None:
        if self.conn.poll(timeout):
            try:
                return self.conn.recv()
            except EOFError:
                pass
            self.proc.join(5)
            self._fail(f"worker died during {what} (exit code {self.proc.exitcode}){self._last_words()}")
            return None
        self._fail(f"timeout: {what} did not finish within {timeout:g} s")
        return None

    def solve(self) -> dict | None:
        if self.failure:
            return None
        self.conn.send("solve")
        msg = self._recv(self.timeout, "one solve")
        if msg is not None and "error" in msg:
            self._fail(msg["error"])
            return None
        return msg

    def _last_words(self) -> str:
        try:
            lines = [ln.strip() for ln in Path(self.stderr_path).read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return f": {lines[-1]}" if lines else ""

    def stop(self) -> None:
        if self.proc.is_alive():
            try:
                self.conn.send("stop")
            except (BrokenPipeError, OSError):
                pass
            self.proc.join(2)
        if self.proc.is_alive():
            self.proc.kill()  # only our own worker, by its handle
            self.proc.join(5)
        if os.path.exists(self.stderr_path):
            os.unlink(self.stderr_path)


def _median(xs: list[float]) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def bench_size(M: int, args: argparse.Namespace) -> dict[str, Any]:
    model, cons, build_s = _instance(M, args.sigma, args.seed)
    N = model.variables.N
    print(f"M = {M}: N = {N}, {len(cons)} constraints; starting cvxpy worker …", flush=True)
    m2, c2, _ = _instance(2, args.sigma, args.seed)
    solve_direct(m2, c2)  # warm-up of the direct path
    worker = CvxpyWorker(M, args.sigma, args.seed, args.cvxpy_timeout, args.cvxpy_mem_gb)
    direct: list[dict] = []
    cvx: list[dict] = []
    for rep in range(args.reps):
        order = ("direct", "cvxpy") if rep % 2 == 0 else ("cvxpy", "direct")
        for method in order:
            if method == "direct":
                direct.append(solve_direct(model, cons))
            elif worker.failure is None:
                r = worker.solve()
                if r is not None:
                    cvx.append(r)
        last_c = f"{cvx[-1]['full_s']:.3f}" if cvx else "-"
        print(f"  rep {rep + 1}/{args.reps}: direct {direct[-1]['full_s']:.3f} s, cvxpy {last_c} s"
              f"{'  (' + worker.failure + ')' if worker.failure else ''}", flush=True)
    worker.stop()

    def summary(rows: list[dict]) -> dict[str, Any]:
        return {"full_s": [r["full_s"] for r in rows], "solve_s": [r["solve_s"] for r in rows],
                "cpu_s": [r["cpu_s"] for r in rows],
                "median_full_s": _median([r["full_s"] for r in rows]),
                "median_cpu_s": _median([r["cpu_s"] for r in rows]),
                "median_solve_s": _median([r["solve_s"] for r in rows]),
                "status": sorted({r["status"] for r in rows}), "cost": rows[0]["cost"] if rows else float("nan"),
                "n": len(rows)}

    d, c = summary(direct), summary(cvx)
    d["log_svr"] = direct[0]["log_svr"]
    if cvx:
        c["median_compile_s"] = _median([r["compile_s"] for r in cvx])
    c["failure"] = worker.failure
    out: dict[str, Any] = {"M": M, "N": N, "n_constraints": len(cons), "build_s": build_s, "direct": d, "cvxpy": c}
    if cvx:
        out["ratio_full"] = c["median_full_s"] / d["median_full_s"]
        out["ratio_solve"] = c["median_solve_s"] / d["median_solve_s"]
        out["ratio_is_lower_bound"] = False
        out["cost_rel_diff"] = abs(c["cost"] - d["cost"]) / abs(d["cost"])
    else:  # cvxpy never finished: a time-out bounds the ratio from below; a crash gives no ratio
        timed_out = bool(worker.failure and worker.failure.startswith("timeout"))
        out["ratio_full"] = args.cvxpy_timeout / d["median_full_s"] if timed_out else None
        out["ratio_solve"] = None
        out["ratio_is_lower_bound"] = timed_out
        out["cost_rel_diff"] = None
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100], help="values of M (default 10 100)")
    ap.add_argument("--reps", type=int, default=7, help="repetitions per method and size (default 7)")
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cvxpy-timeout", type=float, default=120.0,
                    help="seconds allowed for one plain-cvxpy solve before it is stopped (default 120)")
    ap.add_argument("--cvxpy-mem-gb", type=float, default=8.0,
                    help="address-space limit of the cvxpy worker in GiB (default 8; 0 = none)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "sdp_solve.json")
    args = ap.parse_args(argv)

    from threadpoolctl import threadpool_limits

    from autotight.io import versions, write_json

    # one BLAS thread in both processes: the matrices are small, and on a shared 2-core machine
    # BLAS threads only add contention (see autotight/threads.py)
    threadpool_limits(limits=1, user_api="blas")
    t0 = time.perf_counter()
    load_before = os.getloadavg()
    sizes = [bench_size(M, args) for M in args.sizes]
    load_after = os.getloadavg()
    by_m = {s["M"]: s for s in sizes}
    target = {"description": f"direct path median full call < {TARGET_S} s at M = 10",
              "threshold_s": TARGET_S, "paper_mosek_s": PAPER_MOSEK_S}
    if 10 in by_m:
        med = by_m[10]["direct"]["median_full_s"]
        cpu = by_m[10]["direct"]["median_cpu_s"]
        target |= {"median_full_s_M10": med, "met": bool(med < TARGET_S),
                   "median_cpu_s_M10": cpu, "met_by_cpu_time": bool(cpu < TARGET_S)}
    record = {
        "benchmark": "sdp_solve", "problem": PROBLEM, "sigma": args.sigma, "seed": args.seed, "reps": args.reps,
        "constraints": "primary (h² = 1, orthonormality, Cayley relation per measurement)",
        "clarabel_settings": _clarabel_settings(), "blas_threads": 1, "cvxpy_timeout_s": args.cvxpy_timeout,
        "cvxpy_mem_gb": args.cvxpy_mem_gb,
        "timing": {"full_s": "whole call incl. set-up (direct: autotight.sdp.solve; cvxpy: build + compile + solve)",
                   "cpu_s": "process CPU time of the full call (less sensitive to other load on a shared machine)",
                   "solve_s": "solver iterations only (direct: solver.solve() wall time; cvxpy: solver_stats)"},
        "sizes": sizes, "target": target,
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "loadavg_1_5_15_before": load_before, "loadavg_1_5_15_after": load_after},
        "versions": versions(), "total_time_s": time.perf_counter() - t0,
    }
    write_json(args.out, record)

    print()
    print(f"{'M':>4} {'N':>4} {'direct full':>12} {'direct solve':>13} {'cvxpy full':>12} {'cvxpy solve':>12} "
          f"{'ratio full':>11} {'ratio solve':>12}  statuses")
    for s in sizes:
        d, c = s["direct"], s["cvxpy"]
        lb = ">" if s["ratio_is_lower_bound"] else ""
        cf = f"{c['median_full_s']:.3f}" if c["n"] else (f">{args.cvxpy_timeout:g}" if lb else "failed")
        cs = f"{c['median_solve_s']:.3f}" if c["n"] else "-"
        rs = f"{s['ratio_solve']:.1f}" if s["ratio_solve"] is not None else "-"
        rf = lb + format(s["ratio_full"], ".1f") if s["ratio_full"] is not None else "-"
        print(f"{s['M']:>4} {s['N']:>4} {d['median_full_s']:>12.4f} {d['median_solve_s']:>13.4f} {cf:>12} {cs:>12} "
              f"{rf:>11} {rs:>12}  direct {d['status']}, cvxpy "
              f"{c['status'] if c['n'] else c['failure']}")
    print("median CPU time of the full call: " + ", ".join(
        f"M = {s['M']}: direct {s['direct']['median_cpu_s']:.3f} s, cvxpy "
        + (f"{s['cvxpy']['median_cpu_s']:.3f} s" if s["cvxpy"]["n"] else "-") for s in sizes))
    print(f"load average (1 min) before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} CPUs")
    if "met" in target:
        print(f"target: direct median {target['median_full_s_M10']:.4f} s wall, {target['median_cpu_s_M10']:.4f} s CPU "
              f"at M = 10 (wall: {'met' if target['met'] else 'NOT met'}, CPU: "
              f"{'met' if target['met_by_cpu_time'] else 'NOT met'}; target < {TARGET_S} s; "
              f"paper, MOSEK: {PAPER_MOSEK_S} s)")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
