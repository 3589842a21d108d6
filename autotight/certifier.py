"""Certify a local solution x̂ without solving the full SDP.

x̂ (lifted: Θ̂, d×N) is globally optimal for the relaxation iff some y gives H(y) = Q − Σ yᵢAᵢ ⪰ 0 with
H(y)Θ̂ᵀ = 0.  With redundant constraints such y are not unique (the stationarity system has a
nullspace of dimension 100 at pose averaging M = 10, 371 at discrete K = 20), so finding one is a
convex feasibility problem.  Ours, on a clique tree of the data (``sdp.clique_program``):

1. Chordal form.  By Agler's theorem every H ⪰ 0 with the chordal pattern is Σ_k E_kᵀ S_k E_k with
   S_k ⪰ 0, S_k = C_k − F_k w affine in w = (y, the transfers t on the clique overlaps).  Θ̂HΘ̂ᵀ = 0
   forces S_kΘ̂_kᵀ = 0 in every clique: linear equalities L w = l.  With U_k an orthonormal basis of
   Θ̂_k's rows, on {Lw = l}:  S_k ⪰ λ on the complement of U_k  ⟺  S̃_k = S_k + α U_kU_kᵀ − λI ⪰ 0
   (α = 1 on the cost scaled to max|Q_ij| = 1, for 0 ≤ λ ≤ α).
2. A phase-I barrier method (``phase_one``).  Starting from the least-squares w₀ of L w = l (LSQR)
   and λ₀ below every block's smallest eigenvalue, damped Newton steps on
       −τλ − Σ_k log det S̃_k(w, λ) + β/2 ‖D(Lw − Lw₀)‖²
   (D: L's inverse row norms).  The equalities are kept by this penalty (β = ``PENALTY`` × the
   barrier Hessian's mean diagonal) rather than by a KKT system: L has dependent rows, and the
   quasi-definite KKT matrix broke down in LDLᵀ without pivoting.  LᵀL lies on the barrier Hessian's
   pattern, so each step assembles one sparse positive definite matrix, Σ_k F_kᵀ(S̃_k⁻¹ ⊗ S̃_k⁻¹)F_k
   + βLᵀD²L bordered by the dense λ row (the Schur-complement assembly of ``schur_ipm._Schur``), and
   factors it once (qdldl: ordering once, a numeric refactorisation per step).  The Newton step is
   affine in τ, Δ = Δ₀ + τΔ₁, so τ is chosen after the factorisation: the largest of τ·``TAU_FACTORS``
   whose step to the boundary of every block is ≥ ``MIN_STEP`` (then damped by ``STEP_FRACTION``).
   Stop "feasible" when λ ≥ ``target`` (every S_k is PSD with a margin on the complement of Θ̂_k);
   stop "infeasible" after a full step from near the centre of τ (Newton decrement ≤ 1/2) with
   λ + 2ν/τ < 0 (ν = Σ|C_k|: near the central path the best margin λ* ≤ λ + ν/τ is then negative, no
   certificate exists); or after ``max_iter`` steps.  Long steps can jam near the boundary far from
   the central path (discrete K = 10, seeds 4 and 6: a fake optimum at λ = −0.08 on the default
   cover); a run that does not end "feasible" is repeated with τ growing only from near-centred
   points (Newton decrement² ≤ ``CENTRED_DECREMENT``; 25–45 steps there).  At tight instances the
   margin is large (λ* ≈ 0.03 of max|Q| at discrete K = 10) and 1–7 long steps suffice, where the
   full SDP's interior-point method needs 15–30 iterations of similar cost, on X and y
   (benchmarks/certify.py).
3. Check.  The y part of w goes to the exact certificate of ``autotight.certificate`` (sparse
   certified λ_min(H) by LDLᵀ inertia, the trace bound, the suboptimality bound), which decides.  The
   barrier only proposes y, so no speed trick can produce a false "certified".

Scope.  The Newton matrix has about Σ_k m_k² entries (m_k: the variables touching block k), and each
step costs about as much as an iteration of the full SDP's IPM (discrete K = 100: 18 steps, as long as
the full solve).  From ``PROJECTION_MIN_N`` columns on (discrete trajectory from K ≈ 40), step 2 is
first replaced by Douglas–Rachford splitting between the affine set and the cone
(``autotight.dual_projection``: one sparse factorisation, then per round a solve and the blocks'
small eigenproblems; no Newton matrix).  Given the diagonal scale D of x̂'s blocks (``certify_model``
passes it), the rounds run on the congruent data D Q D, D Aᵢ D, and the polish weighs stationarity by D
in the metric of its system's column norms (``_certify_projected``).  Without D the polished y gets an
LSQR refinement of the stationarity residual (``LSQR_REFINE_ITER`` iterations at most; the min-norm
polish alone leaves ‖H Θ̂ᵀ‖ at 1e-6 relative at discrete K = 1000, a relative bound of 5e-5).  Where that
does not certify, or below PROJECTION_MIN_N columns, the barrier runs if its Newton matrix fits (at
most ``NEWTON_MAX_ENTRIES`` entries) and its factorisation is cheap enough (``newton_flops``, at most
``NEWTON_MAX_FLOPS``); if it does not and N < ``FALLBACK_MAX_N`` (continuous time,
whose cliques of up to 67 columns share thousands of transfers, and where Douglas–Rachford stalls at
a margin of −0.04), certify solves the full SDP, polishes its y as the pipeline does
(``dual_polish.polished``) and certifies it the same way: the verdict stays right, without the
speed-up.  Above FALLBACK_MAX_N neither the barrier nor a full SDP runs after Douglas–Rachford: certify
stays sparse and linear in the chain's length, and "not certified" then says only that no certificate was
found (``autotight solve`` decides): at that size the barrier's Newton steps cost as much as the full SDP's
iterations.

A negative final margin means no certificate exists for x̂ (it is not a global minimiser of a tight
relaxation); the returned Certificate then carries the bound that the best y found still proves.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .certificate import Certificate, certificate, entries, polish_dual, stack
from .dual_polish import closes
from .model import Constraint, Model
from .svec import reusing_entries
from .threads import single_blas_thread

if TYPE_CHECKING:
    from .problem import LocalResult

#: candidate growth factors of τ per Newton step (the largest whose step is long enough is taken)
TAU_FACTORS = (1000.0, 300.0, 100.0, 30.0, 10.0, 5.0, 3.0, 2.0, 1.5, 1.0)
#: … among those whose step to the boundary is at least this long (then damped by STEP_FRACTION)
MIN_STEP = 0.5
#: weight of the stationarity penalty, relative to the mean diagonal of the barrier's Hessian
PENALTY = 1e6
#: the retry's centring: τ grows only from points with Newton decrement² ≤ this
CENTRED_DECREMENT = 1.0
#: above this many entries (``newton_size``) in the Newton matrix, the barrier is not run (module docstring, Scope)
#: (discrete K = 100: 1.2e6; continuous time K = 11 on the default cover: 3.3e8)
NEWTON_MAX_ENTRIES = 10_000_000
#: … nor above this estimate of one Newton step's factorisation (``newton_flops``): continuous time K = 21 with a
#: learned 2-pair set has 6.2e6 entries but 2.0e10 (a step took 9.7 s, its full SDP 9 s); robust pose averaging M = 6
#: with its learned set 7.3e8 (0.13 s a step), discrete K = 20 and pose averaging M = 10 with the paper's 1.6e7
NEWTON_MAX_FLOPS = 2e9
#: below this many columns, a large program that Douglas–Rachford does not certify falls back to the full SDP's
#: y (continuous time, K = 21: N = 517); above it Douglas–Rachford's certificate is the answer (no barrier, no
#: full SDP: module docstring, Scope)
FALLBACK_MAX_N = 4000
#: from this many columns on, "auto" tries Douglas–Rachford before the barrier (discrete K = 100, N = 2395:
#: 4 rounds, about 1 s, where the barrier took 18 Newton steps and as long as the full SDP's IPM)
PROJECTION_MIN_N = 1000
#: the ways ``certify`` finds y
METHODS = ("auto", "barrier", "projection")
#: μ of Douglas–Rachford in the unscaled frame once the scaled frame did not certify (``_certify_projected``):
#: a set with few redundant constraints leaves a thin feasible set of multipliers, whose margin is small
#: (discrete trajectory K = 200, the 5-pair set of ``discover discrete_trajectory``: 2e-4 … 9e-4 of max|Q|
#: unscaled, 34 rounds at μ = 0.003, where the scaled frame stalls at −0.01 for every μ tried)
THIN_CLIPS = (0.003,)
#: … and its rounds at most (34 there; at K = 500 and 1000 that set stalls in both frames, the SDP being tight)
THIN_ROUNDS = 60
#: LSQR iterations that refine the stationarity of the polished y on large programs (discrete K = 1000: 64)
LSQR_REFINE_ITER = 1000
#: fraction of the distance to the cone's boundary a damped step may cover
STEP_FRACTION = 0.95


def default_cliques(Q: sp.sparray, As: Sequence[sp.sparray], d: int) -> list[np.ndarray]:
    """A chordal clique cover of the data's pattern (h in every clique), merged up to 32 columns."""
    from .sdp.chordal import column_cliques, merge_small

    return merge_small(column_cliques(Q.shape[0], [Q, *As], always=range(d)), 32)


