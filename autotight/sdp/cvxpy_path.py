"""The same SDP through cvxpy, for solvers other than direct Clarabel (SCS, MOSEK, …)."""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .config import Retries, SolverConfig, SolverConfigError
from .result import SDPResult, Status, finish

#: cvxpy's statuses that mean a solution, as ``Status``; any other stays cvxpy's own text
CVXPY_STATUS = {"optimal": Status.SOLVED, "optimal_inaccurate": Status.ALMOST_SOLVED}


def solve_cvxpy(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int, solver: str,
                opts: SolverConfig) -> SDPResult:
    """min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0 with all constraints as one sparse linear map on vec(X)."""
    import cvxpy as cp

    t0 = time.perf_counter()
    N = Q.shape[0]
    X = cp.Variable((N, N), PSD=True)
    rows = [sp.csr_array(A).reshape((1, N * N), order="F") for A in As]
    M = sp.vstack(rows, format="csr") if rows else sp.csr_array((0, N * N))
    cons = [M @ cp.vec(X, order="F") == np.asarray(b, float)] if rows else []
    obj = cp.Minimize(cp.sum(cp.multiply(sp.csr_array(Q).toarray(), X)))
    prob = cp.Problem(obj, cons)
    kwargs: dict = {"verbose": opts.verbose}
    name = solver.upper()
    if name == "SCS":
        kwargs.update(eps=max(opts.tol, 1e-7), max_iters=max(opts.max_iter, 20000))
    elif name == "CLARABEL":
        kwargs.update(tol_gap_abs=opts.tol, tol_gap_rel=opts.tol, tol_feas=opts.tol, max_iter=opts.max_iter)
    t1 = time.perf_counter()
    try:
        prob.solve(solver=name, **kwargs)
        status = str(prob.status)
    except cp.error.SolverError as e:  # the solver's own failure is a status, not a crash
        status = f"SolverError: {e}".splitlines()[0]
    t2 = time.perf_counter()
    Xv = X.value
    y = -np.asarray(cons[0].dual_value, float) if cons and cons[0].dual_value is not None else None
    mapped = CVXPY_STATUS.get(status, status)
    res = SDPResult(status=mapped, solver=f"cvxpy-{name.lower()}", d=d, X=None if Xv is None else np.asarray(Xv),
                    y=y, primal_cost=float(prob.value) if Xv is not None else float("nan"),
                    dual_cost=float(np.dot(b, y)) if y is not None else float("nan"),
                    solve_time_s=t2 - t1, setup_time_s=t1 - t0, message=status)
    return finish(res)


#: the cvxpy solver used for a bare "cvxpy" backend
DEFAULT_SOLVER = "SCS"


class CvxpyBackend:
    """Any solver cvxpy has installed, named after the colon ("cvxpy:SCS", "cvxpy:MOSEK"); one PSD
    variable, no decomposition.  A solver's ``SolverError`` becomes a status."""

    name = "cvxpy"
    decompose_default = False
    cover = None  # takes no clique cover
    fallback = None
    errors: tuple[type[BaseException], ...] = ()  # SolverError is caught in solve_cvxpy

    def check(self, arg: str | None) -> None:
        import cvxpy as cp

        name = (arg or DEFAULT_SOLVER).upper()
        installed = cp.installed_solvers()
        if name not in installed:
            raise SolverConfigError(f"cvxpy solver {name!r} is not installed; installed: {', '.join(installed)}")

    def solve(self, Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, config: SolverConfig) -> SDPResult:
        return solve_cvxpy(Q, As, b, d, config.backend_arg or DEFAULT_SOLVER, config)

    def retries(self, config: SolverConfig, decomposed: bool, N: int) -> Retries:
        return []
