"""Refuse work that cannot fit, before it starts: an estimate of the memory or time it needs.

Sizes (``check_size``): an integer parameter far above its default (more than ``PROBE_FACTOR`` ×
the default and more than ``PROBE_MIN``) is probed: the problem is built at 1, 2 and 3 × the
default (the other parameters as given, or at their defaults when they are probed too), and the
lifting size N and the SDP data's nonzeros (Q and the primary constraints) are extrapolated by the
quadratic through those three points, summed over the probed parameters.  The memory estimate is
``BYTES_PER_NONZERO`` per nonzero of the data plus ``BYTES_PER_DENSE_ENTRY`` per entry of the
N × N solution X, fitted to the peak RSS of ``autotight solve`` on rotation averaging with M = 50,
200, 400 (89, 173, 350 MB); the run is refused when it exceeds the memory available.  A solve on
our clique cover (``--solver ipm``, ``--decompose``; ``holds_dense_x``) keeps X on the cliques' pattern
above ``DENSE_X_MAX`` columns: there no dense X counts, and the memory is ``COVER_BASE_BYTES`` plus a
linear term in the nonzeros, fitted to long discrete trajectories, and a quadratic one where Clarabel may
solve again (see those constants).

Certify (``check_certify_size``) never forms X nor the full SDP on large problems (``autotight.certifier``):
its memory is ``CERTIFY_BYTES_PER_NONZERO`` per nonzero of the same data, fitted to the peak RSS of
``autotight certify`` on discrete trajectory with the set learned at K = 5 (see that constant).

Counts (``check_count``): trials, instances, random starts, held-out and training instances, samples:
n × the measured time of one item (by default one local solve from the ground truth, a lower bound:
every item does at least that; ``local_solve_seconds(start="random")`` for random starts,
``sample_seconds`` for samples) must stay below a budget: ``MAX_SECONDS`` for sweeps and discovery
(report, check, discover), ``ONE_RUN_SECONDS`` for the work on one instance (``solve --random-starts``,
``check-module --samples``).  Counts up to ``COUNT_FREE`` are never timed, so a refusal costs a
few local solves (well under a second on the shipped problems).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from .errors import ParameterError
from .sdp import BACKENDS, FALLBACK_MAX_N, decomposes
from .sdp.config import AUTO, SolverConfig
from .sdp.result import DENSE_X_MAX

PROBE_FACTOR = 4
#: certify's peak RSS per nonzero of the SDP data (Q and the primary constraints), redundant constraints
#: included: discrete trajectory K = 1000 with the set learned at K = 5 (3.6 constraints per primary one),
#: 0.46 GB peak for 4.9e5 nonzeros (930 B each)
CERTIFY_BYTES_PER_NONZERO = 1000.0
PROBE_MIN = 64
BYTES_PER_NONZERO = 3000.0
#: a solve on a clique cover above DENSE_X_MAX columns (X sparse on the cliques' pattern): peak RSS =
#: COVER_BASE_BYTES + COVER_BYTES_PER_NONZERO · z, z the nonzeros of Q and the primary constraints, plus
#: COVER_BYTES_PER_NONZERO_SQUARED · z² where the SDP layer may hand an unusable result to Clarabel's chordal
#: solve (N ≤ ``sdp.FALLBACK_MAX_N``), whose memory grows faster (at K = 4000 it passed 21 GB).  Discrete
#: trajectory solved by the IPM with the set learned at K = 5 (3.6 redundant constraints per primary one),
#: whole ``solve`` pipeline: 0.83, 1.59, 3.24 and 7.86 GB at K = 1000, 2000, 4000 and 10 000
#: (z = 4.9e5 … 4.9e6), linear at about 1540 B per nonzero
COVER_BASE_BYTES = 3e8
COVER_BYTES_PER_NONZERO = 1600.0
COVER_BYTES_PER_NONZERO_SQUARED = 1e-3
BYTES_PER_DENSE_ENTRY = 100.0
MAX_SECONDS = 24 * 3600.0
ONE_RUN_SECONDS = 600.0
COUNT_FREE = 1000


class SizeError(ParameterError):
    """A run that cannot fit in memory or finish in reasonable time."""


@dataclass(frozen=True)
class SizeEstimate:
    N: float
    nonzeros: float
    dense_x: bool = True

    @property
    def bytes(self) -> float:
        if self.dense_x or self.N <= DENSE_X_MAX:
            return self.nonzeros * BYTES_PER_NONZERO + self.N * self.N * BYTES_PER_DENSE_ENTRY
        z = self.nonzeros
        fallback = z * z * COVER_BYTES_PER_NONZERO_SQUARED if self.N <= FALLBACK_MAX_N else 0.0
        return COVER_BASE_BYTES + z * COVER_BYTES_PER_NONZERO + fallback


def holds_dense_x(config: SolverConfig | None) -> bool:
    """Whether a solve with ``config`` may hold X dense: every solve but one on our clique cover
    (``--solver ipm``, or ``--decompose``), whose X above DENSE_X_MAX columns is sparse."""
    if config is None:
        return True
    if config.backend == AUTO:  # decompose given: either backend it picks takes a cover; else as the size decides
        return True if config.decompose is None else holds_dense_x(replace(config, backend="clarabel"))
    return not (decomposes(config) and BACKENDS[config.backend_name].cover is not None)


def _measure(problem: Any, params: dict[str, Any]) -> tuple[int, int]:
    inst = problem.generate(params, 0)
    model = problem.build(inst)
    nnz = model.Q.nnz + sum(c.A.nnz for c in model.primary())  # as stored (canonical: no duplicates)
    return model.variables.N, nnz


def _extrapolate(xs: Sequence[float], ys: Sequence[float], x: float) -> float:
    """The quadratic through (xs, ys) at x, its curvature clipped at 0 (growth at least linear)."""
    a2, a1, a0 = np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 2)
    if a2 < 0:
        a1, a0 = np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 1)
        a2 = 0.0
    return float(a2 * x * x + a1 * x + a0)


def probed(problem: Any, params: dict[str, Any]) -> dict[str, int]:
    """The integer parameters far above their defaults (see the module docstring)."""
    out = {}
    for k, p in problem.params.items():
        if type(p.default) is int and isinstance(params.get(k), int) and not isinstance(params[k], bool):
            base = max(p.default, 1)
            if params[k] > max(PROBE_FACTOR * base, PROBE_MIN):
                out[k] = base
    return out


def estimate_size(problem: Any, params: dict[str, Any], dense_x: bool = True) -> SizeEstimate | None:
    """N and the nonzeros at ``params`` (parsed), or None when no parameter needs probing."""
    big = probed(problem, params)
    if not big:
        return None
    base = dict(params, **big)
    N0, z0 = _measure(problem, base)
    N, z = float(N0), float(z0)
    for k, a in big.items():
        pts = [(N0, z0)] + [_measure(problem, dict(base, **{k: m * a})) for m in (2, 3)]
        xs = [a, 2 * a, 3 * a]
        N += _extrapolate(xs, [q[0] for q in pts], params[k]) - N0
        z += _extrapolate(xs, [q[1] for q in pts], params[k]) - z0
    return SizeEstimate(N, z, dense_x)


def available_memory() -> float:
    """Bytes of memory available (MemAvailable on Linux, else physical memory)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return float("inf")


