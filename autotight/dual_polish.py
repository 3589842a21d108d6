"""Polish an SDP's multipliers onto the best feasible point's complementarity; keep the better bound.

An interior-point solve returns y that is dual infeasible by its accuracy: H(y) = Q − Σ yᵢAᵢ has
λ_min < 0 of that order, and bᵀy can then lie above the cost f(x̂) of a feasible point x̂.  Measured on
continuous time (K = 21, paper's families), Solved and AlmostSolved alike: bᵀy above f(x̂) by 1e-8 to
1e-5 relative at every σ; a tighter tolerance, Clarabel's default regularisation, no decomposition or
our IPM left it there (they stall or stop at the same accuracy).

At a tight relaxation the dual optimal face is {y : H(y) ⪰ 0, H(y)Θ̂ᵀ = 0}, and the solver's y lies
within its accuracy of that face.  ``certificate.polish_dual`` moves y by the least change (2-norm)
onto the affine part H(y)Θ̂ᵀ = 0; then bᵀy′ = f(x̂) − ⟨H(y′), Θ̂ᵀΘ̂⟩ = f(x̂) up to x̂'s constraint
residual and its stationarity (x̂ is stationary only to the local solver's accuracy).  That alone
proves nothing (it holds for any x̂): y′ is worth its lower bound
    L(y′) = bᵀy′ − max(−λ⁻(H(y′)), 0)·tr X,
λ⁻ the certified lower bound on λ_min of ``certificate.lambda_min``, exactly as the bracket test
(``tightness``) corrects the solver's own y.

``polished`` takes two steps.
1. It keeps y′ when y′ certifies x̂ and y does not, or when
   - L(y′) > L(y), or bᵀy > f(x̂) (a claimed bound above a feasible cost: y is certainly infeasible)
     and y′ is no less dual feasible (λ_min(H(y′)) ≥ λ_min(H(y)), estimates), and
   - bᵀy′ ≤ max(bᵀy, f(x̂)): the polish never creates an excess over f(x̂).
   (A y that must vanish on recession columns, ``certificate`` docstring, is certified only after
   the polish, which enforces that.)
   L alone cannot choose at low noise: λ⁻ is then the roundoff floor λ̂ − n·ε·max|H| for both, and
   n·ε·max|H|·tr X is as large as the excess that the polish removes.  Where x̂ is not optimal for
   the relaxation (a loose relaxation, or a worse local minimum) no y′ with H(y′)Θ̂ᵀ = 0 is near PSD
   and y is kept.
2. If the y kept still has bᵀy > f(x̂) (x̂ is stationary only to the local solver's accuracy, so
   H(y′)Θ̂ᵀ = 0 holds only to that accuracy too), the multipliers of (X_hh)_ii = 1 are lowered by the
   excess δ (δ/d each, ``lower_to_cost``): bᵀy drops to f(x̂) and H gains (δ/d)·I on the h block, so
   it is at least as PSD as before.  This is the complementarity ⟨H, X̂⟩ ≥ 0 that every dual feasible y
   has at a feasible X̂, restored on the side where it costs no dual feasibility.  Only an excess that
   the solve's accuracy explains is absorbed (``allowed_excess``); a larger one is left in place, and the
   bracket then reports the solve as inconsistent (undecided) instead of closing.
Either step is recorded: the solver's own dual cost stays in ``SDPResult.dual_cost_raw`` and the
steps in ``SDPResult.message``; the certificate and the bracket use the y kept, whose λ_min is
computed afresh.

Continuous time, σ = 0.01, seed 1: bᵀy − f(x̂) = +8.1e-7 relative with λ_min(H(y)) = −1.1e-9 (the
excess is that infeasibility times tr X ≈ 95); after the polish −5.3e-10 with λ_min = +7.8e-13
(‖δy‖ = 4.9e-6 against ‖y‖ = 1.7e3).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from .certificate import Certificate, certificate, polish_dual, stack, tolerance_scale
from .model import Constraint
from .sdp.result import SDPResult


def closes(cert: Certificate, Q, Th: np.ndarray, tol: float, floor: float) -> bool:
    """Whether f(x̂) − bᵀy is within the certificate's tolerance (``certificate.certificate``): only then
    can some frame's certificate of this bᵀy succeed."""
    denom = tolerance_scale(cert.cost, float(abs(Q).max()) if Q.nnz else 1.0, float(np.sum(Th * Th)), floor)
    return bool(np.isfinite(cert.dual_value) and cert.cost - cert.dual_value <= tol * denom)


