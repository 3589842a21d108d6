"""The bracket test: tight, not tight and undecided, from D, P, U and the solve's accuracy."""

from dataclasses import replace

import numpy as np
import pytest

from autotight.certificate import Certificate
from autotight.problem import load
from autotight.constraint_set import named as constraint_set
from autotight.pipeline import local_search
from autotight.sdp import solve_model
from autotight.sdp.config import SolverConfig, SolverOptions
from autotight.sdp.result import SDPResult
from autotight.tightness import Criteria, Verdict, judge


def _res(P: float, D: float, log_svr: float = 10.0, status: str = "Solved") -> SDPResult:
    return SDPResult(status=status, solver="test", d=1, X=np.eye(2), y=np.zeros(1), primal_cost=P, dual_cost=D,
                     solve_time_s=0.0, log_svr=log_svr, cost_scale=1.0)


def test_cost_slack_rule():
    """Numbers on both sides of the tolerance: a slack 10× too large or too small fails one of them."""
    c = Criteria(gap_tol=1e-5)
    U = 1.0
    assert judge(_res(1 - 0.8e-5 + 1e-13, 1 - 0.8e-5), U, c).outcome == "tight"  # U − D = 0.8·tol
    v = judge(_res(1 - 2e-5 + 1e-13, 1 - 2e-5), U, c)  # U − P = 2·tol, accuracy 1e-13
    assert v.outcome == "not tight" and not v.undecided and not v.tight
    # the same gap with a solve only accurate to 5e-5 (|P − D|): undecided, never "not tight"
    v = judge(_res(1 + 1e-5, 1 - 4e-5), U, c)
    assert v.outcome == "undecided" and v.undecided and not v.tight
    assert v.accuracy == pytest.approx(5e-5, rel=1e-6) and v.tolerance == pytest.approx(1e-5, rel=1e-3)
    # the reason names what is too wide: here the accuracy (U − D = 4e-5 is within tolerance + accuracy)
    assert "solver accuracy 5.00e-05 > tolerance 1.00e-05 (U − D = 4.000e-05)" in v.reason
    # a gap far outside the accuracy is decided
    assert judge(_res(0.5, 0.5 - 1e-6), U, c).outcome == "not tight"
    # a lower bound above a feasible point's cost beyond the accuracy is flagged, never "tight"
    v = judge(_res(1.2 + 1e-13, 1.2), U, c)
    assert v.outcome == "undecided" and "inconsistent solve" in v.reason
    # low rank alone: not tight for accept="rank", tight for accept="cost"
    low = _res(1 - 1e-8, 1 - 1e-8 - 1e-13, log_svr=1.0)
    assert judge(low, U, c).outcome == "not tight"
    assert judge(low, U, replace(c, accept="cost")).outcome == "tight"
    # an unusable solve is undecided, an unbounded relaxation is not tight
    failed = SDPResult(status="NumericalError", solver="test", d=1, X=None, y=None, primal_cost=np.nan,
                       dual_cost=np.nan, solve_time_s=0.0)
    assert judge(failed, U, c).outcome == "undecided"
    assert judge(replace(failed, status="DualInfeasible"), U, c).outcome == "not tight"


def test_accept_certified_uses_the_certificate():
    cert = Certificate(True, 1e-12, 1e-12, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 5.0, 0.0, "test")
    wide = _res(1 + 1e-5, 1 - 4e-5)  # undecided bracket
    assert judge(wide, 1.0, Criteria(accept="certified"), cert).outcome == "tight"
    assert judge(wide, 1.0, Criteria(accept="cost"), cert).outcome == "tight"
    assert judge(wide, 1.0, Criteria(accept="certified")).outcome == "undecided"
    no = replace(cert, certified=False)
    assert judge(_res(1.0, 1.0), 1.0, Criteria(accept="certified"), no).outcome == "not tight"
    with pytest.raises(ValueError):
        Criteria(accept="sometimes")


