"""One ``solve`` for the Shor relaxation  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

Backends (one module each): ``clarabel`` (direct, sparse, default), ``clarabel`` with
``cliques`` (clique decomposition of a chordal pattern), ``cvxpy:<SOLVER>`` (SCS, MOSEK, …).
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

__all__ = ["solve", "SDPResult", "SolverOptions", "log_svr", "rank_d_factor"]

#: A parent-child-merged solve that fails this way is retried with clique-graph merging, on liftings
#: of at most RETRY_MAX_N columns only: clique-graph merging can take many minutes on larger chains.
RETRY_STATUSES = ("NumericalError", "InsufficientProgress")
RETRY_MAX_N = 100


@single_blas_thread
def solve(Q: sp.spmatrix | sp.sparray, constraints: Sequence[Constraint], *, d: int = 1,
          solver: str = "clarabel", cliques: Sequence[np.ndarray] | None = None,
          options: SolverOptions | None = None) -> SDPResult:
    """Solve the SDP; ``constraints`` are ``Constraint`` objects (A sparse symmetric, b)."""
    opts = options or SolverOptions()
    Q = sp.csr_array(Q)
    As = [sp.csr_array(c.A) for c in constraints]
    b = np.array([c.b for c in constraints], dtype=float)
    try:
        if solver == "clarabel":
            res = solve_cliques(Q, As, b, d, cliques, opts) if cliques is not None else solve_dense(Q, As, b, d, opts)
        elif solver.startswith("cvxpy"):
            name = solver.split(":", 1)[1] if ":" in solver else "SCS"
            res = solve_cvxpy(Q, As, b, d, name, opts)
        else:
            res = None
        if (res is not None and solver == "clarabel" and cliques is None and opts.clarabel_chordal
                and opts.chordal_merge == "parent_child" and res.status in RETRY_STATUSES
                and Q.shape[0] <= RETRY_MAX_N):
            retry = solve_dense(Q, As, b, d, replace(opts, chordal_merge="clique_graph"))
            first = f"parent_child merge ended {res.status}; retried with clique_graph merge"
            if retry.status == "Solved" or not res.usable:
                res = retry
            res.message = (first + (f" ({retry.status})" if res is not retry else "")).strip()
        if res is not None:
            if res.X is not None:
                res.cost_scale = float(abs(Q.multiply(res.X)).sum())
            return res
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as e:
        return SDPResult(status=f"Failed: {type(e).__name__}: {e}".splitlines()[0], solver=solver, d=d, X=None,
                         y=None, primal_cost=float("nan"), dual_cost=float("nan"), solve_time_s=0.0,
                         message=str(e))
    raise ValueError(f"unknown solver {solver!r}; use 'clarabel' or 'cvxpy:SCS', 'cvxpy:MOSEK', …")
