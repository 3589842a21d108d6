"""A held-out instance proved tight without the full SDP: the certificate of its local solution.

x̂ = the best local solution (lifted: Θ̂, d × N, cost f̂ = ⟨Q, Θ̂ᵀΘ̂⟩).  The relaxation is tight at x̂,
with Θ̂ᵀΘ̂ its only solution, when some multipliers y give H(y) = Q − Σ yᵢAᵢ ⪰ 0 with H Θ̂ᵀ = 0 (cost
tight) and λ_{d+1}(H) > 0 (strict complementarity).  ``certified_tight`` proposes y by the clique barrier
of ``autotight.certifier`` (its phase one) up to ``MAX_N`` columns, above by its Douglas–Rachford splitting
(``certifier.projected_dual``, ``ROUNDS`` rounds at most in the scaled frame only: beyond those the full SDP is
cheaper), and then decides by exact tests only:

1. cost: ``autotight.certificate.certificate`` certifies f̂ − p* ≤ gap_tol·|f̂| (the tolerance and absolute
   floor of the full SDP's bracket, ``Criteria``);
2. rank: an LDLᵀ inertia count (``certificate.negative_pivots``) finds exactly d eigenvalues of H below
   μ = 10^(min_log_svr + ``SPARE``)·g·max(|f̂|, floor)/tr(Θ̂ᵀΘ̂), g the solver's relative gap
   (``sdp.effective_tol``).  Every feasible X within g·|f̂| of the optimum has ⟨H, X⟩ ≤ g·|f̂| (up to the
   certified bound), so its mass off Θ̂ is at most g·|f̂|/λ_{d+1}(H) ≤ tr(Θ̂ᵀΘ̂)·10^−(min_log_svr + SPARE):
   the full SDP, solved to g, is rank d with log SVR above ``Criteria.min_log_svr`` + ``SPARE``.

Only "tight" is ever decided here.  Anything else (not certified, a smaller λ_{d+1}, recession columns,
a Newton matrix too large or too costly to factorise) returns None, and
the caller solves the full SDP, so an instance that fails validation is always one the full SDP judged.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..certificate import certificate, dual_matrix, negative_pivots, polish_dual, stack
from ..certifier import barrier_too_costly, default_cliques, model_cliques, phase_one, projected_dual
from ..sdp.scaling import block_scale
from ..model import Constraint, Model
from ..tightness import Criteria

#: decades of log SVR to spare above ``Criteria.min_log_svr`` in the rank test (module docstring).  The bound
#: is conservative by orders: discrete trajectory K = 20 (seed 500, paper set) has λ₂(H) = 2.6e-5·max|Q|, a
#: bound of log SVR ≥ 4.8 at g = 1e-8, and its full SDP gives log SVR 9.0
SPARE = 0.0
#: columns above which y comes from Douglas–Rachford instead of the barrier, whose steps then cost more than the
#: full SDP they would save (discrete trajectory K = 200, N = 4795: 272 s without a decision against 76 s for the
#: IPM's tight solve; K = 20, N = 475: 4 s against 30 s)
MAX_N = 1000
#: Douglas–Rachford's μ and rounds in the scaled frame, and its rounds in the unscaled one after it
#: (``certifier.projected_dual``): none.  Discrete trajectory K = 200 against the IPM's SDP (3.2 s a solve): the
#: paper's set certifies in 4–7 scaled rounds (1.1–1.5 s for the whole instance); a 5-pair learned set needs 30–45
#: unscaled rounds (2.3–3.1 s), more than the SDP, and with 15 scaled rounds certifies none (margin −1 of max|Q|)
CLIPS = (0.3,)
ROUNDS = 15
THIN_ROUNDS = 0
#: Newton steps of the barrier at most (it stops once the margin μ is reached: 1–7 steps at tight instances)
MAX_ITER = 12


@dataclass(frozen=True)
class Shortcut:
    """A held-out instance proved tight: the certificate's relative bound, μ (λ_{d+1}(H) ≥ μ, relative to
    max|Q_ij|) and the time it took."""

    rel_bound: float
    margin: float
    time_s: float

    def reason(self) -> str:
        return (f"tight by the certificate of the local solution (relative bound {self.rel_bound:.1e}; "
                f"λ_(d+1)(H) ≥ {self.margin:.1e}·max|Q|): no full SDP needed")


def certified_tight(model: Model, constraints: Sequence[Constraint], theta_hat: np.ndarray,
                    criteria: Criteria = Criteria(), gap: float = 1e-8) -> Shortcut | None:
    """``Shortcut`` when the local solution Θ̂ proves the relaxation with ``constraints`` (every constraint of
    the SDP, primary included) tight as the module docstring says, for a solver of relative gap ``gap``;
    None when it does not decide."""
    from ..sdp.clique_program import clique_program

    t0 = time.perf_counter()
    Q = sp.csr_array(model.Q)
    d = model.d
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    As, b = stack(constraints)
    scale = float(abs(Q).max()) if Q.nnz else 0.0
    trace = float(np.sum(Th * Th))
    if scale == 0.0 or trace == 0.0:
        return None
    f_hat = float(np.sum(Th.T * (Q @ Th.T)))
    mu = 10 ** (criteria.min_log_svr + SPARE) * gap * max(abs(f_hat), criteria.cost_atol * scale * trace) / trace
    floor = criteria.cost_atol / criteria.gap_tol
    if model.variables.N > MAX_N:
        try:
            prog = clique_program(Q, As, b, [np.asarray(C) for C in model_cliques(model, As)])
        except ValueError:
            return None
        cert, y = projected_dual(Q, As, constraints, prog, Th, d=d, tol=criteria.gap_tol, floor=floor, trace=None,
                                 scale=block_scale(model.variables, [Th]), rounds=ROUNDS, clips=CLIPS,
                                 thin_rounds=THIN_ROUNDS)
    else:
        try:
            prog = clique_program(Q, As, b, [np.asarray(C) for C in default_cliques(Q, As, d)])
        except ValueError:  # no clique tree of the data's pattern
            return None
        if barrier_too_costly(prog)[2]:
            return None  # the barrier's steps would cost more than the full SDP they are meant to save
        # the barrier's own margin is clique-wise and pessimistic (discrete K = 100: −1e-3 after 12 steps, where
        # the exact tests below pass): whatever it ends with, its y is polished and tested
        ph = phase_one(prog, Th, target=min(max(2 * mu / scale, 1e-6), 0.1), max_iter=MAX_ITER)
        y = polish_dual(Q, As, ph.w[:prog.m] / prog.scale, Th)
        cert = certificate(Q, constraints, y, Th, d=d, tol=criteria.gap_tol, floor=floor)
    if not cert.certified or cert.recession:
        return None
    if negative_pivots(dual_matrix(Q, As, y), mu) != d:  # exactly the d directions of Θ̂ below μ
        return None
    return Shortcut(float(cert.rel_bound), mu / scale, time.perf_counter() - t0)