def newton_incidence(prog) -> list[np.ndarray]:
    """Per clique block k, the variables touching it (F's columns in the block's rows), sorted."""
    F = sp.csr_array(prog.F)
    return [np.unique(F.indices[F.indptr[prog.start[k]]:F.indptr[prog.start[k + 1]]]) for k in range(len(prog.cliques))]


def newton_size(prog, inc: Sequence[np.ndarray] | None = None) -> int:
    """Σ_k m_k², m_k the variables touching block k: about the entries of the Newton matrix.  inc:
    ``newton_incidence(prog)`` when known."""
    return int(sum(i.size ** 2 for i in (newton_incidence(prog) if inc is None else inc)))


def newton_flops(prog, inc: Sequence[np.ndarray] | None = None) -> float:
    """M·b²: the flops of a band Cholesky of the Newton matrix (M variables) in the order of
    ``schur_ipm.band_order``, b its half bandwidth there; an estimate of one Newton step's factorisation, whose
    fill ``newton_size`` does not see (it has the same pattern as the IPM's Schur complement).  inc:
    ``newton_incidence(prog)`` when known."""
    from .sdp.schur_ipm import band_order

    M = int(prog.F.shape[1])
    return float(M) * float(band_order(newton_incidence(prog) if inc is None else inc, M)[1]) ** 2