def lower_bound(cert: Certificate, trace_X: float) -> float:
    """L = bᵀy − max(−λ⁻(H(y)), 0)·tr X for the y that ``cert`` was made from (module docstring)."""
    return float(cert.dual_value - max(-cert.lambda_lower, 0.0) * trace_X)


def homogenising_rows(constraints: Sequence[Constraint]) -> list[int]:
    """Indices of the constraints (X_hh)_ii = 1: those of ``Model.homogenisation`` with b = 1 (its
    off-diagonal ones have b = 0)."""
    return [i for i, c in enumerate(constraints) if c.family == "homogenisation" and c.b == 1.0]


def lower_to_cost(constraints: Sequence[Constraint], y: np.ndarray, excess: float) -> np.ndarray | None:
    """y with the multipliers of (X_hh)_ii = 1 lowered by ``excess``/d each (d of them): bᵀy drops by
    ``excess`` and H = Q − Σ yᵢAᵢ gains (excess/d)·I on the h block, so it is at least as PSD.  None
    when the constraints hold no such rows."""
    rows = homogenising_rows(constraints)
    if not rows:
        return None
    out = np.array(y, dtype=float)
    out[rows] -= excess / len(rows)
    return out


def allowed_excess(res: SDPResult, Q, constraints: Sequence[Constraint], lambda_lower: float, f_hat: float,
                   tol: float, floor: float) -> float:
    """The largest excess bᵀy − f(x̂) (f̂ = ``f_hat``) that step 2 may absorb: what the solve's own accuracy explains
    (``tightness.accuracy``: |P − D|, the primal and the dual residual terms) plus the bracket's
    tolerance tol·(|f(x̂)| + floor·s), s the cost's scale.  Beyond it the multipliers claim a bound above
    a feasible cost that the solve's accuracy cannot account for: the solve is inconsistent (or x̂ is not
    feasible for these constraints), and lowering would hide it."""
    from .tightness import accuracy

    acc = accuracy(res, Q, constraints, lambda_lower)
    return float(acc.acc + tol * (abs(f_hat) + floor * acc.scale))


def gap_stays_open(res: SDPResult, Q, constraints: Sequence[Constraint], y: np.ndarray, cert: Certificate,
                   tol: float, floor: float) -> bool:
    """Whether no multipliers of this relaxation can certify x̂: the bracket (``tightness.bracket``, with the
    certificate's tolerances, against U = f(x̂), on the accuracy of the multipliers kept so far) says not tight.

    Every y on a face (``autotight.face``) or in a recession frame (``autotight.recession``) is dual feasible
    for the relaxation itself, so by weak duality its bᵀy is at most the relaxation's optimum, which the solve's
    X puts at P = ⟨Q, X⟩ up to its accuracy.  A certificate needs bᵀy within the tolerance of f(x̂); once
    f(x̂) − P exceeds the tolerance plus that accuracy, neither the face's own dual (an SDP solve) nor a
    recession frame can close it, and they are not tried."""
    from .tightness import NOT_TIGHT, Criteria, accuracy, bracket

    kept = replace(res, y=y, dual_cost=cert.dual_value)
    crit = Criteria(gap_tol=tol, cost_atol=tol * floor)  # tol = gap_tol, floor = cost_atol / gap_tol
    return bool(bracket(kept, cert.cost, crit, accuracy(kept, Q, constraints, cert.lambda_lower))[0] == NOT_TIGHT)