def test_an_unusable_solve_is_tight_by_a_certificate_and_undecided_without():
    """accept="rank": a solve that gave no X (status InsufficientProgress) is undecided alone, tight with a
    certificate of the local solution (x̂x̂ᵀ is then a rank-1 optimum) and still undecided with a failed one;
    an unbounded relaxation stays not tight whatever certificate comes with it."""
    cert = Certificate(True, 1e-12, 1e-12, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 5.0, 0.0, "test")
    stalled = SDPResult(status="InsufficientProgress", solver="test", d=1, X=None, y=np.zeros(1), primal_cost=np.nan,
                        dual_cost=np.nan, solve_time_s=0.0)
    assert judge(stalled, 1.0, Criteria()).outcome == "undecided"
    v = judge(stalled, 1.0, Criteria(), cert)
    assert v.outcome == "tight" and v.tight and v.certified and "rank of the solver's X is not measured" in v.reason
    assert judge(stalled, 1.0, Criteria(), replace(cert, certified=False)).outcome == "undecided"
    assert judge(replace(stalled, status="DualInfeasible"), 1.0, Criteria(), cert).outcome == "not tight"


def _judged(name, params, seed, set_name="paper", options=None):
    p = load(name)
    inst = p.generate(params, seed=seed)
    model = p.build(inst)
    cons = constraint_set(model, set_name)
    res = solve_model(model, cons, options)
    loc = local_search(p, inst, np.random.default_rng(seed + 1))
    return judge(res, loc.best.cost, Criteria(), Q=model.Q, constraints=cons), res


def test_loose_solver_tolerance_is_undecided():
    """Clarabel at tol 1e-3 on pose averaging, σ = 0.001: the bracket is far wider than the gap tested."""
    for seed in range(3):
        v, res = _judged("pose_averaging", {"M": 10, "sigma": 0.001}, seed, options=SolverOptions(tol=1e-3))
        assert v.outcome == "undecided", (seed, v)
        assert v.accuracy > 100 * v.tolerance


def test_tight_at_low_noise_with_default_tolerance():
    for seed in range(3):
        v, res = _judged("pose_averaging", {"M": 10, "sigma": 0.001}, seed)
        assert v.outcome == "tight", (seed, v)
        assert v.lower <= v.upper + v.tolerance and v.accuracy < v.tolerance


def test_zero_cost_is_tight():
    """σ = 0, M = 1 (the optimum costs exactly 0): decided by the absolute tolerance."""
    v, res = _judged("pose_averaging", {"M": 1, "sigma": 0.0}, 0)
    assert v.upper == 0.0 and v.outcome == "tight" and v.tight and np.isfinite(v.rel_gap)


def test_primary_set_not_tight():
    v, res = _judged("pose_averaging", {"M": 10}, 0, set_name="primary")
    assert v.outcome == "not tight" and not v.rank_tight and not v.cost_tight


def test_scaled_frame_decides_a_bracket_that_the_plain_frame_cannot():
    """λ_min(H) = −1e-9 on the h column, X with a block of size 1e6: the plain correction
    1e-9·tr(X) = 1e-3 exceeds the tolerance, the scaled frame's 1e-9·tr(D⁻¹XD⁻¹) = 2e-9 does not."""
    import scipy.sparse as sp

    from autotight.model import Constraint

    Q = sp.coo_array(np.diag([1.0, 0.0]))
    cons = [Constraint(sp.coo_array(np.diag([1.0, 0.0])), 1.0)]
    res = replace(_res(1.0, 1.0 + 1e-9), X=np.diag([1.0, 1e6]), y=np.array([1.0 + 1e-9]))
    c = Criteria(gap_tol=1e-5, cost_atol=1e-12)
    plain = judge(res, 1.0, c, Q=Q, constraints=cons)
    assert plain.outcome == "undecided" and plain.frame == "plain"
    assert plain.accuracy == pytest.approx(1e-9 * (1 + 1e6), rel=1e-6)
    scaled = judge(res, 1.0, c, Q=Q, constraints=cons, scale=np.array([1.0, 1e3]))
    assert scaled.outcome == "tight" and scaled.frame == "scaled"
    assert scaled.lower == pytest.approx(1.0 + 1e-9 - 2e-9, abs=1e-15)
    # a scaling that makes the correction larger is not taken
    worse = judge(res, 1.0, c, Q=Q, constraints=cons, scale=np.array([1e3, 1.0]))
    assert worse.frame == "plain" and worse.lower == plain.lower