def barrier_too_costly(prog) -> tuple[int, float, bool]:
    """(``newton_size``, ``newton_flops``, whether either is above its limit, ``NEWTON_MAX_ENTRIES`` or
    ``NEWTON_MAX_FLOPS``): the barrier is then not run."""
    inc = newton_incidence(prog)
    size, flops = newton_size(prog, inc), newton_flops(prog, inc)
    return size, flops, size > NEWTON_MAX_ENTRIES or flops > NEWTON_MAX_FLOPS


@dataclass
class PhaseOne:
    """What the barrier method of step 2 found: w = (y scaled, t), the margin λ (scaled cost), why it
    stopped ("feasible" | "infeasible" | "max_iter" | "breakdown: …") and the Newton steps taken."""

    w: np.ndarray
    margin: float
    status: str
    iterations: int


class _Newton:
    """The Newton matrix in (w, λ): the barrier's Hessian (the Schur pattern of ``schur_ipm._Schur`` and
    a dense λ row, last) plus the penalty β·LᵀD²L on the stationarity equalities (D: L's inverse row
    norms; LᵀL lies on the Schur pattern, since each row of L touches one clique).  Positive definite
    (plus ρ = 1e-12 on the equilibrated diagonal), factored by sparse LDLᵀ (qdldl: ordering once, a
    numeric refactorisation per step), equilibrated by its diagonal."""

    def __init__(self, schur, L: sp.csr_array):
        self.schur = schur
        M = schur.M
        self.M = M
        nr = np.sqrt(np.asarray(L.multiply(L).sum(axis=1)).ravel())
        self.DL = sp.csr_array(sp.diags_array(np.where(nr > 0, 1.0 / np.where(nr > 0, nr, 1.0), 0.0)) @ L)
        LtL = sp.coo_array(self.DL.T @ self.DL)
        keys = schur.rows * M + schur.cols
        at = np.searchsorted(keys, LtL.row * M + LtL.col)
        if not np.array_equal(keys[np.minimum(at, keys.size - 1)], LtL.row * M + LtL.col):
            raise ValueError("the stationarity rows leave the Schur pattern")
        self.ltl = np.bincount(at, weights=LtL.data, minlength=keys.size)
        up = schur.cols >= schur.rows
        self.hsel = np.flatnonzero(up)
        r = np.concatenate([schur.rows[up], np.arange(M + 1)])
        c = np.concatenate([schur.cols[up], np.full(M + 1, M)])
        self.r, self.c = r, c
        self.order = np.lexsort((r, c))
        self.indices = r[self.order].astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(c, minlength=M + 1))]).astype(np.int32)
        self.diag_pos = np.flatnonzero(r == c)
        self.solver: Any = None  # a qdldl.Solver after the first factorisation

    def factor(self, hvals: np.ndarray, h: np.ndarray, hll: float, beta: float):
        """A solver for the Newton matrix with barrier Hessian (hvals on the Schur pattern, h the λ
        column, hll its corner) and penalty weight β."""
        import qdldl

        M = self.M
        vals = hvals + beta * self.ltl
        dh = np.append(vals[self.schur.diag], hll)
        dw = np.where(dh > 0, 1.0 / np.sqrt(np.where(dh > 0, dh, 1.0)), 1.0)
        v = np.concatenate([vals[self.hsel], h, [hll]]) * dw[self.r] * dw[self.c]
        v[self.diag_pos] += 1e-12
        A = sp.csc_matrix((v[self.order], self.indices, self.indptr), shape=(M + 1, M + 1))
        if self.solver is None:
            self.solver = qdldl.Solver(A, upper=True)
        else:
            self.solver.update(A, upper=True)
        if not np.all(self.solver.factors()[1] > 0):
            raise ValueError("the Newton matrix is not positive definite")
        U = A
        solver = self.solver

        def solve(rhs: np.ndarray) -> np.ndarray:
            b = dw * rhs
            x = solver.solve(b)
            x = x + solver.solve(b - (U @ x + U.T @ x - U.diagonal() * x))
            return dw * x

        return solve


