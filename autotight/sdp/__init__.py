"""One ``solve`` for the Shor relaxation  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

Backends (one module each): ``clarabel`` (direct, sparse, default), ``clarabel`` with
``cliques`` (clique decomposition of a chordal pattern), ``ipm`` (our Schur-complement interior-point
method on the clique blocks, ``schur_ipm``), ``cvxpy:<SOLVER>`` (SCS, MOSEK, …).
An ``ipm`` solve that ends unusable (its normal equations limit it to about 1e-8 of the data's
scale, too little when the optimal cost is far smaller than the cost matrix's entries) is solved
again by Clarabel on the same data (on ``fallback_cliques``, Clarabel's own cover, when given);
``res.solver`` and ``res.message`` say so.
A failed or inaccurate solve is returned with its status; it never raises.
"""

from __future__ import annotations

from ..threads import single_blas_thread
from dataclasses import replace
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..model import Constraint
from .clarabel_direct import solve_cliques, solve_dense
from .cvxpy_path import solve_cvxpy
from .result import SDPResult, SolverOptions, log_svr, rank_d_factor
from .schur_ipm import solve_ipm

__all__ = ["solve", "check_solver", "SOLVERS", "SDPResult", "SolverOptions", "log_svr", "rank_d_factor"]

#: the backends ``solve`` knows, besides ``cvxpy:<SOLVER>``
SOLVERS = ("clarabel", "ipm")


def check_solver(name: str) -> str:
    """``name`` if ``solve`` knows it, else ValueError with the choices."""
    if name in SOLVERS or name == "cvxpy" or name.startswith("cvxpy:"):
        return name
    raise ValueError(f"unknown solver {name!r}; use 'clarabel', 'ipm' or 'cvxpy:SCS', 'cvxpy:MOSEK', …")


#: A parent-child-merged solve that fails this way is retried with clique-graph merging, on liftings
#: of at most RETRY_MAX_N columns only: clique-graph merging can take many minutes on larger chains.
RETRY_STATUSES = ("NumericalError", "InsufficientProgress")
RETRY_MAX_N = 100


def _retry_stalled(res: SDPResult, Q: sp.csr_array, As: list[sp.csr_array], b: np.ndarray, d: int,
                   cliques: Sequence[np.ndarray] | None, opts: SolverOptions) -> SDPResult:
    """Re-solve a Clarabel solve that stalled (``RETRY_STATUSES``): first with Clarabel's default
    regularisation, then (small dense liftings with parent-child merging) with clique-graph merging.
    The retry's result replaces the first one when it is Solved or the first one is unusable; the
    message records every attempt."""
    retries = []
    if opts.regularization == "small":
        retries.append(("default regularisation", replace(opts, regularization="default")))
    if cliques is None and opts.clarabel_chordal and opts.chordal_merge == "parent_child" \
            and Q.shape[0] <= RETRY_MAX_N:
        retries.append(("clique_graph merge", replace(opts, chordal_merge="clique_graph")))
    notes = []
    for what, o in retries:
        if res.status not in RETRY_STATUSES:
            break
        retry = _clarabel_once(Q, As, b, d, cliques, o)
        notes.append(f"{res.status}; retried with {what}: {retry.status}")
        if retry.status == "Solved" or not res.usable:
            res = retry
    if notes:
        res.message = "; ".join(notes)
    return res


def _clarabel_once(Q: sp.csr_array, As: list[sp.csr_array], b: np.ndarray, d: int,
                   cliques: Sequence[np.ndarray] | None, opts: SolverOptions) -> SDPResult:
    return solve_cliques(Q, As, b, d, cliques, opts) if cliques is not None else solve_dense(Q, As, b, d, opts)


def _clarabel(Q: sp.csr_array, As: list[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, opts: SolverOptions) -> SDPResult:
    """Clarabel on the clique blocks (or one cone), retried when it stalls (``_retry_stalled``)."""
    return _retry_stalled(_clarabel_once(Q, As, b, d, cliques, opts), Q, As, b, d, cliques, opts)


@single_blas_thread
def solve(Q: sp.spmatrix | sp.sparray, constraints: Sequence[Constraint], *, d: int = 1,
          solver: str = "clarabel", cliques: Sequence[np.ndarray] | None = None,
          options: SolverOptions | None = None,
          fallback_cliques: Sequence[np.ndarray] | None = None) -> SDPResult:
    """Solve the SDP; ``constraints`` are ``Constraint`` objects (A sparse symmetric, b).
    ``fallback_cliques``: the cover for Clarabel's re-solve when an IPM result is unusable
    (default: ``cliques``; the IPM prefers fewer, larger cliques than Clarabel does).
    ValueError for an unknown ``solver``; every failure of a known one is a status."""
    check_solver(solver)
    opts = options or SolverOptions()
    Q = sp.csr_array(Q)
    As = [sp.csr_array(c.A) for c in constraints]
    b = np.array([c.b for c in constraints], dtype=float)
    try:
        if solver == "clarabel":
            res = _clarabel(Q, As, b, d, cliques, opts)
        elif solver == "ipm":
            res = solve_ipm(Q, As, b, d, cliques, opts)
            if not res.usable:  # its attainable accuracy was not enough: Clarabel on the same data
                first = f"ipm: {res.status} ({res.message.strip()}, {res.solve_time_s:.2f} s, counted in solve_time_s)"
                spent = res.solve_time_s + res.setup_time_s
                res = _clarabel(Q, As, b, d, cliques if fallback_cliques is None else fallback_cliques, opts)
                res.message = (f"{first}; solved again by {res.solver}: {res.status}"
                               + (f"; {res.message}" if res.message else ""))
                res.solve_time_s += spent
        else:
            name = solver.split(":", 1)[1] if ":" in solver else "SCS"
            res = solve_cvxpy(Q, As, b, d, name, opts)
        if res.X is not None:
            res.cost_scale = float(abs(Q.multiply(res.X)).sum())
        return res
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as e:
        return SDPResult(status=f"Failed: {type(e).__name__}: {e}".splitlines()[0], solver=solver, d=d, X=None,
                         y=None, primal_cost=float("nan"), dual_cost=float("nan"), solve_time_s=0.0,
                         message=str(e))
