"""The SDP layer: one ``solve`` for the Shor relaxation  min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0.

The layer owns the solve policy; callers give the data, a ``SolverConfig`` and optionally the
model's own clique cover (a hint) and a scaling vector:

- backend: ``config.backend`` names an entry of ``registry.BACKENDS`` ("clarabel", "ipm",
  "cvxpy:<NAME>");
- cover: when the solve is decomposed (``config.decompose``, or the backend's default), the cover
  is chosen here (``covers.CliqueCovers``: min-fill covers of the columns and of the variable
  blocks, small cliques merged, and the hint, ranked by the backend's cost model);
- retries: a result is solved again with each of the backend's ``retries`` configs in turn whose
  statuses include its status (Clarabel, as ``config.clarabel`` allows: default regularisation on a
  stalled solve, or an AlmostSolved one of at most 100 columns, then clique-graph merging on a stalled
  one); the retry replaces the result when it is Solved or the result is unusable; a usable result that the
  caller's ``settled`` rule calls settled is not retried;
- fallback: an unusable result of a backend with a ``fallback`` (the IPM) is solved again by that
  backend on its own cover (Clarabel's), with its retries, up to ``FALLBACK_MAX_N`` columns; above, the
  first backend's result stands, and its message says that no fallback was tried and why.  So does a best
  iterate (``SDPResult.has_iterate``) that the caller's ``settled`` rule calls settled (``SDPResult.settled``);
- scaling: ``scale`` = D (see ``solve``);
- counting: every solver call is counted in ``SDPResult.n_calls``, its solve and set-up times are
  summed into ``solve_time_s`` and ``setup_time_s``, and ``message`` lists every attempt.

A solver's failure is a status, never an exception: an ``SDPResult`` is returned whatever the
solver reports.  Only what a backend declares in ``errors`` (exceptions the solver legitimately
signals) becomes a "Failed: …" status; bad input (shapes, a cover hint that misses entries) raises
ValueError, and a bad config raises ``SolverConfigError`` when it is built.

Adding a backend is one module plus one line that registers it.  The module defines a small class with
the attributes of ``backend.Backend``::

    # autotight/sdp/mysolver.py
    class MySolverBackend:
        name, decompose_default, cover, fallback = "mysolver", False, None, None
        errors = ()
        min_tol = 0.0                                # optional: the tightest tol it solves to
        def check(self, arg): ...                    # SolverConfigError if not installed
        def solve(self, Q, As, b, d, cliques, config): ...   # -> SDPResult
        def retries(self, config, decomposed, N): return []

    # autotight/sdp/__init__.py, beside the shipped ones:
    BACKENDS["mysolver"] = MySolverBackend()

and ``SolverConfig(backend="mysolver")`` selects it everywhere (API, CLI ``--solver``, reports).  Settings
that only this backend reads go in a frozen options dataclass in ``sdp/options.py``, validated in
``__post_init__`` (SolverConfigError), and a field of ``SolverConfig`` holding it, as ``options.ClarabelOptions``
(``SolverConfig.clarabel``) and ``options.IpmOptions`` (``SolverConfig.ipm``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..model import Constraint, Model, fast_coo
from ..threads import single_blas_thread
from .config import (AUTO, FALLBACK_MAX_N, ClarabelOptions, IpmOptions, SolverConfig, SolverConfigError,
                     SolverOptions)
from .covers import IPM_MERGE_CAPS, MERGE_MAX_SIZE, CliqueCovers
from .clarabel_direct import ClarabelBackend
from .cvxpy_path import CvxpyBackend
from .backend import Backend, SettledRule, StopRule
from .registry import BACKENDS
from .schur_ipm import IPMBackend
from .result import SDPResult, Status, finish, log_svr, rank_d_factor

__all__ = ["solve", "solve_model", "FALLBACK_MAX_N",
           "model_cover", "check_solver", "SolverConfig", "SolverConfigError", "SolverOptions",
           "ClarabelOptions", "IpmOptions",
           "SDPResult", "BACKENDS", "CliqueCovers", "MERGE_MAX_SIZE", "IPM_MERGE_CAPS", "log_svr",
           "rank_d_factor"]

#: the shipped backends (``registry``)
BACKENDS.update(clarabel=ClarabelBackend(), ipm=IPMBackend(), cvxpy=CvxpyBackend())


def check_solver(name: str) -> str:
    """``name`` if it is a usable backend, else SolverConfigError with the choices."""
    SolverConfig(backend=name)
    return name


@dataclass
class _Attempt:
    why: str  # "" for the first call, else the retry or fallback
    res: SDPResult

    def describe(self, k: int) -> str:
        r = self.res
        head = f"{k}. {self.why + ': ' if self.why else ''}{r.solver} {r.status} ({r.solve_time_s:.2f} s"
        return head + (f"; {r.message.strip()})" if r.message.strip() else ")")


def _call(backend: Backend, why: str, Q: sp.csr_array, As: list[sp.csr_array], b: np.ndarray, d: int,
          cliques: list[np.ndarray] | None, config: SolverConfig, log: list[_Attempt],
          stop: StopRule | None = None, settled: SettledRule | None = None) -> SDPResult:
    """One solver call, logged; an exception the backend declares becomes a "Failed" status.  A backend with
    ``stops_early`` gets ``stop``, and ``settled`` when that is an ``EarlySettle`` (``backend.Backend``)."""
    early = settled if callable(getattr(settled, "may_settle", None)) else None
    try:
        if (stop is not None or early is not None) and getattr(backend, "stops_early", False):
            res = backend.solve(Q, As, b, d, cliques, config, stop, early)  # type: ignore[call-arg]
        else:
            res = backend.solve(Q, As, b, d, cliques, config)
    except backend.errors as e:
        res = SDPResult(status=f"Failed: {type(e).__name__}: {e}".splitlines()[0], solver=backend.name, d=d,
                        X=None, y=None, primal_cost=float("nan"), dual_cost=float("nan"), solve_time_s=0.0,
                        message=str(e))
    log.append(_Attempt(why, res))
    return res


def _with_retries(backend: Backend, why: str, Q: sp.csr_array, As: list[sp.csr_array], b: np.ndarray, d: int,
                  cliques: list[np.ndarray] | None, config: SolverConfig, log: list[_Attempt],
                  stop: StopRule | None = None, settled: SettledRule | None = None) -> SDPResult:
    res = _call(backend, why, Q, As, b, d, cliques, config, log, stop, settled)
    for what, cfg, statuses in backend.retries(config, cliques is not None, Q.shape[0]):
        if res.status not in statuses or res.settled:  # settled: the backend ended at an iterate the rule settles
            continue
        if settled is not None and res.usable and settled(res, Q, As, b):
            res.settled = True
            res.message = "; ".join(m for m in (res.message.strip(), f"not retried with {what}: its verdict is settled")
                                    if m)
            break
        retry = _call(backend, f"retried with {what}", Q, As, b, d, cliques, cfg, log, stop, settled)
        if retry.status == Status.SOLVED or not res.usable:
            res = retry
    return res


def effective_tol(config: SolverConfig) -> float:
    """The tolerance the backend solves to: ``config.tol``, or the backend's floor when higher (the
    optional attribute ``min_tol``; our IPM's is ``schur_ipm.IPM_MIN_TOL``)."""
    if config.backend_name == AUTO:  # not resolved yet (``SolverConfig.for_size``): no floor known
        return config.tol
    return max(config.tol, float(getattr(BACKENDS[config.backend_name], "min_tol", 0.0)))