def phase_one(prog, Th: np.ndarray, *, alpha: float = 1.0, target: float = 1e-6, max_iter: int = 50,
              dec_max: float = np.inf) -> PhaseOne:
    """Step 2 of the module docstring on the clique program ``prog`` for the candidate Θ̂ (d × N).
    dec_max: τ grows only from points whose Newton decrement² is at most this (∞: always)."""
    from .sdp.schur_ipm import _Blocks, _Schur, _sym, svec_to_vec

    sizes = prog.sizes
    P = svec_to_vec(sizes)
    Gv = sp.csr_array(P @ prog.F)
    GvT = sp.csr_array(Gv.T)
    cv = P @ prog.c
    blocks = _Blocks(sizes)
    schur = _Schur(Gv, blocks)
    M = Gv.shape[1]
    Ks, UU = [], np.zeros(blocks.voff[-1])
    for k, C in enumerate(prog.cliques):
        U = np.linalg.qr(Th[:, C].T)[0]  # n_k × d, orthonormal
        Ks.append(sp.kron(sp.identity(len(C)), sp.csr_array(U.T)))  # vec(S) → vec(S U)
        UU[blocks.voff[k]:blocks.voff[k + 1]] = (U @ U.T).ravel()
    K = sp.block_diag(Ks, format="csr")
    L = sp.csr_array(K @ Gv)
    newton = _Newton(schur, L)
    w = spla.lsqr(L, K @ cv, atol=1e-14, btol=1e-14, iter_lim=10 * M)[0]
    Dl = newton.DL @ w  # the penalty's target: the least-squares point's own residual stays
    eye = blocks.join(blocks.identity(1.0))
    base = cv + alpha * UU
    nu = float(sum(sizes))
    S = blocks.split(base - Gv @ w)
    lam = min(min(float(np.linalg.eigvalsh(Sg)[:, 0].min()) for Sg in S) - 1e-3, -1e-3)
    tau = nu / abs(lam)
    status, it = "max_iter", 0
    for it in range(1, max_iter + 1):
        S = blocks.split(base - Gv @ w - lam * eye)
        try:
            chol = [np.linalg.cholesky(Sg) for Sg in S]
        except np.linalg.LinAlgError:
            status = "breakdown: a block left the cone"
            break
        Linv = [np.linalg.inv(c) for c in chol]
        Sinv = [np.swapaxes(Li, -1, -2) @ Li for Li in Linv]
        # gradient and Hessian of −Σ log det S̃ + β/2‖D(Lw − Lw₀)‖² in (w, λ): the λ row is the last one
        hvals = schur.assemble(Sinv, Sinv)
        beta = PENALTY * float(np.mean(hvals[schur.diag]))
        g = np.append(GvT @ blocks.join(Sinv) + beta * (newton.DL.T @ (newton.DL @ w - Dl)),
                      sum(float(np.trace(Si, axis1=1, axis2=2).sum()) for Si in Sinv))
        h = GvT @ blocks.join([Si @ Si for Si in Sinv])
        try:
            solve = newton.factor(hvals, h, sum(float(np.sum(Si * Si)) for Si in Sinv), beta)
        except (RuntimeError, ValueError) as e:
            status = f"breakdown: {e}"
            break
        # Newton direction for −τλ − Σ log det S̃ + penalty:  Δ = Δ₀ + τ Δ₁ (affine in τ)
        e_last = np.zeros(M + 1)
        e_last[-1] = 1.0
        d1, d0 = solve(e_last), solve(-g)
        dw1, dl1, dw0, dl0 = d1[:M], d1[M], d0[:M], d0[M]
        if not dl1 > 0:
            status = "breakdown: the Newton system is not positive definite"
            break
        A1 = [Li @ Dg @ np.swapaxes(Li, -1, -2) for Li, Dg in zip(Linv, blocks.split(-(Gv @ dw1) - dl1 * eye))]
        A0 = [Li @ Dg @ np.swapaxes(Li, -1, -2) for Li, Dg in zip(Linv, blocks.split(-(Gv @ dw0) - dl0 * eye))]

        def max_step(t: float) -> float:
            low = min(float(np.linalg.eigvalsh(_sym(x0 + t * x1))[:, 0].min()) for x0, x1 in zip(A0, A1))
            return np.inf if low >= 0 else -1.0 / low

        dec_now = -(g[:M] @ (dw0 + tau * dw1) + (g[M] - tau) * (dl0 + tau * dl1))
        for f in (TAU_FACTORS if dec_now <= dec_max else (1.0,)):
            step_max = max_step(tau * f)
            if step_max * STEP_FRACTION >= MIN_STEP:
                break
        tau *= f
        step = min(1.0, STEP_FRACTION * step_max)
        dw, dl = dw0 + tau * dw1, dl0 + tau * dl1
        decrement2 = -(g[:M] @ dw + (g[M] - tau) * dl)  # Newton decrement² at τ: distance to the centre
        w = w + step * dw
        lam = lam + step * dl
        if lam >= target:
            status = "feasible"
            break
        # near the centre of τ (decrement ≤ 1/2 before a full step), λ* ≤ λ + ν/τ (+ a margin of ν/τ)
        if step == 1.0 and decrement2 <= 0.25 and lam + 2 * nu / tau < 0:
            status = "infeasible"
            break
    return PhaseOne(w, lam, status, it)


