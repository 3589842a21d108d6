"""Clarabel called directly with sparse data.

Dense cone (one PSD block), dual form:
    max bᵀy  s.t.  s = Q − Σ yᵢ Aᵢ ∈ PSD,
i.e. Clarabel's  min −bᵀy  s.t.  [svec A₁ … svec A_m] y + s = svec Q,  s ∈ PSDTriangleConeT(N).
The cone's dual variable z is svec(X) of the primal  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

Clique form: the block program of ``clique_program`` (Agler's theorem on a clique tree), whose
dual Clarabel solves with one PSDTriangleConeT per clique; the cones' dual variables are the blocks.

This backend's own options are ``ClarabelOptions`` (``SolverConfig.clarabel``); ``clarabel_settings``
turns a config into Clarabel's settings.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Sequence

import clarabel
import numpy as np
import scipy.sparse as sp

from ..svec import smat, svec_columns, svec_dim
from .clique_program import clique_program, complete_auto, complete_from_cliques, cost_scale
from ..errors import SolverConfigError
from .config import Retries, SolverConfig
from .result import SDPResult, Status, finish

#: from this many columns of X on, Clarabel factors its KKT system with its supernodal solver "faer"
#: (Clarabel ≥ 0.10, bundled, Apache-2.0) instead of qdldl.  Measured side by side (clarabel 0.11.1, one
#: process alternating, 2 repeats, load ~14): discrete trajectory K = 20 (N = 475) SDP 16.0/20.5 s against
#: 19.3/24.6 s, continuous K = 21 (N = 517) 54.5/63.9 s against 73.9/68.2 s; but pose averaging M = 10
#: (N = 73) 0.51/0.58 s against 0.42/0.50 s and rotation averaging (N = 40) equal, so small SDPs keep
#: Clarabel's default.  Costs agree to 6e-11 relative.
FAER_MIN_N = 200


def kkt_solver(N: int) -> str:
    """Clarabel's ``direct_solve_method`` for an SDP of N columns (``FAER_MIN_N``; pyproject requires
    clarabel ≥ 0.10, which has faer); below it Clarabel's own default ("auto"), so small SDPs are solved
    exactly as before (forcing "qdldl" there changed the path of degenerate solves: pose averaging M = 10
    with the primary constraints only ended AlmostSolved instead of Solved)."""
    return "faer" if N >= FAER_MIN_N else "auto"


def clarabel_settings(config: SolverConfig, N: int = 0, chordal: bool | None = None) -> "clarabel.DefaultSettings":
    """Clarabel's settings for a solve of an SDP of N columns with ``config``: its accuracy and limits,
    ``config.clarabel``'s regularisation, and Clarabel's chordal decomposition when ``chordal`` (None:
    ``config.clarabel.chordal``) with ``config.clarabel.merge``."""
    o = config.clarabel
    chordal = o.chordal if chordal is None else chordal
    s = clarabel.DefaultSettings()
    s.direct_solve_method = kkt_solver(N)
    s.verbose = config.verbose
    s.max_iter = config.max_iter
    s.time_limit = config.time_limit
    s.tol_gap_abs = config.tol * 1e-3  # the scaled cost can be ≪ 1: keep the relative gap in charge
    s.tol_gap_rel = config.tol
    s.tol_feas = config.tol
    s.tol_ktratio = max(config.tol, 1e-8)
    if config.threads:
        s.max_threads = config.threads
    if o.regularization == "small":
        # Tight relaxations have rank-deficient PSD blocks; the default static regularisation (1e-8)
        # then limits accuracy (AlmostSolved, costs ~1e-5 off).  A smaller one solves them to tol.
        s.static_regularization_constant = 1e-10
        s.static_regularization_proportional = 1e-16
        s.dynamic_regularization_enable = False
    # Clarabel decomposes by default; "dense" must mean dense, so it is on only when asked for
    s.chordal_decomposition_enable = chordal
    if chordal:
        s.chordal_decomposition_complete_dual = True
        s.chordal_decomposition_merge_method = o.merge
    return s


def _sdp_status(clarabel_status: object) -> str:
    """Clarabel's status as a ``Status``.  Clarabel solved the SDP's dual: its "primal infeasible" is our
    dual infeasible and vice versa.  A status this version of Clarabel added stays its own string."""
    s = str(clarabel_status).rsplit(".", 1)[-1]
    for a, b in (("PrimalInfeasible", "DualInfeasible"), ("DualInfeasible", "PrimalInfeasible")):
        if s.endswith(a):
            s = s[: -len(a)] + b
            break
    return Status(s) if s in Status.__members__.values() else s


def solve_dense(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
                opts: SolverConfig) -> SDPResult:
    """One PSD cone of size N, dual form."""
    t0 = time.perf_counter()
    N = Q.shape[0]
    c = cost_scale(Q)
    Acl = svec_columns(As, N)
    bcl = (svec_columns([Q], N) * c).toarray().ravel()
    m = Acl.shape[1]
    P = sp.csc_matrix((m, m))
    solver = clarabel.DefaultSolver(P, -np.asarray(b, float), sp.csc_matrix(Acl), bcl,
                                    [clarabel.PSDTriangleConeT(N)], clarabel_settings(opts, N))
    t1 = time.perf_counter()
    sol = solver.solve()
    t2 = time.perf_counter()
    status = _sdp_status(sol.status)
    z = np.asarray(sol.z, float)
    X = smat(z, N) if z.size == svec_dim(N) and np.all(np.isfinite(z)) else None
    y = np.asarray(sol.x, float) / c
    primal = float((Q.multiply(X)).sum()) if X is not None else float("nan")
    dual = float(np.dot(b, y))
    svrs = cliques = None
    chordal = opts.clarabel.chordal
    if chordal and X is not None:
        # Clarabel completes X off the pattern with some PSD completion, not the rank-d one:
        # judge rank on the clique blocks of the pattern and complete X from their factors.
        from .chordal import column_cliques

        cliques = column_cliques(N, [Q, *As], always=range(d))
        X, svrs = complete_from_cliques(X, cliques, d)
    res = SDPResult(status=status, solver="clarabel-chordal" if chordal else "clarabel", d=d, X=X, y=y,
                    primal_cost=primal, dual_cost=dual,
                    solve_time_s=t2 - t1, setup_time_s=t1 - t0, iterations=int(sol.iterations),
                    clique_log_svr=svrs, cliques=cliques)
    return finish(res)


def solve_cliques(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
                  cliques: Sequence[np.ndarray], opts: SolverConfig) -> SDPResult:
    """Clique-decomposed dual (see the module docstring); X is read on the pattern from the cones'
    dual variables and completed from the clique blocks' rank-d factors."""
    t0 = time.perf_counter()
    prog = clique_program(Q, As, b, cliques)
    m, obj = prog.m, -prog.g
    cones = [clarabel.PSDTriangleConeT(len(C)) for C in prog.cliques]
    # the cones are the cliques already: Clarabel's own decomposition stays off
    solver = clarabel.DefaultSolver(sp.csc_matrix((obj.size, obj.size)), obj, prog.F, prog.c, cones,
                                    clarabel_settings(opts, Q.shape[0], chordal=False))
    t1 = time.perf_counter()
    sol = solver.solve()
    t2 = time.perf_counter()
    y = np.asarray(sol.x, float)[:m] / prog.scale
    X, svrs, completion = complete_auto(prog, np.asarray(sol.z, float), d)
    primal = float(Q.multiply(X).sum()) if X is not None else float("nan")
    status = _sdp_status(sol.status)
    res = SDPResult(status=status, solver="clarabel-cliques", d=d, X=X, y=y, primal_cost=primal,
                    dual_cost=float(np.dot(b, y)), solve_time_s=t2 - t1, setup_time_s=t1 - t0,
                    iterations=int(sol.iterations), clique_log_svr=svrs or None,
                    cliques=prog.cliques if svrs else None, completion=completion)
    return finish(res)


