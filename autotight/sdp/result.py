"""The result of an SDP solve, and what is read off X (eigenvalues, log SVR, rank-d factor)."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import scipy.sparse as sp


class Status(StrEnum):
    """How a solve ended, in Clarabel's words; every backend maps its own statuses to these once
    (``clarabel_direct._sdp_status``, ``cvxpy_path``, ``schur_ipm``).  A backend's failure that names its
    cause is a free string "Failed: …" (``errors`` of the backend) or "SolverError: …" (cvxpy)."""

    SOLVED = "Solved"
    ALMOST_SOLVED = "AlmostSolved"
    MAX_ITERATIONS = "MaxIterations"
    MAX_TIME = "MaxTime"
    NUMERICAL_ERROR = "NumericalError"
    INSUFFICIENT_PROGRESS = "InsufficientProgress"
    PRIMAL_INFEASIBLE = "PrimalInfeasible"
    DUAL_INFEASIBLE = "DualInfeasible"
    ALMOST_PRIMAL_INFEASIBLE = "AlmostPrimalInfeasible"
    ALMOST_DUAL_INFEASIBLE = "AlmostDualInfeasible"
    CALLBACK_TERMINATED = "CallbackTerminated"
    UNSOLVED = "Unsolved"
    FAILED = "Failed"


SOLVED = Status.SOLVED


@dataclass
class SDPResult:
    """Solution of min ⟨Q,X⟩ s.t. ⟨A_i,X⟩ = b_i, X ⪰ 0.

    status: the solver's own status string ("Solved", "AlmostSolved", "NumericalError", …).
    X: the N×N solution (assembled from clique blocks when the solve was decomposed): a dense array,
    or, for a decomposed solve of more than ``DENSE_X_MAX`` columns, a sparse csr_array holding X on the
    cliques' pattern only (memory ∝ Σ|C_k|², not N²); ``completion`` (d×N) then gives the entries off the
    pattern as ΘᵀΘ (the completion from the blocks' rank-d factors).
    y: the multipliers of the constraints, in the order given.
    eigvals: eigenvalues of X, descending (a decomposed solve of more than FULL_EIG_MAX columns: the
    top d + 1 only; one whose X is kept sparse, with a ``completion``: the top d only).
    log_svr = log10(λ_d / λ_{d+1}) (for cliques: the minimum over the clique blocks).
    Theta: the rank-d factor (d×N) with its h block = I_d.
    cliques: the blocks ``clique_log_svr`` is read from (a decomposed solve), else None.
    solve_time_s, setup_time_s: summed over every solver call; n_calls: the number of solver calls
    (first attempt, retries, fallback); message: every attempt, in order.
    dual_cost_raw: nan, or the solver's own dual cost when ``autotight.dual_polish`` replaced y (and
    dual_cost) by a polished y with a better lower bound.
    settled: the caller's ``settled`` rule (``autotight.sdp.solve``) held for this result, so it was not solved
    again; for a result that is not ``usable`` (a best iterate, ``has_iterate``) it then ends the solve in place
    of the fallback backend's.
    """

    status: str
    solver: str
    d: int
    X: np.ndarray | sp.csr_array | None
    y: np.ndarray | None
    primal_cost: float
    dual_cost: float
    solve_time_s: float
    setup_time_s: float = 0.0
    iterations: int = 0
    eigvals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    log_svr: float = float("nan")
    Theta: np.ndarray | None = None
    clique_log_svr: list[float] | None = None
    message: str = ""
    cost_scale: float = 0.0  # Σ|Q_ij X_ij|: the magnitude of the terms that the cost sums
    n_calls: int = 1
    cliques: list[np.ndarray] | None = None
    completion: np.ndarray | None = None
    dual_cost_raw: float = float("nan")  # the solver's own bᵀy when y was replaced by its polish (dual_polish)
    settled: bool = False

    @property
    def solved(self) -> bool:
        return self.status == SOLVED

    @property
    def usable(self) -> bool:
        """A solution was returned (Solved or AlmostSolved) and X is finite."""
        return self.X is not None and self.status in (Status.SOLVED, Status.ALMOST_SOLVED) and finite(self.X)

    @property
    def has_iterate(self) -> bool:
        """X and y of the solve's last (or best) iterate, finite, with finite costs: usable, or a solve that stopped
        early (InsufficientProgress, MaxIterations, …) but returned where it got to; never an infeasible one."""
        return (self.X is not None and self.y is not None and finite(self.X) and bool(np.all(np.isfinite(self.y)))
                and bool(np.isfinite(self.primal_cost)) and bool(np.isfinite(self.dual_cost))
                and "Infeasible" not in self.status)

    @property
    def cost(self) -> float:
        return self.primal_cost

    def summary(self) -> str:
        return (f"status={self.status} cost={self.primal_cost:.8g} dual={self.dual_cost:.8g} "
                f"log_svr={self.log_svr:.2f} time={self.solve_time_s:.3f}s")


#: a decomposed solve with more columns keeps X sparse on its cliques' pattern (see ``SDPResult``)
DENSE_X_MAX = 3000


def finite(X) -> bool:
    """Every stored entry of X (dense or sparse) is finite."""
    return bool(np.all(np.isfinite(X.data if sp.issparse(X) else X)))


def log_svr(eigvals: np.ndarray, d: int = 1) -> float:
    """log10(λ_d / λ_{d+1}) of a PSD matrix's descending eigenvalues (∞ if λ_{d+1} ≤ 0)."""
    ev = np.asarray(eigvals, dtype=float)
    if ev.size <= d:
        return float("inf")
    top, nxt = ev[d - 1], max(ev[d], 0.0)
    if top <= 0:
        return float("nan")
    return float("inf") if nxt <= 0 else float(np.log10(top / nxt))