def certify(Q: sp.sparray, constraints: Sequence[Constraint], theta_hat: np.ndarray, *, d: int = 1,
            cliques: Sequence[np.ndarray] | None = None, tol: float = 1e-5, floor: float = 1e-12,
            max_iter: int = 50, trace: float | None = None, scale: np.ndarray | None = None,
            method: str = "auto", names: Sequence[str] | None = None) -> Certificate:
    """Certify x̂ (Θ̂ = ``theta_hat``) for min ⟨Q,X⟩ s.t. ``constraints``, X ⪰ 0 (module docstring).

    certified: the certified suboptimality bound f(x̂) − p* is ≤ tol relative to f(x̂)
    (``certificate.certificate``; the default is ``Criteria.gap_tol``, so that certify and the bracket
    test of a full SDP decide with the same relative gap); floor: the absolute tolerance of a zero-cost
    candidate (``certificate.certificate``).  cliques: a chordal cover containing the
    pattern of Q and every Aᵢ, each with the h columns (default: ``default_cliques``).  max_iter: Newton
    steps of the barrier method.  trace: a known bound on tr(X) (default: derived from the constraints).
    scale: the diagonal scaling D of the full SDP's fallback (``sdp.solve``; None: unscaled).  method: how y
    is found: "barrier" (step 2), "projection" (Douglas–Rachford, module docstring, Scope), or "auto" (the
    order of the module docstring, Scope).  Where the barrier's y does not certify but closes the bracket,
    the frame of the relaxation's recession directions is tried (``recession.frame_certificate``); names:
    the columns' names for its description.
    """
    from .sdp.clique_program import clique_program

    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    t0 = time.perf_counter()
    Q = sp.csr_array(Q)
    As, b = stack(constraints)
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    if cliques is None:
        cliques = default_cliques(Q, As, d)
    prog = clique_program(Q, As, b, [np.asarray(C) for C in cliques])
    tried = ""
    if method == "projection" or (method == "auto" and Q.shape[0] >= PROJECTION_MIN_N):
        cert = _certify_projected(Q, As, constraints, prog, Th, d=d, tol=tol, floor=floor, trace=trace,
                                  scale=scale)
        if cert.certified or method == "projection":
            return replace(cert, time_s=time.perf_counter() - t0)
        if Q.shape[0] >= FALLBACK_MAX_N:
            return replace(cert, time_s=time.perf_counter() - t0,
                           method=f"{cert.method}; from {FALLBACK_MAX_N} columns on neither the barrier nor the full "
                                  "SDP follows: `autotight solve` decides")
        tried = f"Douglas–Rachford did not certify ({cert.method.split(';')[0]}); "
    load, flops, big = barrier_too_costly(prog)
    if big and method == "auto":  # the full SDP's y, certified alike
        import autotight.sdp as sdp
        from .dual_polish import polished

        res = sdp.solve(Q, constraints, d=d, scale=scale)
        note = (f"{tried}full SDP ({res.solver} {res.status}): the Newton matrix would have ~{load:.1e} "
                f"entries (at most {NEWTON_MAX_ENTRIES:.0e}) and ~{flops:.1e} flops a factorisation (at most "
                f"{NEWTON_MAX_FLOPS:.0e})")
        res, polished_cert = polished(Q, constraints, res, Th, d=d, tol=tol, floor=floor)  # as the pipeline's y
        cert = polished_cert if polished_cert is not None else certificate(
            Q, constraints, np.zeros(len(As)), Th, d=d, tol=tol, floor=floor, trace=trace,
            method=note + ", no multipliers")
        return replace(cert, time_s=time.perf_counter() - t0, method=note + "; " + cert.method)
    ph = phase_one(prog, Th, max_iter=max_iter)
    how = "long steps"
    if ph.status != "feasible":  # long steps can jam near the boundary: once more, centred first
        ph2 = phase_one(prog, Th, max_iter=max_iter, dec_max=CENTRED_DECREMENT)
        if ph2.margin > ph.margin:
            ph, how = PhaseOne(ph2.w, ph2.margin, ph2.status, ph.iterations + ph2.iterations), "centred retry"
    y = ph.w[:prog.m] / prog.scale
    if ph.margin > 0:  # the penalty leaves a small residual of H(y)Θ̂ᵀ = 0
        y = polish_dual(Q, As, y, Th)
    cert = certificate(Q, constraints, y, Th, d=d, tol=tol, floor=floor, trace=trace,
                       method=f"{tried}clique barrier ({ph.status}, {how}, {ph.iterations} Newton steps, margin "
                              f"{ph.margin:.2e} of max|Q|, {len(prog.cliques)} cliques ≤ {max(prog.sizes)})")
    if not cert.certified and closes(cert, Q, Th, tol, floor):  # directions along which X grows at no cost
        from .recession import frame_certificate

        got = frame_certificate(Q, constraints, y, Th, cert, d=d, tol=tol, floor=floor, names=names)
        if got is not None:
            cert = got[1]
    return replace(cert, time_s=time.perf_counter() - t0)