def _gb(b: float) -> str:
    return f"{b / 1e9:.3g} GB"


def check_size(problem: Any, params: dict[str, Any], config: SolverConfig | None = None) -> SizeEstimate | None:
    """Refuse parameters whose SDP data would not fit in memory (``SizeError``) with the solver of
    ``config`` (default: one that may hold X dense); returns the estimate."""
    est = estimate_size(problem, params, holds_dense_x(config))
    if est is None:
        return None
    if config is not None and est.dense_x and config.backend == AUTO:  # what "auto" picks at this size
        est = replace(est, dense_x=holds_dense_x(config.for_size(int(est.N))))
    avail = available_memory()
    if est.bytes > avail:
        given = ", ".join(f"{k}={params[k]}" for k in probed(problem, params))
        raise SizeError(f"{problem.name} with {given}: the SDP would have N ≈ {est.N:.3g} columns and "
                        f"≈ {est.nonzeros:.3g} nonzeros, needing about {_gb(est.bytes)} of memory; "
                        f"{_gb(avail)} available")
    return est


def check_certify_size(problem: Any, params: dict[str, Any]) -> SizeEstimate | None:
    """``check_size`` for ``autotight certify``: the memory it needs is ``CERTIFY_BYTES_PER_NONZERO`` per
    nonzero of the data (no X, no full SDP above ``certifier.FALLBACK_MAX_N`` columns); ``SizeError`` when
    that exceeds the memory available; returns the estimate."""
    from .certifier import FALLBACK_MAX_N

    est = estimate_size(problem, params, dense_x=False)
    if est is None:
        return None
    need = est.nonzeros * CERTIFY_BYTES_PER_NONZERO
    if est.N < FALLBACK_MAX_N:  # the full SDP may be solved as the fallback
        need = max(need, est.bytes)
    avail = available_memory()
    if need > avail:
        given = ", ".join(f"{k}={params[k]}" for k in probed(problem, params))
        raise SizeError(f"{problem.name} with {given}: certify would need about {_gb(need)} of memory (N ≈ "
                        f"{est.N:.3g} columns, ≈ {est.nonzeros:.3g} nonzeros of data); {_gb(avail)} available")
    return est