def polished(Q, constraints: Sequence[Constraint], res: SDPResult, theta_hat: np.ndarray, *, d: int = 1,
             tol: float = 1e-6, floor: float = 1e-12,
             names: Sequence[str] | None = None) -> tuple[SDPResult, Certificate | None]:
    """``res`` with its multipliers polished by the rules of the module docstring at the best feasible
    point x̂ (Θ̂ = ``theta_hat``, (N,) or (d, N)), and the certificate of x̂ from the y kept
    (``certificate.certificate`` with ``tol`` and ``floor``).  (res, None) when the solve returned no
    finite y; its own y and certificate when X is unusable (no tr X to weigh two multipliers by).
    Where neither y nor a face of columns certifies but bᵀy closes the bracket, the frame of the
    relaxation's recession directions is tried (``autotight.recession``); the certificate is then that
    frame's (same y, same bound).  Neither a face nor a frame is tried when f(x̂) − P already exceeds the
    tolerance plus the solve's accuracy (``gap_stays_open``: no dual bound of this relaxation can close that; the
    bracket's "not tight" says why).  names: the columns' names, for the certificate's description."""
    if res.y is None or not np.all(np.isfinite(res.y)):
        return res, None
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    cert = certificate(Q, constraints, res.y, Th, d=d, tol=tol, floor=floor)
    if not res.usable or res.X is None:
        return res, cert
    As, _ = stack(constraints)
    y, steps = res.y, []
    y0_lambda_lower = cert.lambda_lower
    y2 = polish_dual(Q, As, res.y, Th)
    if np.all(np.isfinite(y2)):
        # the trace bound depends on the data and x̂ only, not on y: computed once (8 s at discrete K = 1000)
        cert2 = certificate(Q, constraints, y2, Th, d=d, tol=tol, floor=floor, trace=cert.trace,
                            method="given y, polished")
        trX = float(res.X.trace())  # res.usable: X is there
        contradicts = cert.dual_value > cert.cost  # bᵀy above f(x̂): y is infeasible by at least that much
        better = (lower_bound(cert2, trX) > lower_bound(cert, trX)
                  or (contradicts and cert2.lambda_min >= cert.lambda_min))
        # never a new excess over f(x̂), unless y′ certifies x̂ (step 2 then lowers the excess, keeping H ⪰ 0)
        if (cert2.certified and not cert.certified) or (better and cert2.dual_value <= max(cert.dual_value,
                                                                                           cert.cost)):
            steps.append(f"polished onto H(y)Θ̂ᵀ = 0 (‖δy‖ = {np.linalg.norm(y2 - y):.1e})")
            y, cert = y2, cert2
    free = None  # the columns set aside on a face, if one certified
    # no face or frame can certify where the bracket is open (its "not tight" then says why)
    hopeless = not cert.certified and gap_stays_open(res, Q, constraints, y, cert, tol, floor)
    if not cert.certified and not hopeless:  # the face of the bounded columns (autotight.face)
        from .face import face_certificate

        y, cert, note, free = face_certificate(Q, constraints, y, Th, cert, d=d, tol=tol, floor=floor,
                                               trace=cert.trace)
        steps += [note] if note else []
    judged = (Q, constraints, Th)  # the data the certificate is made in (a recession frame's, below)
    if not cert.certified and not hopeless and closes(cert, Q, Th, tol, floor):
        from .recession import frame_certificate

        got = frame_certificate(Q, constraints, y, Th, cert, d=d, tol=tol, floor=floor, names=names,
                                more=[res.y] if y is not res.y else [])
        if got is not None:
            y, cert, note, free, judged = got
            steps.append(note)
    excess = cert.dual_value - cert.cost
    allowed = allowed_excess(res, Q, constraints, y0_lambda_lower, cert.cost, tol, floor) if excess > 0 else 0.0
    y3 = lower_to_cost(constraints, y, excess) if 0 < excess <= allowed else None
    if excess > allowed:
        steps.append(f"not lowered: bᵀy exceeds f(x̂) by {excess:.1e}, beyond the solve's accuracy {allowed:.1e} "
                     "(an inconsistent solve)")
    if y3 is not None:
        face = cert.face
        Qj, cons_j, Th_j = judged
        cert = certificate(Qj, cons_j, y3, Th_j, d=d, tol=tol, floor=floor, trace=cert.trace,
                           method=cert.method.split(";")[0] + ", lowered to f(x̂)", free=free)
        cert.face = face if free is not None else cert.face
        steps.append(f"h² multiplier lowered by {excess:.1e}")
        y = y3
    if not steps:
        return res, cert
    note = f"y {' and '.join(steps)}: dual cost {res.dual_cost:.10g} → {cert.dual_value:.10g}"
    return replace(res, y=y, dual_cost=cert.dual_value, dual_cost_raw=res.dual_cost,
                   message=f"{res.message}; {note}" if res.message else note), cert