def _certify_projected(Q, As, constraints, prog, Th, *, d, tol, floor, trace,
                       scale: np.ndarray | None) -> Certificate:
    """``projected_dual``'s certificate."""
    return projected_dual(Q, As, constraints, prog, Th, d=d, tol=tol, floor=floor, trace=trace, scale=scale)[0]


def projected_dual(Q, As, constraints, prog, Th, *, d: int, tol: float, floor: float, trace: float | None,
                   scale: np.ndarray | None, rounds: int | None = None, clips: tuple[float, ...] | None = None,
                   thin_rounds: int = THIN_ROUNDS) -> tuple[Certificate, np.ndarray]:
    """The certificate of the y that Douglas–Rachford proposes (``dual_projection``), polished onto
    stationarity (module docstring, Scope), and that y.

    scale: D (N,) positive, or None.  With D, the rounds run on the congruent data D Q D, D Aᵢ D and
    Θ̂ D⁻¹ (``CliqueProgram.congruence``): the same multipliers y, and H(y) ⪰ 0 iff D H(y) D ⪰ 0,
    while each block's spectrum is no longer dominated by its largest entries (discrete trajectory
    K = 3000: positions of magnitude 150 beside rotations of 1; margin 5.8e-2 in 3 rounds instead of
    no feasible point in 144).  The polish then weighs the rows of H(y)Θ̂ᵀ = 0 by D, as the bound
    f(x̂) − bᵀy = Σ_j x̂_j (H x̂)_j does, in the metric of the system's column norms (K = 3000: residual
    3.8e-7 of ‖g‖ = 12, where the plain metric and the LSQR refinement stopped at 1.8e-3).  Where that does not
    certify, the unscaled frame is tried once more with a small μ (``THIN_CLIPS``, at most ``thin_rounds``
    rounds): a set with few redundant constraints leaves the cone and the affine set barely intersecting, and
    there the scaled frame does not find the intersection; the better of the two certificates is returned
    (thin_rounds 0: the scaled frame's alone).
    rounds, clips: Douglas–Rachford's rounds per μ and its μ in the first frame (None: ``dual_projection.MAX_ITER``,
    ``dual_projection.CLIPS``)."""
    from .certificate import stationarity_system
    from .dual_projection import CLIPS, MAX_ITER, project_multipliers

    G, g = stationarity_system(Q, As, Th)
    first = MAX_ITER if rounds is None else rounds
    mus = CLIPS if clips is None else clips

    known = trace  # the trace bound, once a certificate has derived it (the same data and x̂ in both frames)

    def judged(pr, y: np.ndarray, frame: str) -> tuple[Certificate, np.ndarray]:
        nonlocal known
        cert = certificate(Q, constraints, y, Th, d=d, tol=tol, floor=floor, trace=known, estimate_lambda=False,
                           method=f"clique Douglas–Rachford ({frame}{pr.status}, {pr.iterations} rounds, margin "
                                  f"{pr.margin:.2e} of max|Q|, {len(prog.cliques)} cliques ≤ {max(prog.sizes)})")
        if known is None:
            known = cert.trace
        elif trace is None and cert.argument != "trace bound":  # reported only where it was derived and used
            cert = replace(cert, trace=None)
        return cert, y

    def unscaled(clips: tuple[float, ...], frame: str, max_rounds: int) -> tuple[Certificate, np.ndarray]:
        pr = project_multipliers(prog, Th, clips=clips, max_iter=max_rounds)
        y = polish_dual(Q, As, pr.w[:prog.m] / prog.scale, Th, system=(G, g))
        y = y + spla.lsqr(G, g - G @ y, atol=1e-14, btol=1e-14, iter_lim=LSQR_REFINE_ITER)[0]
        return judged(pr, y, frame)

    if scale is None:
        return unscaled(mus, "", first)
    D = np.asarray(scale, dtype=float)
    congruent = prog.congruence(D)
    pr = project_multipliers(congruent, Th / D[None, :], clips=mus, max_iter=first)
    weights = np.ones(G.shape[0])
    weights[:Th.size] = np.repeat(D, d)  # row (j, a) of H Θ̂ᵀ: j·d + a (``stationarity_system``)
    Gw, gw = sp.csr_array(sp.diags_array(weights) @ G), weights * g
    y = polish_dual(Q, As, pr.w[:congruent.m] / congruent.scale, Th, system=(Gw, gw), equilibrate=True)
    scaled = judged(pr, y, "scaled frame: ")
    if scaled[0].certified or thin_rounds <= 0:
        return scaled
    plain = unscaled(THIN_CLIPS, "unscaled frame after the scaled one did not certify: ", thin_rounds)
    return plain if plain[0].certified or plain[0].bound < scaled[0].bound else scaled


