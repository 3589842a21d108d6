"""When a relaxation counts as tight: a rank test and a bracket test on the cost.

Rank: log SVR = log10(λ_d/λ_{d+1}) of X above ``min_log_svr`` (5, as in the paper).

Cost (the bracket).  The SDP gives D = bᵀy (its dual cost, a lower bound on its value p* up to the
solver's accuracy) and P = ⟨Q,X⟩ (its primal cost); U (``upper``) is the best feasible cost of the QCQP,
so p* ≤ U.  The accuracy this solve reached, ``acc``, is the largest of
  |P − D|;  Σᵢ|yᵢ|·|⟨Aᵢ,X⟩ − bᵢ| (what the primal infeasibility can move the cost by);
  max(−λ_min(H), 0)·tr(X), H = Q − Σ yᵢAᵢ (what the dual infeasibility can move the lower bound by:
  ⟨Q,X'⟩ ≥ D + min(λ_min(H), 0)·tr(X') for every feasible X')
(the last two need the data: pass ``Q`` and ``constraints``; without them acc is |P − D| plus the
roundoff of summing the cost).  L = D − max(−λ_min(H), 0)·tr(X) is the lower end of the bracket.
When the solve used a diagonal scaling X = D X' D (``judge(..., scale=D)``) and the bracket is
undecided, the dual correction is also taken in that frame: ⟨H, X'⟩ = ⟨DHD, D⁻¹X'D⁻¹⟩ ≥
λ_min(DHD)·tr(D⁻¹X'D⁻¹), an equally valid bound, and the smaller correction is used.  On long chains it
is the tighter one by orders: tr(X) grows with the squared positions, tr(D⁻¹XD⁻¹) only with the
number of blocks (discrete trajectory K = 1000: tr(X) = 8.5e5 against 1.3e4).
The gap being tested is  tol = gap_tol·|U| + cost_atol·s,  s = ‖Q‖_max·tr(X) (≥ |⟨Q,X⟩|, the cost's own
scale; without Q: max(Σ|Q_ij X_ij|, |P|, |D|)), so a zero-cost instance is judged by cost_atol alone and
nothing is divided by 0.  Then:
  tight      if U − L ≤ tol (with the data only), or (acc ≤ tol and U − D ≤ tol + acc);
  not tight  if U − P > tol + acc (the SDP's value is below U by more than tolerance and accuracy), or
             the SDP is unbounded (DualInfeasible);
  undecided  otherwise (the solver stopped early or is less accurate than the gap being tested; also any
             unusable solve, except the best iterate of one whose bracket already says not tight, which the SDP
             layer then keeps instead of solving again, ``SDPResult.settled``): never counted as not tight.
             Also undecided instead of not tight: a
             tolerance at least the cost it tests, tol ≥ |U| > ``ROUNDOFF``·s (ill-conditioned weights
             make s, hence tol, exceed the cost, and P < U − tol ≤ 0 is then a solve that cannot
             resolve the cost, not a gap).  Where such a bracket closes, it proves little: under
             accept="rank" the rank test decides, under accept="cost" only a certificate does.
The reported ``rel_gap`` is (U − P)/max(|U|, cost_floor).

``accept`` says which verdict counts as ``tight``: "rank" (rank and cost, the paper's; a low rank
counts as not tight only when the bracket is tight, acc ≤ tol and the solver reached its own tolerance
(status Solved), else undecided; a solve that gave no usable X is tight when the certificate proves the
local solution optimal, since x̂x̂ᵀ is then a rank-d optimum of the SDP), "cost" (the
bracket; with a certificate given, both the bracket and the certificate, and a certificate alone
decides a bracket left undecided by the solver's accuracy, never an inconsistent solve), "certified"
(the certificate of ``autotight.certificate`` alone).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .errors import ParameterError
from .sdp.result import SDPResult, Status

ACCEPT = ("rank", "cost", "certified")
#: a cost below this × its scale is zero to rounding (the zero-cost instances cost_atol decides)
ROUNDOFF = 100 * float(np.finfo(float).eps)


class Outcome(StrEnum):
    """A verdict's outcome (equal to its text, which records and CSV files hold)."""

    TIGHT = "tight"
    NOT_TIGHT = "not tight"
    UNDECIDED = "undecided"


TIGHT, NOT_TIGHT, UNDECIDED = Outcome.TIGHT, Outcome.NOT_TIGHT, Outcome.UNDECIDED


