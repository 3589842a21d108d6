"""Our own primal-dual interior-point method for block SDPs with sparse constraints (backend "ipm").

Contract.
- Input: the Shor SDP (Q, Aᵢ, bᵢ) and a clique cover (from ``covers.CliqueCovers``, policy "ipm";
  one block of all N columns when there is none), turned into the block standard form of
  ``clique_program`` (p blocks of n_k × n_k, M = m constraints + the overlap transfers):

      min Σ_k ⟨C_k, X_k⟩  s.t.  Σ_k ⟨A_ik, X_k⟩ = g_i,  X_k ⪰ 0;   max gᵀy  s.t.  Z_k = C_k − Σ_i y_i A_ik ⪰ 0.

- Output (``solve_ipm``): an ``SDPResult`` with X completed from the blocks' rank-d factors, the
  multipliers y of the m constraints, both costs, the per-block log SVRs, and the relative residuals
  of the best iterate in ``message``.
- Accuracy: it stops Solved when the relative gap and the primal and dual infeasibilities
  (``IPMSolution``) are all ≤ max(tol, ``IPM_MIN_TOL`` = 1e-7).  On tight relaxations with many
  redundant constraints the Schur complement has condition ~1/μ², which limits the attainable
  residuals to about 1e-8 of the data's scale; problems whose optimal cost is far below the cost
  matrix's entries (rotation averaging at σ = 1e-4, continuous time) need more than that.
- Giving up: after ``max_iter`` iterations (MaxIterations), ``time_limit`` seconds (MaxTime),
  ``STALL_ITERATIONS`` iterations without progress (InsufficientProgress; ``STALL_ITERATIONS_ALMOST``
  once the best iterate is within ``ALMOST_TOL``), ``JAM_ITERATIONS`` jammed steps once the best iterate is
  AlmostSolved (InsufficientProgress), the caller's stop rule accepting the best iterate's multipliers once
  ``STOP_ASK_ITERATIONS`` iterations have not bettered it (``solve_blocks``'s ``stop``), the caller's settle test
  accepting an iterate (``solve_blocks``'s ``settle``: the bracket of a relaxation already proved not tight), or a
  factorisation that breaks down (NumericalError).  A run that
  stops with a relative gap ≤ ``REDUCED_TOL_GAP`` and pinf, dinf ≤ ``REDUCED_TOL_FEAS`` (Clarabel's reduced
  accuracy) is AlmostSolved.  There is no infeasibility detection: an infeasible or unbounded SDP ends with
  one of those statuses.  It never raises on a numerical failure.  A result that is not usable is solved
  again by Clarabel (``IPMBackend.fallback``; the SDP layer does it and counts both calls).

Method: Nesterov–Todd (default) or HKM search direction (``IpmOptions.search``), Mehrotra's predictor-corrector,
SDPT3's infeasible start and step lengths (or a fixed fraction of the way to the cone's boundary,
``IpmOptions.step_fraction``: the retry of a solve that stalls, ``IPMBackend.retries``).
Each iteration solves the Schur complement system S Δy = r,
S_il = Σ_k ⟨A_ik, P_k A_lk Q_k⟩ with (P, Q) = (W, W) for NT (W Z W = X) and (X, Z⁻¹) for HKM.
S is sparse (S_il ≠ 0 only when constraints i and l touch a common block), assembled per block on
the entries its constraints touch (``_Schur.assemble``), equilibrated to a unit diagonal and
regularised by ``SCHUR_REG``.  When the blocks' constraints can be ordered into a narrow band
(``band_order``: a chain of blocks, e.g. a trajectory) S is stored and factorised as a band by LAPACK
(``_BandSchur``: Cholesky, banded LU with partial pivoting once a pivot is not positive); else by sparse
LDLᵀ (qdldl, Apache-2.0: AMD ordering and symbolic analysis once per solve, a numeric refactorisation
per iteration), with SuperLU's partial pivoting for the rest of the solve once a pivot is not positive.
Refinement steps against S are kept while they lower the residual (``refined_solve``).  From
``COMPILED_MIN_BLOCKS`` blocks on, S's assembly, the step lengths and the band's scaling and full storage
run as compiled kernels (``schur_kernel``, numba) with the same arithmetic as the numpy code here.  Programs
with Σ n_k³ ≥ ``block_threads.THREADED_MIN_WORK`` use two threads where the process may (``IpmOptions.threads``):
the per-block dense algebra on two slices of each stack, the X and Z factors and step lengths side by side,
the assembly and the band's scaling on two ranges of S; every value is the one thread's, bit for bit
(discrete trajectory K = 1000: 0.8 of the one-thread solve time).  Per iteration this costs about
``iteration_cost`` (a ranking used to choose the cover, not a prediction).
Everything works on full row-major vec(·) of each block; the svec data of ``clique_program`` is mapped once
by ``svec_to_vec``.
Measurements and the variants tried are in benchmarks/README.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..svec import SQRT2, triu_indices
from .clique_program import clique_program, complete_auto
from ..errors import SolverConfigError
from ..threads import single_blas_thread
from .backend import EarlySettle, StopRule
from .config import FALLBACK_MAX_N, Retries, SolverConfig
from .options import SEARCH_DIRECTIONS
from .result import SDPResult, Status, finish
from . import schur_kernel
from .schur_kernel import COMPILED_MIN_BLOCKS, BlockProducts, max_step
from .block_threads import BlockThreads, threaded

#: the stall clock's patience grows (STALL_ITERATIONS_ALMOST) once every relative residual is below this
ALMOST_TOL = 1e-6
#: a solve that stops early (iteration or time limit, stalled steps) with its relative gap and its
#: relative infeasibilities below these is AlmostSolved: Clarabel's reduced accuracy
#: (reduced_tol_gap_rel 5e-5, reduced_tol_feas 1e-4), so that the status means the same for both
#: backends.  Discrete trajectory K = 300 in the pipeline (paper set, scaled) stops at gap 4.4e-6,
#: pinf 5.2e-7: before, that counted as a failure and Clarabel solved again for 155 s.
REDUCED_TOL_GAP = 5e-5
REDUCED_TOL_FEAS = 1e-4
#: regularisation of the equilibrated Schur complement (unit diagonal)
SCHUR_REG = 1e-12
#: the corrector is replaced by the centred first-order direction when its shortest step is below
#: this fraction of the predictor's
CORRECTOR_FALLBACK = 0.5
#: SDPT3's step lengths: the fraction γ of the way to the cone's boundary starts at GAMMA_START and is
#: GAMMA_START + GAMMA_GAIN·min(α_p, α_d) after a step of lengths α_p, α_d
GAMMA_START = 0.9
GAMMA_GAIN = 0.09
#: the cost is scaled to max|C_ij| = 1; below this magnitude the gap is measured absolutely
GAP_FLOOR = 1e-6
#: stop (InsufficientProgress) after this many iterations without progress (``_StallClock``)
#: (the absolute gap keeps falling while the costs shrink by orders of magnitude towards a small
#: optimum, where any relative gap stays near 1)
STALL_ITERATIONS = 5
PROGRESS = 0.9
#: … or in this many once the best iterate is AlmostSolved: near the end the residuals bounce for a
#: few iterations before they reach the tolerance (discrete trajectory, 36 instances: 34 Solved with
#: 6, 29 with 3, at 5 % more iterations)
STALL_ITERATIONS_ALMOST = 6
#: a step whose primal and dual lengths are both below JAM_STEP is jammed; after JAM_ITERATIONS jammed steps in a
#: row a solve whose best iterate is already AlmostSolved stops there (InsufficientProgress, then AlmostSolved):
#: jammed steps at σ ≈ 1 leave the gap where it is while the infeasibility grows (discrete trajectory K = 1000,
#: the set learned at K = 5: gap 6.1e-6 from iteration 15 on, pinf 7e-7 → 9e-5, five more iterations)
JAM_STEP = 0.05
JAM_ITERATIONS = 2
#: tests of iterates by the caller's settle rule per solve at most (``solve_blocks``'s ``settle``): each completes X
#: and bounds λ_min of the dual matrix, and where the first ones fail, later ones rarely pass (continuous time
#: K = 41, a 2-pair set: 32 tests, 106 s, none passed, on a solve of 126 s; discrete trajectory K = 200, a 1-pair
#: set: the first test passed, iteration 18 of 64)
SETTLE_TRIES = 2
#: iterations without a better iterate after which ``solve_blocks`` asks its caller's stop rule about an
#: AlmostSolved best iterate.  One is not enough: after a single jammed step the residuals may fall again (discrete
#: trajectory K = 100, seed 2, K = 5 set: Solved three iterations after it, at a cost 1.6e-5 lower).  Not the stall
#: clock's progress, which counts any one measure falling (the gap alone falls while pinf grows: K = 1000, seed 1)
STOP_ASK_ITERATIONS = 2


@dataclass
class IPMSolution:
    """z: (Σ svec(n_k),) the primal blocks in svec; y: (M,) the multipliers.  The residuals are
    relative: gap = |pobj − dobj| / max(|pobj|, |dobj|, GAP_FLOOR), pinf = ‖g − A(X)‖_∞ / (1 + ‖g‖_∞),
    dinf = ‖C − A*(y) − Z‖_max / (1 + ‖C‖_max): entrywise, as Clarabel's, so that the stopping rule
    does not tighten with the number of constraints (a 2-norm over M rows grows like √M at a fixed
    accuracy per row: on discrete trajectory K = 300, paper set, it stayed at 1.4e-7 from iteration 28
    on, where the ∞-norm is 7.9e-8 and the solve ends Solved).
    The best iterate (smallest max residual) is returned."""

    status: str
    z: np.ndarray
    y: np.ndarray
    pobj: float
    dobj: float
    gap: float
    pinf: float
    dinf: float
    iterations: int
    time_s: float
    message: str = ""
    settled: bool = False  # ended at an iterate the caller's ``Settle`` settles (``solve_blocks``)


@dataclass(frozen=True)
class Settle:
    """A caller's test of the IPM's iterates (``solve_blocks``'s ``settle``): ``may(pobj, dobj, trace)`` a cheap
    necessary condition on the iterate's costs (the IPM's scaled cost) and the trace of the N×N matrix its blocks
    complete to, ``test(z, y)`` the test of its primal blocks z (svec, the layout of ``IPMSolution.z``) and
    multipliers y (M,).  ``diag``: the positions, in the blocks' joined vec (``_Blocks.join``), of one diagonal entry
    per column (each column counted once in the trace)."""

    may: Callable[[float, float, float], bool]
    test: Callable[[np.ndarray, np.ndarray], bool]
    diag: np.ndarray


def almost_solved(status: str, gap: float, pinf: float, dinf: float) -> bool:
    """Whether a solve that stopped with ``status`` (not Solved) is AlmostSolved: relative gap ≤
    REDUCED_TOL_GAP and pinf, dinf ≤ REDUCED_TOL_FEAS (Clarabel's reduced accuracy)."""
    return status != Status.SOLVED and gap <= REDUCED_TOL_GAP and max(pinf, dinf) <= REDUCED_TOL_FEAS


class _StallClock:
    """Iterations since the last progress: the best max residual fell below PROGRESS × its value, or
    one of |pobj − dobj|, pinf and dinf that is still above tol (the gap: relative) fell below
    PROGRESS × its best.  Improvements by less (the residuals' jitter at a floor) and changes of a
    measure already within tol (dinf at 1e-14) do not count."""

    def __init__(self, tol: float):
        self.tol = tol
        self.best_err = np.inf
        self.best = np.full(3, np.inf)  # best |pobj − dobj|, pinf, dinf
        self.last = 0

    def tick(self, it: int, err: float, gap_abs: float, gap: float, pinf: float, dinf: float) -> None:
        measures = np.array([gap_abs, pinf, dinf])
        if err < PROGRESS * self.best_err or np.any((measures < PROGRESS * self.best)
                                                    & (np.array([gap, pinf, dinf]) > self.tol)):
            self.last = it
        self.best_err = min(self.best_err, err)
        self.best = np.minimum(self.best, measures)

    def stalled(self, it: int) -> int:
        """The stall limit reached at iteration ``it`` (STALL_ITERATIONS, or STALL_ITERATIONS_ALMOST
        once the best max residual is within ALMOST_TOL), or 0."""
        stall = STALL_ITERATIONS_ALMOST if self.best_err <= ALMOST_TOL else STALL_ITERATIONS
        return stall if it - self.last >= stall else 0


def svec_to_vec(sizes: list[int]) -> sp.csr_array:
    """Block-diagonal operator P with P svec(S) = vec(S) (row-major) for symmetric blocks S;
    Pᵀ vec(S) = svec(S)."""
    sizes_a = np.asarray(sizes, dtype=np.int64)
    voff = np.concatenate([[0], np.cumsum(sizes_a * sizes_a)])
    soff = np.concatenate([[0], np.cumsum(sizes_a * (sizes_a + 1) // 2)])
    rows, cols, vals = [], [], []
    for n in np.unique(sizes_a).tolist():  # the pattern of one block of size n, at every such block's offsets
        ids = np.flatnonzero(sizes_a == n)
        i, j = triu_indices(n)
        e = np.arange(i.size)
        off = i != j
        w = np.where(off, 1 / SQRT2, 1.0)
        r = np.concatenate([i * n + j, (j * n + i)[off]])
        rows.append((voff[ids][:, None] + r[None, :]).ravel())
        cols.append((soff[ids][:, None] + np.concatenate([e, e[off]])[None, :]).ravel())
        vals.append(np.tile(np.concatenate([w, w[off]]), ids.size))
    return sp.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                        shape=(int(voff[-1]), int(soff[-1])))


class _Blocks:
    """The p blocks grouped by size, so that per-block dense algebra runs batched on (B, n, n)."""

    def __init__(self, sizes: list[int]):
        self.sizes = sizes
        self.voff = np.concatenate([[0], np.cumsum([n * n for n in sizes])])
        self.groups: list[tuple[int, np.ndarray, np.ndarray]] = []  # (n, block ids, vec index (B, n²))
        for n in sorted(set(sizes)):
            ids = np.flatnonzero(np.asarray(sizes) == n)
            self.groups.append((n, ids, self.voff[ids][:, None] + np.arange(n * n)[None, :]))
        self.order = int(sum(sizes))  # Σ n_k: μ = ⟨X, Z⟩ / order

    def split(self, v: np.ndarray) -> list[np.ndarray]:
        """vec (Σn²,) → per size group (B, n, n)."""
        return [v[idx].reshape(-1, n, n) for n, _, idx in self.groups]

    def join(self, mats: list[np.ndarray]) -> np.ndarray:
        out = np.empty(self.voff[-1])
        for (n, _, idx), X in zip(self.groups, mats):
            out[idx] = X.reshape(-1, n * n)
        return out

    def identity(self, scale: float) -> list[np.ndarray]:
        return [np.broadcast_to(scale * np.eye(n), (ids.size, n, n)).copy() for n, ids, _ in self.groups]


def _sym(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + np.swapaxes(X, -1, -2))


def _primal_direction(H: np.ndarray, a: np.ndarray, dZ: np.ndarray, b: np.ndarray) -> np.ndarray:
    return _sym(H - a @ dZ @ b)


def _inner(X: list[np.ndarray], Z: list[np.ndarray]) -> float:
    return sum(float(np.einsum("bij,bij->", a, b)) for a, b in zip(X, Z))


def _mehrotra(G: np.ndarray, Ginv: np.ndarray, lam: np.ndarray, dX: np.ndarray, dZ: np.ndarray,
              target: float) -> np.ndarray:
    """NT's corrector right side G V Gᵀ with Λ∘V = target·I − Λ² − sym(ΔX̃ ΔZ̃) in the scaled space."""
    dXs = Ginv @ dX @ np.swapaxes(Ginv, -1, -2)
    dZs = np.swapaxes(G, -1, -2) @ dZ @ G
    R = -_sym(dXs @ dZs)
    n = lam.shape[-1]
    R[:, np.arange(n), np.arange(n)] += target - lam ** 2
    V = 2 * R / (lam[:, :, None] + lam[:, None, :])
    return G @ V @ np.swapaxes(G, -1, -2)


def _inverse_factors(X: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(L, L⁻¹) per block, X = L Lᵀ (Cholesky); LinAlgError when a block is not positive definite."""
    L = [np.linalg.cholesky(Xg) for Xg in X]
    return L, [np.linalg.inv(Lg) for Lg in L]


def _nt_scaling(L: np.ndarray, Z: np.ndarray, LXi: np.ndarray) -> tuple[np.ndarray, ...]:
    """NT scaling of one stack: Lᵀ Z L = U Λ² Uᵀ, G = L U Λ^(−1/2), G⁻¹ and W = G Gᵀ; returns (λ, G, G⁻¹, W)."""
    lam2, U = np.linalg.eigh(np.swapaxes(L, -1, -2) @ Z @ L)
    lam = np.sqrt(np.maximum(lam2, 1e-300))  # Lᵀ Z L ≻ 0 in exact arithmetic
    G = L @ U / np.sqrt(lam)[:, None, :]
    Ginv = np.sqrt(lam)[:, :, None] * np.swapaxes(U, -1, -2) @ LXi
    return lam, G, Ginv, G @ np.swapaxes(G, -1, -2)


def _max_step(Linv: list[np.ndarray], dX: list[np.ndarray]) -> float:
    """The largest α with X + α dX ⪰ 0 in every block (∞ when no block ever leaves the cone), from the
    inverse Cholesky factors L⁻¹ of X (``_inverse_factors``)."""
    lam = np.inf
    for Li, dXg in zip(Linv, dX):
        ev = np.linalg.eigvalsh(_sym(Li @ dXg @ np.swapaxes(Li, -1, -2)))
        lam = min(lam, float(ev[:, 0].min()))
    return np.inf if lam >= 0 else -1.0 / lam


def _step(Linv: list[np.ndarray], dX: list[np.ndarray], gamma: float) -> float:
    """The step length min(1, γ·α), α = ``_max_step`` (the largest step that stays in the cone)."""
    return min(1.0, gamma * _max_step(Linv, dX))


def _step_compiled(Linv: list[np.ndarray], dX: list[np.ndarray], gamma: float) -> float:
    """``_step`` by ``schur_kernel.max_step``: the blocks' eigenvalues only where a Cholesky test says
    they could limit the step below 1/γ; the same value (1 exactly when no block does: γ·(1/γ) may round
    below 1)."""
    limit = 1.0 / gamma
    alpha = max_step(Linv, dX, limit)
    return 1.0 if alpha >= limit else min(1.0, gamma * alpha)


def block_data(Gv: sp.csr_array, blocks: _Blocks
               ) -> tuple[list[sp.csr_array], list[tuple[np.ndarray, np.ndarray, np.ndarray]], list[np.ndarray]]:
    """Per block k: G_k (the data of the constraints touching it on its support, in half form and weighted:
    G_k[i, u] = vec(A_ik)[a_u n + b_u] / o_u for the entries a_u ≤ b_u that any of them touches, o_u = 2 on
    the diagonal and 1 off it, see ``_Schur.assemble``), the support (a_u, b_u, 1/o_u) and the ids of those
    constraints (increasing: G_k's rows)."""
    per_block: list[sp.csr_array] = []
    support: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    inc: list[np.ndarray] = []
    Gv = sp.csr_array(Gv)
    Gv.sort_indices()
    for k, n in enumerate(blocks.sizes):
        lo, hi = Gv.indptr[blocks.voff[k]], Gv.indptr[blocks.voff[k + 1]]
        cols, vals = Gv.indices[lo:hi], Gv.data[lo:hi]
        local = np.repeat(np.arange(n * n), np.diff(Gv.indptr[blocks.voff[k]:blocks.voff[k + 1] + 1]))
        a, b = np.divmod(local, n)
        upper = a <= b  # A_i symmetric: the entry (b, a) repeats (a, b)
        ids, rank = np.unique(cols, return_inverse=True)
        entries, ent = np.unique(local[upper], return_inverse=True)
        au, bu = np.divmod(entries, n)
        o = np.where(au == bu, 0.5, 1.0)
        per_block.append(sp.csr_array((vals[upper] * o[ent], (rank[upper], ent)), shape=(ids.size, entries.size)))
        support.append((au, bu, o))
        inc.append(ids)
    return per_block, support, inc


def block_products(per_block: list[sp.csr_array], support: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                   blocks: _Blocks, P: list[np.ndarray], Q: list[np.ndarray]) -> Iterator[tuple[int, np.ndarray]]:
    """(k, the dense m_k × m_k product G_k K_k G_kᵀ raveled) for every block k, in the order of the size
    groups (the kernel K_k of ``_Schur.assemble``)."""
    same = P is Q
    for (n, ids, _), Pg, Qg in zip(blocks.groups, P, Q):
        for j, k in enumerate(ids):
            a, b, _ = support[k]  # the weights 1/o_u are in G_k
            Pa, Pb = Pg[j][a], Pg[j][b]
            if same:  # P_bc = P_cb: the fourth product is the transpose of the second; the factor 2 at the end
                Pab = Pa[:, b]
                Kk = Pa[:, a] * Pb[:, b]
                Kk += Pab * Pab.T
            else:
                Qa, Qb = Qg[j][a], Qg[j][b]
                Kk = Pa[:, a] * Qb[:, b] + Pa[:, b] * Qb[:, a] + Pb[:, a] * Qa[:, b] + Pb[:, b] * Qa[:, a]
            Gk = per_block[k]
            Sk = Gk @ (Gk @ Kk).T
            if same:
                Sk *= 2
            yield k, Sk.ravel()


def _use_compiled(n_blocks: int, compiled: bool | None = None) -> bool:
    """Whether the compiled kernels run: ``compiled`` when given, else from COMPILED_MIN_BLOCKS blocks on."""
    return n_blocks >= COMPILED_MIN_BLOCKS if compiled is None else compiled


def _compiled_products(per_block: list[sp.csr_array], support: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                       targets: np.ndarray, blocks: _Blocks, compiled: bool | None) -> BlockProducts | None:
    """The compiled assembly of S (``schur_kernel``) over the blocks' concatenated targets, or None for the
    numpy loop (``block_products``); compiled: see ``_use_compiled``."""
    return BlockProducts(per_block, support, targets, blocks.groups) if _use_compiled(len(per_block), compiled) \
        else None


#: refinement steps of S Δy = r at most (``refined_solve``): each is kept only when it lowers the residual, and
#: the next is tried only when the last lowered it by at least this factor.  Near the optimum S's condition grows
#: like 1/μ²; one step was not enough on long chains (discrete trajectory K = 4000: the primal infeasibility rose
#: from 1.5e-7 to 4e-3 over the last ten iterations while the gap reached 1e-7)
REFINE_STEPS = 4
REFINE_GAIN = 0.5


def refined_solve(r: np.ndarray, inner: Callable[[np.ndarray], np.ndarray], dsc: np.ndarray,
                  S: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Δy with S Δy ≈ r from the factorisation ``inner`` of the equilibrated D S D (+ reg), D = diag(dsc), refined
    against S (a matrix-vector product) by up to ``REFINE_STEPS`` steps (see there)."""
    dy = dsc * inner(dsc * r)
    res = r - S(dy)
    size = np.linalg.norm(res)
    for _ in range(REFINE_STEPS):
        step = dy + dsc * inner(dsc * res)
        res_step = r - S(step)
        size_step = np.linalg.norm(res_step)
        if not size_step < size:  # near the optimum a step can make the residual worse: kept only when it helps
            break
        gain = size_step / size
        dy, res, size = step, res_step, size_step
        if gain > REFINE_GAIN:
            break
    return dy


class _Schur:
    """S's sparsity pattern, the per-block constraint data that fill it, and its factorisation."""

    def __init__(self, Gv: sp.csr_array, blocks: _Blocks, compiled: bool | None = None):
        M = Gv.shape[1]
        self.per_block, self.support, inc = block_data(Gv, blocks)
        keys = [(ids[:, None] * M + ids[None, :]).ravel() for ids in inc]
        B = sp.csr_array((np.ones(sum(i.size for i in inc)), (np.repeat(np.arange(len(inc)), [i.size for i in inc]),
                                                               np.concatenate(inc))), shape=(len(inc), M))
        pattern = sp.csr_array(B.T @ B)  # S_il ≠ 0 iff constraints i and l share a block
        pattern.sort_indices()
        self.rows = np.repeat(np.arange(M), np.diff(pattern.indptr))
        self.cols = pattern.indices.astype(np.int64)
        self.indptr = pattern.indptr
        self.inverse = np.searchsorted(self.rows * M + self.cols, np.concatenate(keys))
        self.M = M
        self.blocks = blocks
        self.compiled = _compiled_products(self.per_block, self.support, self.inverse, blocks, compiled)
        # the upper triangle (row ≤ column) of S in CSC order: qdldl's input
        self.upper = np.flatnonzero(self.cols >= self.rows)
        self.diag = np.flatnonzero(self.cols == self.rows)
        self._ldl = _LDLPattern(self.rows[self.upper], self.cols[self.upper], M)
        self.pivoting = False  # LDLᵀ has failed: SuperLU with pivoting for the rest of the solve

    def assemble(self, P: list[np.ndarray], Q: list[np.ndarray], par: BlockThreads | None = None) -> np.ndarray:
        """The values of S = Σ_k G_kᵀ (P_k ⊗ Q_k) G_k on the pattern (CSR order); P_k, Q_k symmetric.

        Only the entries that block k's constraints touch enter, in half form: for support entries
        u = (a, b), w = (c, d) (a ≤ b, c ≤ d) the kernel sums P ⊗ Q over the symmetric orbits,
        K_uw = (P_ac Q_bd + P_ad Q_bc + P_bc Q_ad + P_bd Q_ac) / (o_u o_w), o_u = 2 when a = b (the
        four terms then count that entry's one orbit member twice) and 1 otherwise;
        = 2 (W_ac W_bd + W_ad W_bc) / (o_u o_w) when P is Q (NT).  This costs |support|² per block
        instead of n⁴.  (The Gram form B_kᵀB_k, b_i = vec(L_Pᵀ A_i L_Q), was less accurate.)"""
        if self.compiled is not None:
            out = np.zeros(self.rows.size)
            self.compiled.accumulate(out, P, Q, par)
            return out
        parts: list[np.ndarray] = [np.zeros(0)] * len(self.per_block)
        for k, part in block_products(self.per_block, self.support, self.blocks, P, Q):
            parts[k] = part
        return np.bincount(self.inverse, weights=np.concatenate(parts), minlength=self.rows.size)

    def factor(self, vals: np.ndarray, reg: float,
               par: BlockThreads | None = None) -> Callable[[np.ndarray], np.ndarray]:
        """A solver for S Δy = r: D(DSD + reg·I)⁻¹D with D = diag(S)^(−1/2), by sparse LDLᵀ
        (``_LDLPattern``), or by SuperLU (partial pivoting) when a pivot of LDLᵀ is not positive;
        then refined against S (``refined_solve``).  Raises
        np.linalg.LinAlgError when diag(S) is not positive or S is numerically singular."""
        d = vals[self.diag]
        if not np.all(d > 0):
            raise np.linalg.LinAlgError("Schur complement has a non-positive diagonal entry")
        dsc = 1 / np.sqrt(d)
        S = sp.csr_matrix((vals, self.cols, self.indptr), shape=(self.M, self.M))
        scaled = vals * dsc[self.rows] * dsc[self.cols]
        scaled[self.diag] += reg
        # once LDLᵀ has met a pivot that is not positive it meets one at every later iterate (μ only
        # falls): SuperLU from then on, without the failed LDLᵀ first
        inner = None if self.pivoting else self._ldl.factor(scaled[self.upper])  # None: a pivot was not positive
        if inner is None:
            self.pivoting = True
            try:
                inner = spla.splu(sp.csc_matrix((scaled, self.cols, self.indptr), shape=(self.M, self.M)),
                                  permc_spec="COLAMD").solve  # S symmetric: its CSR arrays are CSC
            except RuntimeError as e:  # SuperLU: "Factor is exactly singular"
                raise np.linalg.LinAlgError(f"Schur complement: {e}") from e

        def solve(r: np.ndarray) -> np.ndarray:
            return refined_solve(r, inner, dsc, lambda v: S @ v)

        return solve


class _LDLPattern:
    """Sparse LDLᵀ by qdldl (Apache-2.0) on a fixed upper-triangular pattern: AMD ordering and
    symbolic analysis on the first call, a numeric refactorisation on each later one."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, M: int):
        order = np.lexsort((rows, cols))  # CSC: by column, then row
        self.order = order
        self.indices = rows[order].astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=M))]).astype(np.int32)
        self.M = M
        self.solver: Any = None  # a qdldl.Solver after the first factorisation

    def factor(self, upper_vals: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """upper_vals in the (row, column) order of the pattern given to __init__; None when a
        pivot is not positive (the matrix is not positive definite to working accuracy)."""
        import qdldl

        A = sp.csc_matrix((upper_vals[self.order], self.indices, self.indptr), shape=(self.M, self.M))
        try:
            if self.solver is None:
                self.solver = qdldl.Solver(A, upper=True)
            else:
                self.solver.update(A, upper=True)
        except RuntimeError:  # a zero pivot ("not quasi-definite")
            self.solver = None
            return None
        if not np.all(self.solver.factors()[1] > 0):
            return None
        return self.solver.solve


#: S is factorised as a band (``_BandSchur``) when its band holds at most this many times the entries of
#: its blocks' lower triangles (Σ_k m_k(m_k + 1)/2, an upper bound of nnz(tril S)); else by sparse LDLᵀ
BAND_FILL_MAX = 2.0


def band_order(inc: Sequence[np.ndarray], M: int) -> tuple[np.ndarray, int]:
    """(pos, b): a position for each of the M constraints and the half bandwidth b of S in that order.

    The blocks are put in reverse Cuthill–McKee order of the block graph (two blocks adjacent when a
    constraint touches both), and the constraints by the first of their blocks in that order (ties by
    id).  S_il ≠ 0 only when i and l touch a common block k, so b = max_k (the spread of the positions of
    block k's constraints).  A chain of blocks gives b ≈ the constraints of one block and its neighbours'
    shared ones, whatever the length of the chain."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    p = len(inc)
    counts = np.array([i.size for i in inc])
    B = sp.csr_array((np.ones(int(counts.sum())), (np.repeat(np.arange(p), counts), np.concatenate(inc))),
                     shape=(p, M))
    rank = np.empty(p, np.int64)
    rank[reverse_cuthill_mckee(sp.csr_matrix(B @ B.T), symmetric_mode=True)] = np.arange(p)
    first = np.full(M, p, np.int64)  # a constraint in no block goes last (its row of S is zero)
    np.minimum.at(first, np.concatenate(inc), np.repeat(rank, counts))
    order = np.lexsort((np.arange(M), first))
    pos = np.empty(M, np.int64)
    pos[order] = np.arange(M)
    filled = counts > 0
    if not filled.any():
        return pos, 0
    at = pos[np.concatenate(inc)]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[filled]
    return pos, int(np.max(np.maximum.reduceat(at, starts) - np.minimum.reduceat(at, starts)))


class _BandSchur:
    """S as a symmetric band in the order of ``band_order``: the same products as ``_Schur`` summed into
    LAPACK's lower band storage (ab[t, j] = S[j + t, j], t ≤ b), factorised by banded Cholesky (pbtrf,
    O(M b²)) or, once a pivot is not positive, by banded LU with partial pivoting (gbtrf) for the rest of
    the solve.  Built by ``make``, which returns None when the band would be too wide (``BAND_FILL_MAX``)."""

    def __init__(self, per_block: list[sp.csr_array], support: list, inc: list[np.ndarray], blocks: _Blocks,
                 pos: np.ndarray, b: int, compiled: bool | None = None):
        M = pos.size
        self.per_block, self.support, self.blocks, self.M, self.b = per_block, support, blocks, M, b
        self.size = (b + 1) * M
        itype = np.int32 if self.size < 2 ** 31 - 1 else np.int64
        # each block entry (i, l) of S_k → its place in the band (column-major (b + 1) × M), or the
        # sentinel ``size`` for the upper triangle (S is symmetric: each pair is summed once)
        self.targets: list[np.ndarray] = []
        self.order = np.argsort(pos)  # the constraint at each position
        self.compiled: BlockProducts | None = None
        if _use_compiled(len(per_block), compiled):
            # G_k's rows in band order, so that the lower triangle of S_k is the band's: packed targets
            perms = [np.argsort(pos[ids]) for ids in inc]
            packed = []
            for ids, perm in zip(inc, perms):
                pi, pl = np.tril_indices(ids.size)
                ps = pos[ids][perm]
                packed.append((ps[pl] * (b + 1) + (ps[pi] - ps[pl])).astype(itype))
            self.compiled = BlockProducts([G[perm] for G, perm in zip(per_block, perms)], support,
                                          np.concatenate(packed) if packed else np.zeros(0, itype), blocks.groups,
                                          lower=True)
        else:
            for ids in inc:
                pi, pl = pos[ids][:, None], pos[ids][None, :]
                self.targets.append(np.where(pi >= pl, pl * (b + 1) + (pi - pl), self.size).astype(itype).ravel())
        self.pivoting = False
        self._held: dict[str, Any] = {}  # the last factorisation's arrays, released by the next ``assemble``
        # the compiled path's scaled and full band arrays, reused by the next factorisation (``_held`` may
        # hold them as its factors until the next ``assemble``)
        self._buffers: dict[str, np.ndarray] = {}

    @classmethod
    def make(cls, Gv: sp.csr_array, blocks: _Blocks, compiled: bool | None = None) -> "_BandSchur | None":
        """The band form of S, or None when it would be too wide; compiled: see ``_compiled_products``."""
        per_block, support, inc = block_data(Gv, blocks)
        M = Gv.shape[1]
        if M == 0:
            return None
        pos, b = band_order(inc, M)
        lower = sum(i.size * (i.size + 1) // 2 for i in inc)
        if (b + 1) * M > BAND_FILL_MAX * max(lower, M):
            return None
        return cls(per_block, support, inc, blocks, pos, b, compiled)

    def assemble(self, P: list[np.ndarray], Q: list[np.ndarray], par: BlockThreads | None = None) -> np.ndarray:
        """S (see ``_Schur.assemble``) in band storage: a (b + 1) × M array, Fortran order.  The solver of the
        previous ``factor`` is invalid from here on (its arrays are released: a few bands at a time)."""
        self._held.clear()
        flat = self._buffers.get("flat")  # the last entry collects the upper triangle
        if flat is None:
            flat = self._buffers["flat"] = np.zeros(self.size + 1)
        else:  # the previous S (held by the previous factorisation, now released): cleared, not reallocated
            flat.fill(0.0)
        if self.compiled is not None:
            self.compiled.accumulate(flat, P, Q, par)
            return flat[:self.size].reshape(self.M, self.b + 1).T
        for k, part in block_products(self.per_block, self.support, self.blocks, P, Q):
            np.add.at(flat, self.targets[k], part)
        return flat[:self.size].reshape(self.M, self.b + 1).T

    def _scaled(self, ab: np.ndarray, dsc: np.ndarray) -> np.ndarray:
        """D ab D in band storage (entry (j + t, j) times dsc[j + t] dsc[j]; the unused corner stays 0)."""
        shifted = np.lib.stride_tricks.sliding_window_view(np.concatenate([dsc, np.zeros(self.b)]), self.b + 1)
        out = ab.T * dsc[:, None]  # on the (M, b + 1) C-order view: contiguous rows
        out *= shifted
        return out.T

    def _full_band(self, low: np.ndarray) -> np.ndarray:
        """LAPACK's general band storage (kl = ku = b, with b more rows for the LU's fill) of the
        symmetric matrix whose lower band is ``low``: A[i, j] at row 2b + i − j."""
        b, M = self.b, self.M
        ab = np.zeros((3 * b + 1, M), order="F")
        ab[2 * b:, :] = low
        for t in range(1, b + 1):
            ab[2 * b - t, t:] = low[t, :M - t]
        return ab

    def factor(self, ab: np.ndarray, reg: float, par: BlockThreads | None = None) -> Callable[[np.ndarray], np.ndarray]:
        """As ``_Schur.factor``: D(DSD + reg·I)⁻¹D with D = diag(S)^(−1/2) by banded Cholesky, or banded
        LU with partial pivoting once a pivot is not positive, then refined against S (``refined_solve``).
        np.linalg.LinAlgError when diag(S) is not positive or S is
        exactly singular.  ``par``: threads for the compiled scaling (the same entries)."""
        from scipy.linalg.blas import dsbmv
        from scipy.linalg.lapack import dgbtrf, dgbtrs, dpbtrf, dpbtrs

        d = ab[0]
        if not np.all(d > 0):
            raise np.linalg.LinAlgError("Schur complement has a non-positive diagonal entry")
        dsc = 1 / np.sqrt(d)
        b, inner, held = self.b, None, self._held

        def scaled() -> np.ndarray:
            if self.compiled is not None:  # into the last factorisation's buffer (released by ``assemble``)
                self._buffers["scaled"] = schur_kernel.scaled_band(ab, dsc, reg, self._buffers.get("scaled"), par)
                return self._buffers["scaled"]
            out = self._scaled(ab, dsc)
            out[0] += reg
            return out

        if not self.pivoting:
            held["chol"], info = dpbtrf(scaled(), lower=1, overwrite_ab=1)
            if info == 0:
                inner = lambda r: dpbtrs(held["chol"], r, lower=1)[0]  # noqa: E731
            else:  # a pivot is not positive: LU with pivoting for the rest of the solve (μ only falls)
                self.pivoting = True
                held.clear()
        if inner is None:
            if self.compiled is not None:  # scaled straight into the general band storage
                self._buffers["full"] = schur_kernel.scaled_full_band(ab, dsc, reg, self._buffers.get("full"), par)
                full = self._buffers["full"]
            else:
                full = self._full_band(scaled())
            held["lu"], held["piv"], info = dgbtrf(full, b, b, overwrite_ab=1)
            if info > 0:
                raise np.linalg.LinAlgError("Schur complement is exactly singular")
            inner = lambda r: dgbtrs(held["lu"], b, b, r, held["piv"])[0]  # noqa: E731
        order = self.order
        held["ab"] = np.asfortranarray(ab)

        def S(v: np.ndarray) -> np.ndarray:
            return dsbmv(b, 1.0, held["ab"], v, lower=1)

        def solve(r: np.ndarray) -> np.ndarray:
            keep = refined_solve(r[order], inner, dsc, S)
            out = np.empty_like(keep)
            out[order] = keep
            return out

        return solve


@single_blas_thread
def solve_blocks(F: sp.csc_matrix, c: np.ndarray, g: np.ndarray, sizes: list[int], *, tol: float = 1e-7,
                 max_iter: int = 100, time_limit: float = np.inf, verbose: bool = False,
                 search: str = "nt", step_fraction: float | None = None, threads: int | None = None,
                 stop: Callable[[np.ndarray], bool] | None = None,
                 settle: Settle | None = None) -> IPMSolution:
    """Solve the block SDP with svec data: cost c (R,), constraint columns F (R × M), right side g (M,),
    block sizes n_k (R = Σ svec(n_k)).  Solved: gap, pinf and dinf (see IPMSolution) all ≤ tol.
    search: "nt" (Nesterov–Todd, default) or "hkm" (HKM) direction.  step_fraction: each step goes this
    fraction of the way to the cone's boundary; None (default): SDPT3's GAMMA_START + GAMMA_GAIN·min(α_p, α_d).
    stop: asked with the best iterate's y (M,) once that iterate is AlmostSolved and ``STOP_ASK_ITERATIONS``
    iterations have not found a better one (smaller max residual), once per best iterate; True ends the solve
    there (AlmostSolved, "stopped by the caller's test of y").  The caller's test (the pipeline: y certifies the
    local solution) decides whether more accuracy can change anything.
    settle: asked of every iterate with pinf and dinf ≤ ``REDUCED_TOL_FEAS`` whose costs and trace meet
    ``settle.may``, ``SETTLE_TRIES`` times at most; ``settle.test(z, y)`` True ends the solve at that iterate
    (returned in place of the best one, ``settled``).
    Never raises on a numerical failure: the status says what happened."""
    if search not in SEARCH_DIRECTIONS:
        raise ValueError(f"unknown search direction {search!r}; use " + " or ".join(map(repr, SEARCH_DIRECTIONS)))
    t0 = time.perf_counter()
    P = svec_to_vec(sizes)
    Gv = sp.csr_array(P @ F)
    GvT = sp.csr_array(Gv.T)
    cv = P @ c
    blocks = _Blocks(sizes)
    schur: _Schur | _BandSchur = _BandSchur.make(Gv, blocks) or _Schur(Gv, blocks)
    step = _step_compiled if _use_compiled(len(sizes)) else _step
    nrm_g, nrm_c = 1 + np.max(np.abs(g), initial=0.0), 1 + np.max(np.abs(cv), initial=0.0)

    def A(mats: list[np.ndarray]) -> np.ndarray:
        return GvT @ blocks.join(mats)

    def At(y: np.ndarray) -> list[np.ndarray]:
        return blocks.split(Gv @ y)

    # SDPT3's infeasible start X = ξI, Z = ηI, y = 0
    col_norm = np.sqrt(np.asarray(Gv.multiply(Gv).sum(axis=0))).ravel()
    nmax = max(sizes)
    xi = max(10.0, np.sqrt(nmax), float(np.max(nmax * (1 + np.abs(g)) / (1 + col_norm))))
    eta = max(10.0, np.sqrt(nmax), float(np.linalg.norm(cv)), float(col_norm.max()))
    X, Z, y = blocks.identity(xi), blocks.identity(eta), np.zeros(g.size)
    C = blocks.split(cv)
    gamma = GAMMA_START if step_fraction is None else step_fraction
    status, message, it = Status.MAX_ITERATIONS, "", 0
    settled, tries = False, 0  # ended by ``settle``; its tests made
    best: tuple | None = None
    clock = _StallClock(tol)
    jammed = 0  # jammed steps in a row (JAM_STEP)
    asked = -1  # the best iterate ``stop`` was last asked about
    par = BlockThreads(threads if threads is not None else (None if threaded(sizes) else 1))

    def steps(dX: list[np.ndarray], dZ: list[np.ndarray]) -> tuple[float, float]:
        """The primal and dual step lengths, side by side."""
        fp = par.submit(step, LXi, dX, gamma)
        ad = step(LZi, dZ, gamma)
        return fp.result(), ad

    # overflow is caught where it matters: a direction that is not finite ends the solve (``direction``)
    with par, np.errstate(over="ignore", invalid="ignore"):
        for it in range(max_iter + 1):
            rp = g - A(X)
            Rd = [Cg - Ag - Zg for Cg, Ag, Zg in zip(C, At(y), Z)]
            pobj, dobj = float(cv @ blocks.join(X)), float(g @ y)
            mu = _inner(X, Z) / blocks.order
            gap = abs(pobj - dobj) / max(abs(pobj), abs(dobj), GAP_FLOOR)
            pinf = float(np.max(np.abs(rp), initial=0.0)) / nrm_g
            dinf = max(float(np.max(np.abs(R), initial=0.0)) for R in Rd) / nrm_c
            err = max(gap, pinf, dinf)
            if verbose:
                print(f"{it:3d} pobj {pobj:+.10e} dobj {dobj:+.10e} gap {gap:.1e} pinf {pinf:.1e} dinf {dinf:.1e}")
            if best is None or err < best[0]:
                best = (err, [x.copy() for x in X], y.copy(), pobj, dobj, gap, pinf, dinf, it)
            xv = (blocks.join(X) if settle is not None and tries < SETTLE_TRIES and err > tol
                  and max(pinf, dinf) <= REDUCED_TOL_FEAS else None)
            if xv is not None and settle is not None and settle.may(pobj, dobj, float(np.sum(xv[settle.diag]))):
                tries += 1
                if settle.test(P.T @ xv, y):
                    best = (err, [x.copy() for x in X], y.copy(), pobj, dobj, gap, pinf, dinf, it)
                    status, message, settled = Status.INSUFFICIENT_PROGRESS, f"iteration {it} settles the verdict", True
                    break
            clock.tick(it, err, abs(pobj - dobj), gap, pinf, dinf)
            if err <= tol:
                status = Status.SOLVED
                break
            if it == max_iter:
                break
            if time.perf_counter() - t0 > time_limit:
                status = Status.MAX_TIME
                break
            stall = clock.stalled(it)
            if stall:
                status, message = Status.INSUFFICIENT_PROGRESS, f"no progress in {stall} iterations"
                break
            if jammed >= JAM_ITERATIONS and almost_solved(Status.INSUFFICIENT_PROGRESS, *best[5:8]):
                status, message = Status.INSUFFICIENT_PROGRESS, f"{jammed} jammed steps (< {JAM_STEP:g})"
                break
            if (stop is not None and it - best[8] >= STOP_ASK_ITERATIONS and best[8] != asked
                    and almost_solved(Status.INSUFFICIENT_PROGRESS, *best[5:8])):
                asked = best[8]
                if stop(best[2]):
                    status = Status.INSUFFICIENT_PROGRESS
                    message = f"stopped by the caller's test of y (iteration {asked})"
                    break
            try:
                # the (inverse) Cholesky factors of X and Z: the step lengths of every direction of this
                # iteration, NT's scaling and Z⁻¹ = L_Z⁻ᵀ L_Z⁻¹ (one factorisation per block and iteration)
                fz = par.submit(_inverse_factors, Z)
                L, LXi = _inverse_factors(X)
                _, LZi = fz.result()

                def z_inverse() -> list[np.ndarray]:
                    return [np.swapaxes(Li, -1, -2) @ Li for Li in LZi]

                Zinv = z_inverse() if search == "hkm" else None  # NT needs it only when the corrector falls back
                if search == "nt":
                    # NT scaling: X = L Lᵀ, Lᵀ Z L = U Λ² Uᵀ, G = L U Λ^(−1/2), W = G Gᵀ (W Z W = X);
                    # in the scaled space G⁻¹ X G⁻ᵀ = Gᵀ Z G = Λ
                    lam, G, Ginv, W = (list(t) for t in zip(*par.each(_nt_scaling, L, Z, LXi)))
                    left, right = W, W
                else:  # HKM: ΔX = H − X ΔZ Z⁻¹
                    assert Zinv is not None
                    left, right = X, Zinv
                fk = par.submit(lambda: [a @ Rg @ b for a, Rg, b in zip(left, Rd, right)])
                solve = schur.factor(schur.assemble(left, right, par), SCHUR_REG, par)
                KRd = fk.result()

                def direction(H: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray, list[np.ndarray]]:
                    """(ΔX, Δy, ΔZ) with ΔX = sym(H − 𝒦(ΔZ)), ΔZ = Rd − A*(Δy), A(ΔX) = rp;
                    𝒦(R) = X R Z⁻¹ (HKM) or W R W (NT).  A direction that overflows (S numerically singular,
                    seen where X grows on blocks nothing bounds) raises ``LinAlgError``: a numerical breakdown."""
                    dy = solve(rp - A([Hg - Kg for Hg, Kg in zip(H, KRd)]))
                    dZ = [Rg - Ag for Rg, Ag in zip(Rd, At(dy))]
                    dX = par.each(_primal_direction, H, left, dZ, right)
                    if not (np.all(np.isfinite(dy)) and all(np.all(np.isfinite(a)) for a in dX + dZ)):
                        raise np.linalg.LinAlgError(f"the Newton direction overflowed at iteration {it}")
                    return dX, dy, dZ

                dX, dy, dZ = direction([-Xg for Xg in X])  # predictor: σ = 0
                ap, ad = steps(dX, dZ)
                mu_aff = _inner([Xg + ap * a for Xg, a in zip(X, dX)], [Zg + ad * b for Zg, b in zip(Z, dZ)])
                sigma = min(1.0, (mu_aff / blocks.order / mu) ** max(1.0, 3 * min(ap, ad) ** 2))
                pred = min(ap, ad)
                if search == "nt":  # Mehrotra's term in the scaled space, Λ∘V = σμI − Λ² − sym(ΔX̃ ΔZ̃)
                    H = par.each(partial(_mehrotra, target=sigma * mu), G, Ginv, lam, dX, dZ)
                else:
                    assert Zinv is not None
                    H = [sigma * mu * Zi - Xg - a @ b @ Zi for Zi, Xg, a, b in zip(Zinv, X, dX, dZ)]
                dX, dy, dZ = direction(H)  # corrector
                ap, ad = steps(dX, dZ)
                if min(ap, ad) < CORRECTOR_FALLBACK * pred:
                    # the second-order term hurts (seen near degenerate optima): centre without it
                    Zinv = Zinv if Zinv is not None else z_inverse()
                    dX1, dy1, dZ1 = direction([sigma * mu * Zi - Xg for Zi, Xg in zip(Zinv, X)])
                    ap1, ad1 = steps(dX1, dZ1)
                    if min(ap1, ad1) > min(ap, ad):
                        dX, dy, dZ, ap, ad = dX1, dy1, dZ1, ap1, ad1
            except np.linalg.LinAlgError as e:  # the factorisation broke down (raised by _Schur.factor)
                status, message = Status.NUMERICAL_ERROR, str(e)
                break
            if verbose:
                print(f"    σ {sigma:.1e}  steps {ap:.2e} {ad:.2e}")
            jammed = jammed + 1 if max(ap, ad) < JAM_STEP else 0
            X = [Xg + ap * a for Xg, a in zip(X, dX)]
            y = y + ad * dy
            Z = [Zg + ad * b for Zg, b in zip(Z, dZ)]
            gamma = GAMMA_START + GAMMA_GAIN * min(ap, ad) if step_fraction is None else step_fraction
    assert best is not None  # the loop body runs at least once
    err, Xb, yb, pobj, dobj, gap, pinf, dinf, _ = best
    if almost_solved(status, gap, pinf, dinf):
        message = f"{status}: {message}" if message else status
        status = Status.ALMOST_SOLVED
    z = P.T @ blocks.join(Xb)
    return IPMSolution(status, z, yb, pobj, dobj, gap, pinf, dinf, it, time.perf_counter() - t0, message, settled)


#: weight of the dense per-block terms of ``iteration_cost`` (BLAS-3 products) against the factorisation of
#: S, and the per-block overhead in the same units
DENSE_WEIGHT = 0.1
BLOCK_OVERHEAD = 1e6


def iteration_cost(sizes: Sequence[int], inc: Sequence[np.ndarray], M: int) -> float:
    """Estimated cost of one iteration on blocks of n_k columns touched by the m_k = |inc[k]| constraints
    (of M in all; ``chordal.block_incidence``): Σ_k DENSE_WEIGHT·(n_k⁴ + m_k² n_k²) (the kernel P_k ⊗ Q_k
    and the block's part of S) + M b² (factorising S, whose half bandwidth in ``band_order`` is b: the
    band's Cholesky, and a bound on the sparse LDLᵀ's fill) + BLOCK_OVERHEAD per block (the per-block work in
    Python).  A ranking, not a prediction.  A block-separable Σ_k m_k³ in place of M b² would miss the
    constraints that spill across blocks far apart in the clique tree, which widen S's band
    (benchmarks/README.md, "Cover choice")."""
    n = np.asarray(sizes, float)
    m = np.array([i.size for i in inc], float)
    _, b = band_order(inc, M)
    return float(np.sum(DENSE_WEIGHT * (n ** 4 + m ** 2 * n ** 2) + BLOCK_OVERHEAD) + float(M) * b * b)


#: the IPM's tolerance is max(SolverConfig.tol, IPM_MIN_TOL): on tight, primal-degenerate SDPs the
#: Schur complement's conditioning (~1/μ²) limits its attainable relative residuals to about 1e-8
IPM_MIN_TOL = 1e-7


def solve_ipm(Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, opts: SolverConfig, finished: bool = True,
              stop: StopRule | None = None, settled: EarlySettle | None = None) -> SDPResult:
    """The Shor SDP by our IPM on the clique blocks of ``clique_program`` (one block of all N
    columns when ``cliques`` is None), with ``opts.ipm``'s search direction.  X is completed from the
    blocks' rank-d factors.  ``finished``: with X's eigenvalues, log SVR and Θ (``result.finish``); False
    leaves them to the caller (the SDP layer, which finishes once, after undoing its scaling).  ``stop``: see
    ``solve_blocks``, given the multipliers of the constraints As (m,).  ``settled``: asked of the iterates as
    ``backend.EarlySettle`` says, with the result of the iterate (``result`` below) and (Q, As as COO, b); the
    costs it pre-tests are those of Q, the IPM's divided by ``prog.scale``."""
    t0 = time.perf_counter()
    prog = clique_program(Q, As, b, cliques if cliques is not None else [np.arange(Q.shape[0])])
    t1 = time.perf_counter()
    blocks_stop = None if stop is None else (lambda y: stop(y[:prog.m] / prog.scale))  # y as ``res.y`` below

    def result(status: str, z: np.ndarray, y_all: np.ndarray, time_s: float, iterations: int,
               message: str) -> SDPResult:
        X, svrs, completion = complete_auto(prog, z, d)
        y = y_all[:prog.m] / prog.scale
        return SDPResult(status=status, solver="autotight-ipm", d=d, X=X, y=y,
                         primal_cost=float(Q.multiply(X).sum()) if X is not None else float("nan"),
                         dual_cost=float(np.dot(b, y)), solve_time_s=time_s, setup_time_s=t1 - t0,
                         iterations=iterations, clique_log_svr=svrs or None, cliques=prog.cliques if svrs else None,
                         completion=completion, message=message)

    settle = None
    if settled is not None:
        coo = [sp.coo_array(A) for A in As]
        top = float(abs(Q).max()) if Q.nnz else 0.0
        seen, diag, voff = np.zeros(Q.shape[0], bool), [], 0
        for C in prog.cliques:  # each column's diagonal entry in the first block that holds it
            f = np.flatnonzero(~seen[C])
            diag.append(voff + f * (len(C) + 1))
            seen[C] = True
            voff += len(C) ** 2
        settle = Settle(lambda pobj, dobj, tr: settled.may_settle(pobj / prog.scale, dobj / prog.scale, top * tr),
                        lambda z, y: settled(result(Status.INSUFFICIENT_PROGRESS, z, y, 0.0, 0, ""), Q, coo, b),
                        np.concatenate(diag))
    sol = solve_blocks(prog.F, prog.c, prog.g, prog.sizes, tol=max(opts.tol, IPM_MIN_TOL),
                       max_iter=opts.max_iter, time_limit=opts.time_limit, verbose=opts.verbose,
                       search=opts.ipm.search, step_fraction=opts.ipm.step_fraction, threads=opts.ipm.threads,
                       stop=blocks_stop, settle=settle)
    res = result(sol.status, sol.z, sol.y, sol.time_s, sol.iterations, (f"{sol.message}; " if sol.message else "")
                 + f"relative gap {sol.gap:.1e}, pinf {sol.pinf:.1e}, dinf {sol.dinf:.1e}")
    res.settled = sol.settled
    return finish(res) if finished else res


#: the fixed step fraction of the retry (``IPMBackend.retries``), the statuses that get it, and the largest
#: number of columns that gets it (the SDP layer's ``FALLBACK_MAX_N``: above, the pipeline certifies the local
#: solution with the stalled solve's multipliers instead, ``pipeline.solve_relaxation``)
RETRY_STEP_FRACTION = 0.9
RETRY_STATUSES = (Status.INSUFFICIENT_PROGRESS, Status.NUMERICAL_ERROR)
RETRY_MAX_N = FALLBACK_MAX_N


class IPMBackend:
    """Our IPM (this module) on the clique cover of policy "ipm"; an unusable result is solved again
    by Clarabel (``fallback``) on Clarabel's own cover.

    Retry (``retries``): a solve with SDPT3's step lengths that stalls (``RETRY_STATUSES``) on at most
    ``RETRY_MAX_N`` columns is solved again with the fixed fraction ``RETRY_STEP_FRACTION``, whose shorter
    steps do not jam where SDPT3's do after a full step (low-noise instances).  Not the default: it takes
    more iterations where SDPT3's rule converges (benchmarks/README.md, "Step lengths and the retry")."""

    name = "ipm"
    decompose_default = True
    cover = "ipm"
    fallback = "clarabel"
    min_tol = IPM_MIN_TOL  # a tighter SolverConfig.tol solves to this (``sdp.effective_tol``)
    stops_early = True  # ``solve`` takes a stop rule (``backend.Backend``)
    errors: tuple[type[BaseException], ...] = ()  # a breakdown of S's factorisation is a status already

    def check(self, arg: str | None) -> None:
        if arg is not None:
            raise SolverConfigError(f"backend 'ipm' takes no argument, got 'ipm:{arg}'")

    def solve(self, Q: sp.csr_array, As: Sequence[sp.csr_array], b: np.ndarray, d: int,
              cliques: Sequence[np.ndarray] | None, config: SolverConfig, stop: StopRule | None = None,
              settled: EarlySettle | None = None) -> SDPResult:
        # the layer finishes (``sdp._solve``)
        return solve_ipm(Q, As, b, d, cliques, config, finished=False, stop=stop, settled=settled)

    def retries(self, config: SolverConfig, decomposed: bool, N: int) -> Retries:
        if config.ipm.step_fraction is not None or N > RETRY_MAX_N:
            return []
        fixed = replace(config, ipm=replace(config.ipm, step_fraction=RETRY_STEP_FRACTION))
        return [(f"the fixed step fraction {RETRY_STEP_FRACTION}", fixed, RETRY_STATUSES)]