def model_cliques(model: Model, As: Sequence[sp.sparray]) -> list[np.ndarray]:
    """The clique cover of ``default_cliques`` built on the graph of the model's variable blocks
    (``sdp.chordal.block_cliques``, merged up to 32 columns): the same kind of cover, from a graph about
    20× smaller (discrete K = 1000: 2 s instead of 20 s of min-fill on the columns)."""
    from .sdp.chordal import block_cliques, merge_small

    V = model.variables
    Qc = sp.coo_array(model.Q)
    r, c, v, _ = entries(As)  # both triangles: the block graph is symmetric either way
    rows = np.concatenate([Qc.row[Qc.data != 0], r[v != 0]])
    cols = np.concatenate([Qc.col[Qc.data != 0], c[v != 0]])
    return merge_small(block_cliques([V.sizes[n] for n in V.names], rows, cols), 32)


@single_blas_thread
def certify_model(model: Model, constraints: Sequence[Constraint], theta_hat: np.ndarray, **kw) -> Certificate:
    """``certify`` on a model's cost (keywords as ``certify``), on the cover of ``model_cliques`` from
    ``PROJECTION_MIN_N`` columns on unless ``cliques`` is given (below, ``default_cliques``: on continuous
    time, N = 517, the block cover makes the Newton matrix small enough for the barrier, which does not
    certify there, where the column cover sends it to Douglas–Rachford and the full SDP).  The full SDP's
    fallback is scaled by blocks from x̂ (``sdp.scaling.block_scale``, as the pipeline scales its solves).
    One BLAS thread (``threads``): the blocks are small, and threaded eigendecompositions of 31 × 31
    blocks were 100× slower on a busy machine."""
    from .pretty import column_names
    from .sdp.scaling import block_scale

    kw.setdefault("scale", block_scale(model.variables, [np.asarray(theta_hat, dtype=float).reshape(model.d, -1)]))
    kw.setdefault("names", column_names(model.variables))
    if kw.get("cliques") is None and model.variables.N >= PROJECTION_MIN_N:  # below: ``default_cliques``
        kw["cliques"] = model_cliques(model, stack(constraints)[0])
    return certify(model.Q, constraints, theta_hat, d=model.d, **kw)