def decomposes(config: SolverConfig) -> bool:
    """``config.decompose`` with None resolved by the backend's default: whether the solve runs on a
    clique cover chosen by this layer (for a backend that takes one, ``Backend.cover``)."""
    if config.backend_name == AUTO:
        raise ValueError("resolve backend 'auto' first (SolverConfig.for_size)")
    return BACKENDS[config.backend_name].decompose_default if config.decompose is None else config.decompose


def _cover(backend: Backend, decompose: bool, covers: CliqueCovers | None) -> list[np.ndarray] | None:
    if not decompose or backend.cover is None or covers is None:
        return None
    cl = covers.choose(backend.cover)
    return None if len(cl) == 1 and backend.cover == "clarabel" else cl  # one cone: the dense path


def _unscale(res: SDPResult, D: np.ndarray) -> SDPResult:
    """X' → X = D X' D; per-clique log SVRs, eigenvalues and Θ recomputed on X.  y and the costs are
    unchanged (⟨DQD, X'⟩ = ⟨Q, X⟩, and the constraints' right-hand sides are the same)."""
    if res.X is None:
        return res
    if sp.issparse(res.X):  # X on the cliques' pattern (``result.DENSE_X_MAX``): scale entries and completion
        Dm = sp.diags_array(D)
        res.X = sp.csr_array(Dm @ res.X @ Dm)
        if res.completion is not None:
            res.completion = res.completion * D[None, :]
        if res.cliques:
            res.clique_log_svr = [log_svr(ev[::-1], res.d) for ev in clique_eigvals(res.X, res.cliques)]
        res.eigvals, res.Theta, res.log_svr = np.zeros(0), None, float("nan")
        return finish(res)
    res.X = res.X * D[:, None] * D[None, :]
    if res.cliques:
        res.clique_log_svr = [log_svr(np.linalg.eigvalsh(res.X[np.ix_(C, C)])[::-1], res.d) for C in res.cliques]
    res.eigvals, res.Theta, res.log_svr = np.zeros(0), None, float("nan")
    return finish(res)