#: a solve that stalls (these statuses) is retried with Clarabel's default regularisation, and (one
#: cone, at most RETRY_MAX_N columns: clique-graph merging can take many minutes on larger chains)
#: with clique-graph merging
RETRY_STATUSES = ("NumericalError", "InsufficientProgress")
#: on liftings of at most RETRY_MAX_N columns, an AlmostSolved solve is retried with the default
#: regularisation too (scaled pose averaging, M = 10, σ = 1e-3: "small" stops AlmostSolved 7e-7 from
#: the optimum, "default" solves it to 1e-9); on larger ones that retry costs more than it gains
#: (continuous time, K = 17, not tight: 100 s more for no change of verdict)
SMALL_RETRY_STATUSES = RETRY_STATUSES + ("AlmostSolved",)
RETRY_MAX_N = 100


class ClarabelBackend:
    """Clarabel, direct: one PSD cone (with Clarabel's own chordal decomposition when
    ``ClarabelOptions.chordal``), or one cone per clique of the cover the SDP layer chose.

    Retries (``retries``, read from ``config.clarabel``): a solve with the small regularisation that
    stalls (``RETRY_STATUSES``; on at most ``RETRY_MAX_N`` columns also AlmostSolved) is solved again
    with Clarabel's default regularisation, then one that still stalls (one cone, Clarabel's chordal
    decomposition with parent-child merging, at most ``RETRY_MAX_N`` columns) with clique-graph
    merging."""

    name = "clarabel"
    decompose_default = False  # Clarabel's own chordal decomposition is the default path
    cover = "clarabel"
    fallback = None
    errors: tuple[type[BaseException], ...] = ()  # Clarabel reports its failures as statuses

    def check(self, arg: str | None) -> None:
        if arg is not None:
            raise SolverConfigError(f"backend 'clarabel' takes no argument, got 'clarabel:{arg}'")

    def solve(self, Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, config: SolverConfig) -> SDPResult:
        if cliques is not None and len(cliques) > 1:
            return solve_cliques(Q, As, b, d, cliques, config)
        return solve_dense(Q, As, b, d, config)  # one clique: the dense path

    def retries(self, config: SolverConfig, decomposed: bool, N: int) -> Retries:
        o = config.clarabel
        out: Retries = []
        if o.regularization == "small":
            out.append(("default regularisation", replace(config, clarabel=replace(o, regularization="default")),
                        SMALL_RETRY_STATUSES if N <= RETRY_MAX_N else RETRY_STATUSES))
        if not decomposed and o.chordal and o.merge == "parent_child" and N <= RETRY_MAX_N:
            out.append(("clique_graph merge", replace(config, clarabel=replace(o, merge="clique_graph")),
                        RETRY_STATUSES))
        return out