@dataclass
class CertifyRun:
    """One ``certify_instance``: the instance, its constraint set's name and constraints, the local solve that was
    certified (``start``: "truth", "random" or "given") and the certificate."""

    instance: object
    constraint_set: str
    constraints: list
    start: str
    local: LocalResult
    certificate: Certificate


@single_blas_thread
def certify_instance(problem, inst, constraints=None, *, start="truth", criteria=None,
                     max_iter: int = 50, model: Model | None = None) -> CertifyRun:
    """Run the local solver on ``inst`` from ``start`` ("truth", "random": the first random start of
    ``autotight.solve`` for this seed, or a state dict), lift its solution and ``certify`` it with the
    constraints of ``constraints`` (as ``autotight.solve``) and the tolerances of ``criteria`` (those
    of the full SDP's bracket test: gap_tol, and cost_atol for zero-cost candidates).  model: ``problem.build(inst)``
    when the caller has it (built here otherwise)."""
    from .constraint_set import resolve, set_name
    from .errors import ParameterError
    from .pipeline import LocalSearch, feasible_points, seeds
    from .tightness import Criteria
    from .validity import check_valid

    criteria = Criteria() if criteria is None else criteria
    s = seeds(inst.seed if inst.seed is not None else 0)
    model = problem.build(inst) if model is None else model
    cons = resolve(constraints, problem, inst, model, s.constraints())
    if isinstance(start, str):
        if start == "truth":
            init = inst.truth
        elif start == "random":
            init = problem.random_state(inst, s.local())
        else:
            raise ParameterError(f"start must be 'truth', 'random' or a state, got {start!r}")
        label = start
    elif isinstance(start, dict):
        missing = sorted(set(inst.truth) - set(start))
        if missing:
            raise ParameterError(f"the start state lacks {', '.join(missing)}")
        try:
            init = {k: np.asarray(start[k], dtype=float).reshape(np.shape(inst.truth[k])) for k in inst.truth}
        except (TypeError, ValueError) as e:
            raise ParameterError(f"the start state does not fit this instance: {e}") from e
        label = "given"
    else:
        raise ParameterError(f"start must be 'truth', 'random' or a state dict, got {type(start).__name__}")
    local = problem.local_solve(inst, init)
    with reusing_entries():  # the check and the certificate read the same stacked entries
        check_valid(problem.name, cons, feasible_points(problem, inst, LocalSearch(local, []), s.validity()))
        cert = certify_model(model, cons, problem.lift(inst, local.state), tol=criteria.gap_tol,
                             floor=criteria.cost_atol / criteria.gap_tol, max_iter=max_iter)
    return CertifyRun(inst, set_name(constraints, model), cons, label, local, cert)