def clique_eigvals(X: sp.sparray, cliques: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The ascending eigenvalues of each clique block X[C, C] of a sparse X, gathered and decomposed per
    clique size in one batch (not one sparse slice per clique)."""
    X = sp.csr_array(X)
    X.sort_indices()
    out: list[np.ndarray] = [np.zeros(0)] * len(cliques)
    sizes = np.array([len(C) for C in cliques])
    for n in np.unique(sizes):
        ids = np.flatnonzero(sizes == n)
        C = np.array([np.asarray(cliques[int(k)], np.int64) for k in ids])  # (B, n)
        rows = np.repeat(C, n, axis=1).ravel()
        cols = np.tile(C, (1, n)).ravel()
        blocks = np.asarray(X[rows, cols]).reshape(len(ids), n, n)
        for k, ev in zip(ids, np.linalg.eigvalsh(blocks)):
            out[int(k)] = ev
    return out


def congruence(A: sp.sparray, D: np.ndarray) -> sp.sparray:
    """D A D for a diagonal D (given as its vector), by scaling the stored entries (a COO matrix stays COO:
    a CSR copy per constraint would hold an N + 1 index array)."""
    if isinstance(A, sp.coo_array) and A.has_canonical_format and A.shape[0] == A.shape[1]:
        return fast_coo(A.data * D[A.row] * D[A.col], A.row, A.col, A.shape[0])
    if isinstance(A, (sp.coo_array, sp.coo_matrix)):
        return sp.coo_array((A.data * D[A.row] * D[A.col], (A.row, A.col)), shape=A.shape)
    A = sp.csr_array(A, copy=True)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    A.data *= D[rows] * D[A.indices]
    return A


def _solve(Q: sp.spmatrix | sp.sparray, constraints: Sequence[Constraint], d: int, config: SolverConfig | None,
           cliques: Sequence[np.ndarray] | None, scale: np.ndarray | None,
           block_sizes: Sequence[int] | None, stop: StopRule | None = None,
           settled: SettledRule | None = None) -> SDPResult:
    config = SolverConfig() if config is None else config
    Q = sp.csr_array(Q)
    N = Q.shape[0]
    if Q.ndim != 2 or Q.shape != (N, N):
        raise ValueError(f"Q must be square, got shape {Q.shape}")
    config = config.for_size(N)
    # COO, as the constraints store them: memory ∝ nonzeros (a CSR copy each held an index array of N + 1)
    As = [c.A if isinstance(c.A, sp.coo_array) else sp.coo_array(c.A) for c in constraints]
    bad = [c.name or str(i) for i, (c, A) in enumerate(zip(constraints, As)) if A.shape != (N, N)]
    if bad:
        raise ValueError(f"constraint matrices must be {N}×{N} like Q; wrong shape: {bad[:5]}")
    if d < 1 or d > N:
        raise ValueError(f"d = {d} must be in [1, N = {N}]")
    b = np.array([c.b for c in constraints], dtype=float)
    D = None
    if scale is not None and config.scale != "none":
        D = np.asarray(scale, float)
        if D.shape != (N,) or not np.all(np.isfinite(D)) or not np.all(D > 0):
            raise ValueError(f"scale must be a positive finite vector of length N = {N}")
        Qs, As_s = congruence(Q, D), [congruence(A, D) for A in As]
    else:
        Qs, As_s = Q, As
    backend = BACKENDS[config.backend_name]
    decompose = decomposes(config)
    fb = BACKENDS[backend.fallback] if backend.fallback else None
    needs_cover = decompose and (backend.cover is not None or (fb is not None and fb.cover is not None))
    covers = CliqueCovers(Qs, As_s, d, block_sizes, cliques) if needs_cover else None
    log: list[_Attempt] = []
    res = _with_retries(backend, "", Qs, As_s, b, d, _cover(backend, decompose, covers), config, log, stop,
                        settled)
    skipped = ""
    if not res.usable and fb is not None and settled is not None and res.has_iterate and (res.settled or
                                                                                         settled(res, Qs, As_s, b)):
        # the best iterate already settles the verdict: another backend's solve of the same SDP cannot change it
        res.settled = True
        skipped = f"; not solved again by {fb.name}: the verdict of its best iterate is settled"
    elif not res.usable and fb is not None and N > FALLBACK_MAX_N:
        skipped = (f"; not solved again by {fb.name}: N = {N} columns > {FALLBACK_MAX_N} (its memory grows faster "
                   "than the data)")
    elif not res.usable and fb is not None:
        # the backend's attainable accuracy was not enough: the fallback on its own cover
        fb_cover = _cover(fb, decompose, covers)
        res = _with_retries(fb, f"solved again by {fb.name}", Qs, As_s, b, d, fb_cover, config, log, stop,
                            settled)
    message = "; ".join(a.describe(k + 1) for k, a in enumerate(log)) + skipped  # before res is changed
    solve_s, setup_s = sum(a.res.solve_time_s for a in log), sum(a.res.setup_time_s for a in log)
    res.n_calls, res.solve_time_s, res.setup_time_s, res.message = len(log), solve_s, setup_s, message
    if D is not None:
        res = _unscale(res, D)
    elif res.Theta is None:
        res = finish(res)  # a backend that left eigenvalues, log SVR and Θ to the layer
    if res.X is not None:
        res.cost_scale = float(abs(Q.multiply(res.X)).sum())
    return res


@single_blas_thread
def solve(Q: sp.spmatrix | sp.sparray, constraints: Sequence[Constraint], *, d: int = 1,
          config: SolverConfig | None = None, cliques: Sequence[np.ndarray] | None = None,
          scale: np.ndarray | None = None, stop: StopRule | None = None,
          settled: SettledRule | None = None) -> SDPResult:
    """Solve the SDP; ``constraints`` are ``Constraint`` objects (A sparse symmetric N×N, b).

    d: the lifting width (h is the first d columns).  cliques: the model's own clique cover (column
    index arrays, each with h), a candidate when the solve is decomposed; None: none.
    scale: None, or a positive vector D (N,) (``scaling.block_scale``): the layer solves
    min ⟨DQD, X'⟩ s.t. ⟨DAᵢD, X'⟩ = bᵢ, X' ⪰ 0 and returns X = D X' D, with the costs and y unchanged;
    eigenvalues, log SVR (also per clique), and Θ are read from the unscaled X.  Ignored when
    ``config.scale == "none"``.
    stop: a test of the multipliers y (one per constraint, as given) that may end an iterative backend's solve
    at its best iterate once that is within reduced accuracy (a backend with ``stops_early``, ``backend.Backend``:
    our IPM asks it once its progress stalls; the others run to their end).  The result is then AlmostSolved and its
    message says so.
    settled: a test of a result (``backend.SettledRule``) that skips the backend's retries of a usable one, and the
    fallback backend's solve of an unusable one that holds its best iterate (e.g. a result whose bracket already
    proves the relaxation not tight: another solve cannot change that verdict); ``SDPResult.settled`` and its
    message then say so.  A rule that is a ``backend.EarlySettle`` asking for it is also asked of the iterates of a
    backend with ``stops_early`` (our IPM), which then ends at the first iterate the rule settles.
    Returns the last attempt's result (see the module docstring for retries and fallback) with
    ``n_calls``, the summed times and every attempt in ``message``.  ValueError on bad input.
    """
    return _solve(Q, constraints, d, config, cliques, scale, None, stop, settled)


@single_blas_thread
def model_cover(model: Model, constraints: Sequence[Constraint], policy: str = "clarabel") -> list[np.ndarray]:
    """The clique cover this layer would choose for ``model`` with ``constraints`` under ``policy``
    ("clarabel" or "ipm"; ``covers.CliqueCovers.choose``)."""
    V = model.variables
    hint = model.clique_indices() if model.cliques else None
    return CliqueCovers(model.Q, [c.A for c in constraints], model.d, [V.sizes[n] for n in V.names],
                        hint).choose(policy)


@single_blas_thread
def solve_model(model: Model, constraints: Sequence[Constraint], config: SolverConfig | None = None,
                scale: np.ndarray | None = None, stop: StopRule | None = None,
                settled: SettledRule | None = None) -> SDPResult:
    """``solve`` for a model: its Q and d, its own clique cover as the hint, and its variable blocks
    for the block cover (``covers.CliqueCovers``); ``stop`` and ``settled`` as for ``solve``."""
    V = model.variables
    hint = model.clique_indices() if model.cliques else None
    config = (config or SolverConfig()).for_size(V.N)
    if config.decompose is None and model.decompose is not None and BACKENDS[config.backend_name].cover is not None:
        config = replace(config, decompose=model.decompose)  # the module's advice, when the user left it open
    return _solve(model.Q, constraints, model.d, config, hint, scale, [V.sizes[n] for n in V.names], stop,
                  settled)