def test_scaled_frame_bound_is_a_lower_bound_on_a_real_relaxation():
    """On a perturbed y (H indefinite), L = bᵀy − max(−λ_min, 0)·tr in either frame stays below the
    SDP's optimal value p* (solved accurately), and the scaled frame is the one that gets close."""
    from autotight.pipeline import block_scale_at
    from autotight.sdp.config import SolverConfig
    from autotight.tightness import accuracy, scaled_frame

    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": 4, "sigma": 0.1}), np.random.default_rng(3))
    model = prob.build(inst)
    cons = constraint_set(model, "paper")
    loc = local_search(prob, inst, np.random.default_rng(1), 0)
    D = block_scale_at(prob, inst, model, loc.best.state, SolverConfig())
    res = solve_model(model, cons, SolverConfig(), D)
    assert res.status == "Solved"
    p_star = res.primal_cost
    rng = np.random.default_rng(7)
    b = np.array([c.b for c in cons])
    for _ in range(3):
        y = res.y + 1e-2 * np.abs(res.y).max() * rng.standard_normal(res.y.size)
        pert = replace(res, y=y, dual_cost=float(b @ y))
        acc = accuracy(pert, model.Q, cons)
        assert acc.dual_correction > 0  # H is indefinite
        both = [acc, scaled_frame(replace(acc, dual_correction=np.inf), pert, model.Q, cons, D)]
        for a in both:
            assert pert.dual_cost - a.dual_correction <= p_star + 1e-9 * abs(p_star)
        assert both[1].frame == "scaled"


def _undecided_relaxation(monkeypatch, status: str):
    """pose averaging (M = 3, primary) solved by Clarabel, its status set to ``status``, every verdict stubbed
    undecided, and every later SDP solve's tolerance recorded: (pipeline, problem, instance, prepared, relaxation,
    tolerances, the stub verdict)."""
    import autotight.pipeline as pl

    prob = load("pose_averaging")
    inst = prob.generate(prob.parse_params({"M": 3}), 0)
    prep = pl.prepare(prob, inst, "primary", config=SolverConfig(backend="clarabel"))
    relax = pl.solve_relaxation(prob, inst, prep)
    relax = replace(relax, res=replace(relax.res, status=status), certified=None)
    calls: list = []
    real_solve = pl.sdp.solve_model
    monkeypatch.setattr(pl.sdp, "solve_model", lambda *a, **k: calls.append(a[2].tol) or real_solve(*a, **k))
    undecided = Verdict(False, False, False, 0.0, 1e-3, "stub", undecided=True, outcome="undecided")
    monkeypatch.setattr(pl, "judge", lambda *a, **k: undecided)
    return pl, prob, inst, prep, relax, calls, undecided


@pytest.mark.parametrize("status, solves", [("Solved", 2), ("AlmostSolved", 1), ("InsufficientProgress", 1)])
def test_an_undecided_verdict_is_solved_again_only_after_a_solve_that_reached_its_tolerance(monkeypatch, status,
                                                                                           solves):
    """The retry at a 100× tighter tolerance: a solve that stopped short of its tolerance would stop at the same
    point again, so only a Solved one is solved again (the verdict is stubbed undecided; the SDPs are real)."""
    pl, prob, inst, prep, relax, calls, _ = _undecided_relaxation(monkeypatch, status)
    jd = pl.judge_relaxation(prob, inst, prep, relax, prep.local.best, Criteria())
    assert len(jd.attempts) == solves
    assert calls == ([prep.config.tol / 100] if solves == 2 else [])


def test_discoverys_training_solves_leave_an_undecided_verdict_standing(monkeypatch):
    """``retry_undecided=False`` (discovery's training solves): the undecided verdict of a Solved solve stands, with
    no solve at a tighter tolerance; the verdict and the multipliers judged are the first solve's (the verdict is
    stubbed undecided, the SDP is real).  Through ``solve_instance`` as well: one attempt, the same verdict."""
    pl, prob, inst, prep, relax, calls, undecided = _undecided_relaxation(monkeypatch, "Solved")
    jd = pl.judge_relaxation(prob, inst, prep, relax, prep.local.best, Criteria(), retry_undecided=False)
    assert len(jd.attempts) == 1 and calls == [] and jd.verdict is undecided
    assert np.array_equal(jd.res.y, pl.dual_certificate(prob, inst, prep.model, prep.constraints, relax.res,
                                                        prep.local.best, Criteria())[0].y)
    monkeypatch.setattr(pl.sdp, "solve_model", solve_model)  # the real solve again; the verdict stays stubbed
    res = pl.solve_instance(prob, inst, "primary", retry_undecided=False)
    assert len(res.attempts) == 1 and res.outcome == "undecided"