def _duration(s: float) -> str:
    for unit, n, start in (("years", 365 * 86400, 2), ("days", 86400, 2), ("h", 3600, 1), ("min", 60, 1)):
        if s >= start * n:
            return f"{s / n:.3g} {unit}"
    return f"{s:.3g} s"


def local_solve_seconds(problem: Any, params: dict[str, Any], start: str = "truth") -> float:
    """The time of one generate + local solve at ``params`` (seed 0) from the ground truth, or from a random
    state (``start="random"``, the start of ``solve --random-starts``)."""
    t0 = time.perf_counter()
    inst = problem.generate(params, 0)
    init = inst.truth if start == "truth" else problem.random_state(inst, np.random.default_rng(0))
    problem.local_solve(inst, init)
    return time.perf_counter() - t0


def sample_seconds(problem: Any, params: dict[str, Any], n: int = 3) -> float:
    """The time of one sample + lift at ``params`` (seed 0; the mean of ``n``, after generate and build)."""
    inst = problem.generate(params, 0)
    problem.build(inst)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for _ in range(n):
        problem.lift(inst, problem.sample(inst, rng))
    return (time.perf_counter() - t0) / n


def count_arg(n: Any, option: str, low: int = 0) -> int:
    """``n`` as an int ≥ ``low`` (a bool, a float or a string is refused), else ParameterError naming ``option``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < low:
        raise ParameterError(f"{option} must be an int ≥ {low}, got {n!r}")
    return int(n)


def check_count(problem: Any, params: dict[str, Any], option: str, n: int, per_item: float = 1.0,
                what: str = "items", *, budget: float = MAX_SECONDS, seconds: Any = None) -> None:
    """Refuse ``n`` items (each at least ``per_item`` × the time of ``seconds(problem, params)``, default one local
    solve from the truth) that would take more than ``budget`` seconds."""
    if n <= COUNT_FREE:
        return
    t = (seconds or local_solve_seconds)(problem, params)
    total = n * per_item * t
    if total > budget:
        raise SizeError(f"{option}: {n} {what} would take at least {_duration(total)} (one alone takes "
                        f"{t * 1e3:.3g} ms here); at most about {int(budget / (per_item * t))} fit in "
                        f"{_duration(budget)}")


def check_random_starts(problem: Any, params: dict[str, Any], n: Any, option: str = "n_random") -> int:
    """``n`` random-start local solves on one instance: an int ≥ 0 that fits in ``ONE_RUN_SECONDS``."""
    n = count_arg(n, option)
    check_count(problem, params, f"{option} {n}", n, what="random-start local solves", budget=ONE_RUN_SECONDS,
                seconds=lambda p, q: local_solve_seconds(p, q, start="random"))
    return n