#: above this many columns, a decomposed solve's X (whose log SVR comes from its clique blocks) gets
#: only its top d + 1 eigenpairs (Lanczos) instead of a full O(N³) eigendecomposition
FULL_EIG_MAX = 600


def rank_d_factor(X: np.ndarray, d: int, top_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (descending) and the best rank-d factor Θ (d×N) of X ≈ ΘᵀΘ.

    Θ is fixed up to the left orthogonal ambiguity by making its h block (columns
    ``0:d``) the identity where possible (Θ ← Θ_h⁻¹ Θ for invertible Θ_h; for d = 1 h > 0).
    top_only: only the d + 1 largest eigenvalues are computed (Lanczos, started from a fixed vector;
    the full eigendecomposition when Lanczos does not converge).
    """
    Xs = (X + X.T) / 2
    w = None
    if top_only and Xs.shape[0] > d + 2:
        from scipy.sparse.linalg import ArpackNoConvergence, eigsh
        try:
            w, V = eigsh(Xs, k=d + 1, which="LA", v0=np.ones(Xs.shape[0]))
            order = np.argsort(w)[::-1]
            w, V = w[order], V[:, order]
        except ArpackNoConvergence:
            w = None  # the full eigendecomposition below
    if w is None:
        w, V = np.linalg.eigh(Xs)
        w, V = w[::-1], V[:, ::-1]
    return w, _normalise(V, w, d)


def _normalise(V: np.ndarray, w: np.ndarray, d: int) -> np.ndarray:
    """Θ = √λ Vᵀ of the top d eigenpairs with its h block made I_d where possible (see ``rank_d_factor``)."""
    Theta = (V[:, :d] * np.sqrt(np.maximum(w[:d], 0.0))).T
    Th = Theta[:, :d]
    if d == 1:
        if Th[0, 0] < 0:
            Theta = -Theta
    else:
        U, _, Vt = np.linalg.svd(Th)
        Theta = (U @ Vt).T @ Theta  # nearest rotation that maps Θ_h to a symmetric PSD block
    return Theta


def completed_top(X: sp.sparray, completion: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Top d eigenvalues and the rank-d factor of the completed X (X on the pattern, ΘᵀΘ off it)
    by Lanczos on the operator v ↦ Xv + Θᵀ(Θv) − (ΘᵀΘ on the pattern)v: no N×N array.  λ_{d+1} is not
    computed: the log SVR of a decomposed solve is its cliques' (``finish``), and at a rank-d X λ_{d+1}
    lies in a cluster of near-zero eigenvalues that Lanczos resolves slowly (ten times the top d's time).
    None when Lanczos does not converge."""
    from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigsh

    X = sp.csr_array(X)
    C = X.tocoo()
    Th = np.asarray(completion, float)
    M = sp.csr_array((np.einsum("dk,dk->k", Th[:, C.row], Th[:, C.col]), (C.row, C.col)), shape=X.shape)
    N = X.shape[0]
    op = LinearOperator((N, N), matvec=lambda v: X @ v + Th.T @ (Th @ v) - M @ v, dtype=float)
    try:
        w, V = eigsh(op, k=d, which="LA", v0=np.ones(N))
    except ArpackNoConvergence:
        return None
    order = np.argsort(w)[::-1]
    w, V = w[order], V[:, order]
    return w, _normalise(V, w, d)


def finish(res: SDPResult) -> SDPResult:
    """Fill eigvals, log SVR and Θ from res.X (when X is available); with per-clique log SVRs
    (a decomposed solve), log SVR is their minimum."""
    if res.X is None or not finite(res.X):
        return res
    if sp.issparse(res.X):
        top = completed_top(res.X, res.completion, res.d) if res.completion is not None else None
        w, Theta = top if top is not None else (np.zeros(0), res.completion)
        res.eigvals, res.Theta = w, Theta
        res.log_svr = float(np.min(res.clique_log_svr)) if res.clique_log_svr else log_svr(w, res.d)
        return res
    w, Theta = rank_d_factor(res.X, res.d, top_only=bool(res.clique_log_svr) and res.X.shape[0] > FULL_EIG_MAX)
    res.eigvals, res.Theta = w, Theta
    res.log_svr = float(np.min(res.clique_log_svr)) if res.clique_log_svr else log_svr(w, res.d)
    return res