@dataclass(frozen=True)
class Criteria:
    """Tightness thresholds.

    min_log_svr: rank tight when log SVR exceeds it.  gap_tol: the relative cost gap U − D allowed,
    relative to |U|.  cost_atol: the absolute gap allowed, relative to the cost's scale ‖Q‖_max·tr(X)
    (decides zero- and near-zero-cost instances).  cost_floor: the denominator floor of the reported
    ``rel_gap``.  accept: "rank" | "cost" | "certified" (module docstring).
    """

    min_log_svr: float = 5.0
    gap_tol: float = 1e-5
    cost_atol: float = 1e-9
    cost_floor: float = 1e-9
    accept: str = "rank"

    def __post_init__(self) -> None:
        if self.accept not in ACCEPT:
            raise CriteriaError(f"accept must be one of {', '.join(ACCEPT)}, got {self.accept!r}")
        for k in ("min_log_svr", "gap_tol", "cost_atol", "cost_floor"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or \
                    (k != "min_log_svr" and v < 0):
                raise CriteriaError(f"{k} must be a finite number{' ≥ 0' if k != 'min_log_svr' else ''}, got {v!r}")


class CriteriaError(ParameterError, ValueError):
    """Bad ``Criteria`` (an ``AutotightError``; a ValueError too, as it was before)."""


def relative_gap(sdp_cost: float, local_cost: float, floor: float = 1e-9) -> float:
    """(f_local − f_SDP) / max(|f_local|, floor)."""
    return float((local_cost - sdp_cost) / max(abs(local_cost), floor))


@dataclass
class Verdict:
    """outcome: "tight" | "not tight" | "undecided" under ``accept``; tight = (outcome == "tight").
    rank_tight, cost_tight: the two tests separately (cost_tight: the bracket says tight);
    cost_outcome: the bracket's own outcome.  lower, primal, upper: L, P, U; accuracy: acc;
    tolerance: the gap tested (module docstring).  certified: the certificate's verdict (None: none given).
    accept: the rule that decided ``outcome`` (``Criteria.accept``).  frame: "plain", or "scaled" when
    the dual correction of L was taken in the solve's scaled frame (module docstring).
    """

    tight: bool
    rank_tight: bool
    cost_tight: bool
    log_svr: float
    rel_gap: float
    reason: str
    undecided: bool = False
    outcome: str = NOT_TIGHT
    cost_outcome: str = NOT_TIGHT
    lower: float = float("nan")
    primal: float = float("nan")
    upper: float = float("nan")
    accuracy: float = float("nan")
    tolerance: float = float("nan")
    certified: bool | None = None
    accept: str = "rank"
    frame: str = "plain"

    def record(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class Accuracy:
    """What one solve's residuals say (module docstring): acc, the dual correction of L, the cost's
    scale s, and the parts of acc."""

    acc: float
    dual_correction: float
    scale: float
    gap_pd: float
    primal_term: float
    from_residuals: bool = True
    frame: str = "plain"


def accuracy(res: SDPResult, Q=None, constraints: Sequence | None = None,
             lambda_lower: float | None = None) -> Accuracy:
    """The accuracy of ``res`` from its residuals (with the data) or from |P − D| alone.
    ``lambda_lower``: a certified lower bound on λ_min(Q − Σ yᵢAᵢ) for this solve's y when already
    known (a ``Certificate`` from the same y has it), else computed here."""
    if Q is None or constraints is None or res.X is None or res.y is None:
        P, D = res.primal_cost, res.dual_cost
        gap_pd = abs(P - D)
        scale = max(res.cost_scale, abs(P), abs(D))
        return Accuracy(gap_pd + 10 * np.finfo(float).eps * scale, 0.0, scale, gap_pd, 0.0, False)
    from .certificate import stack

    As, b = stack(constraints)
    return accuracy_of(res, Q, As, b, lambda_lower)


def accuracy_of(res: SDPResult, Q, As: Sequence, b: np.ndarray, lambda_lower: float | None = None) -> Accuracy:
    """``accuracy`` from the residuals, with the data as matrices: Q, the Aᵢ (COO) and b, in the frame of
    ``res`` (which must hold X and y)."""
    from .certificate import dual_matrix, lambda_min
    from .model import constraint_values

    X, y = res.X, res.y
    if X is None or y is None:
        raise ValueError("accuracy_of needs a result with X and y")
    P, D = res.primal_cost, res.dual_cost
    gap_pd = abs(P - D)
    r = constraint_values(As, X) - b  # COO: no per-constraint N×N work
    primal_term = float(np.abs(y) @ np.abs(r))
    trX = float(X.trace())  # dense or sparse (X on the cliques' pattern)
    lam_lo = lambda_min(dual_matrix(Q, As, y))[1] if lambda_lower is None else lambda_lower
    dual_corr = max(-lam_lo, 0.0) * trX
    scale = (float(abs(Q).max()) if Q.nnz else 0.0) * trX
    return Accuracy(max(gap_pd, primal_term, dual_corr), dual_corr, scale, gap_pd, primal_term)


def scaled_frame(acc: Accuracy, res: SDPResult, Q, constraints: Sequence, D: np.ndarray) -> Accuracy:
    """``acc`` with the dual correction of the frame X = D X' D when it is smaller (module docstring):
    max(−λ_min(DHD), 0)·tr(D⁻¹XD⁻¹), D (N,) positive."""
    from .certificate import dual_matrix, lambda_min, stack
    from .sdp import congruence

    if res.X is None or res.y is None:  # no solution: nothing to re-bound
        return acc
    D = np.asarray(D, float)
    As, _ = stack(constraints)
    lam_lo = lambda_min(congruence(sp.coo_array(dual_matrix(Q, As, res.y)), D))[1]
    corr = max(-lam_lo, 0.0) * float(np.sum(np.asarray(res.X.diagonal()).ravel() / D ** 2))
    if not corr < acc.dual_correction:
        return acc
    return replace(acc, acc=max(acc.gap_pd, acc.primal_term, corr), dual_correction=corr, frame="scaled")


def ill_conditioned(upper: float, tol: float, acc: Accuracy) -> bool:
    """Whether the gap tested is at least the (nonzero) cost it tests: tol ≥ |U| > ``ROUNDOFF``·s."""
    return bool(tol >= abs(upper) > ROUNDOFF * acc.scale)


def ill_conditioned_reason(upper: float, tol: float, acc: Accuracy) -> str:
    return (f"ill-conditioned cost: the tolerance {tol:.2e} exceeds the cost U = {upper:.3e} it tests (cost scale "
            f"‖Q‖·tr X = {acc.scale:.2e})")


def bracket(res: SDPResult, upper: float, criteria: Criteria, acc: Accuracy,
            partial: bool = False) -> tuple[str, float, float, str]:
    """(cost outcome, L, tol, reason) of the bracket test (module docstring).  partial: a result that is not
    usable but holds its best iterate (``SDPResult.has_iterate``: a solve that stopped early) is tested too, and
    only "not tight" can come of it: U − P beyond the tolerance plus the accuracy that iterate's own residuals give
    (|P − D|, the constraints' residuals weighted by y, the dual correction) is the same evidence as from a finished
    solve, while "tight" needs a solve that reached its tolerance."""
    if res.status.endswith("DualInfeasible"):
        return NOT_TIGHT, -np.inf, np.nan, f"the relaxation is unbounded (solver status {res.status})"
    unfinished = not res.usable
    if (unfinished and not (partial and res.has_iterate)) or not np.isfinite(res.dual_cost) \
            or not np.isfinite(res.primal_cost):
        return UNDECIDED, np.nan, np.nan, f"solver status {res.status}: no usable bracket"
    if unfinished:
        out, L, tol, why = bracket(replace(res, status=Status.SOLVED), upper, criteria, acc)
        if out == NOT_TIGHT:
            return out, L, tol, f"{why} (the best iterate of a solve that ended {res.status})"
        return UNDECIDED, np.nan, np.nan, f"solver status {res.status}: no usable bracket"
    U, P, D = float(upper), res.primal_cost, res.dual_cost
    L = D - acc.dual_correction
    tol = criteria.gap_tol * abs(U) + criteria.cost_atol * acc.scale
    if L - U > tol + acc.acc:  # a lower bound above a feasible point's cost: the solve is wrong, flag it
        return UNDECIDED, L, tol, (f"inconsistent solve: its lower bound exceeds a feasible cost by {L - U:.3e} "
                                   f"(> tolerance {tol:.2e} + accuracy {acc.acc:.2e})")
    if (acc.from_residuals and U - L <= tol) or (acc.acc <= tol and U - D <= tol + acc.acc):
        return TIGHT, L, tol, ""
    if U - P > tol + acc.acc:
        if ill_conditioned(U, tol, acc):  # P < U − tol ≤ 0: below a cost the tolerance cannot resolve
            return UNDECIDED, L, tol, ill_conditioned_reason(U, tol, acc)
        return NOT_TIGHT, L, tol, f"U − P = {U - P:.3e} exceeds the tolerance {tol:.2e} + accuracy {acc.acc:.2e}"
    if acc.acc > tol:  # the solve cannot resolve the tolerance, whatever U − D is
        return UNDECIDED, L, tol, (f"bracket too wide: solver accuracy {acc.acc:.2e} > tolerance {tol:.2e} "
                                   f"(U − D = {U - D:.3e})")
    return UNDECIDED, L, tol, (f"bracket too wide: U − D = {U - D:.3e} > tolerance {tol:.2e} + solver accuracy "
                               f"{acc.acc:.2e}")


def judge(res: SDPResult, upper: float, criteria: Criteria = Criteria(), certificate=None, *,
          Q=None, constraints: Sequence | None = None, scale: np.ndarray | None = None) -> Verdict:
    """Tightness of one SDP solution against the best feasible cost ``upper`` (module docstring).

    certificate: an ``autotight.certificate.Certificate`` for the local solution from this solve's y
    (optional; needed for accept="certified"; its λ_min bound is reused for the accuracy).  Q, constraints: the SDP's
    data, for the residual-based accuracy.  scale: the solve's diagonal scaling D (N,), if any; an
    undecided bracket is then tried once more with the dual correction of the scaled frame.  A result that is not
    usable but that the SDP layer settled (``SDPResult.settled``: its best iterate's bracket says not tight) is
    bracketed as ``bracket``'s ``partial``.
    """
    acc = accuracy(res, Q, constraints, None if certificate is None else certificate.lambda_lower)
    cost_outcome, L, tol, why = bracket(res, upper, criteria, acc, res.settled)
    if (cost_outcome == UNDECIDED and scale is not None and constraints is not None and acc.from_residuals
            and acc.dual_correction > 0):
        acc = scaled_frame(acc, res, Q, constraints, scale)
        if acc.frame == "scaled":
            cost_outcome, L, tol, why = bracket(res, upper, criteria, acc, res.settled)
    lsvr = res.log_svr
    rank_tight = bool(lsvr == np.inf or (np.isfinite(lsvr) and lsvr > criteria.min_log_svr))
    cert = None if certificate is None else bool(certificate.certified)
    reasons = [why] if why else []
    weak = bool(res.usable and np.isfinite(tol) and ill_conditioned(upper, tol, acc)) and not why
    outcome: str
    if criteria.accept == "rank":
        if cost_outcome == TIGHT and rank_tight:
            outcome = TIGHT
        elif cert and not res.usable and not res.status.endswith("DualInfeasible"):
            # no X to rank, but the certificate proves x̂x̂ᵀ (rank d) optimal for the SDP to its bound
            outcome = TIGHT
            reasons.append(f"certified: x̂x̂ᵀ is optimal for the SDP up to the certificate's bound; the rank of the "
                           f"solver's X is not measured (status {res.status})")
        elif cost_outcome == NOT_TIGHT or (not rank_tight and cost_outcome == TIGHT and acc.acc <= tol and res.solved):
            outcome = NOT_TIGHT
        else:
            outcome = UNDECIDED  # the rank of an X solved less accurately than the gap tested, or not to the
            # solver's own tolerance, says little
        if not rank_tight:
            reasons.append(f"log SVR {lsvr:.2f} ≤ {criteria.min_log_svr}")
        if weak and outcome != TIGHT:  # a tolerance above the cost tested decides no "not tight" either
            outcome = UNDECIDED
            reasons.append(ill_conditioned_reason(upper, tol, acc))
    elif criteria.accept == "cost":
        outcome = cost_outcome
        if outcome == TIGHT and weak:  # a bracket closed only by a tolerance above the cost proves nothing
            outcome = UNDECIDED
            reasons.append(ill_conditioned_reason(upper, tol, acc))
        if cert is not None:
            if cert and cost_outcome != NOT_TIGHT and not why.startswith("inconsistent"):
                outcome = TIGHT
            elif not cert and cost_outcome == TIGHT:
                outcome = UNDECIDED
                reasons.append("the bracket is tight but the certificate is not")
    else:
        outcome = UNDECIDED if cert is None else (TIGHT if cert else NOT_TIGHT)
        if cert is None:
            reasons.append("accept='certified' needs a certificate")
    if cert is False:
        reasons.append("not certified" + (f": {certificate.message}" if certificate.message else ""))
    if res.status != Status.SOLVED and res.usable:
        reasons.append(f"status {res.status}")
    return Verdict(outcome == TIGHT, rank_tight, cost_outcome == TIGHT, lsvr,
                   relative_gap(res.primal_cost, upper, criteria.cost_floor)
                   if res.usable or res.settled else float("nan"),
                   "; ".join(reasons) or "tight", undecided=outcome == UNDECIDED, outcome=outcome,
                   cost_outcome=cost_outcome, lower=float(L), primal=float(res.primal_cost), upper=float(upper),
                   accuracy=float(acc.acc), tolerance=float(tol), certified=cert, accept=criteria.accept,
                   frame=acc.frame)
