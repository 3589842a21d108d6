"""Polishing the SDP's multipliers onto x̂'s complementarity (autotight.dual_polish)."""

from dataclasses import replace

import numpy as np

from autotight.certificate import certificate, dual_matrix, polish_dual, stack
from autotight.constraint_set import named as constraint_set
from autotight.dual_polish import homogenising_rows, lower_bound, lower_to_cost, polished
from autotight.pipeline import solve_instance
from autotight.problem import load
from autotight.sdp import solve_model


def _setup(params, set_name, seed=0):
    p = load("pose_averaging")
    inst = p.generate(params, seed=seed)
    model = p.build(inst)
    loc = p.local_solve(inst, inst.truth)
    cons = constraint_set(model, set_name)
    return p, inst, model, loc, cons, solve_model(model, cons)


def test_polish_makes_x_complementary_and_the_dual_cost_f_of_x():
    """A tight instance (pose averaging, paper set, σ = 0.001) with y pushed off by 1e-6 relative: the
    polish brings H(y)x̂ back to roundoff, bᵀy to f(x̂), and λ_min back to ≥ the solver's own."""
    p, inst, model, loc, cons, res = _setup({"M": 10, "sigma": 0.001}, "paper")
    x = p.lift(inst, loc.state)
    As, b = stack(cons)
    rng = np.random.default_rng(0)
    y_off = res.y + 1e-6 * np.abs(res.y).max() * rng.standard_normal(res.y.size)
    y_pol = polish_dual(model.Q, As, y_off, x)
    off = np.linalg.norm(dual_matrix(model.Q, As, y_off) @ np.ravel(x))
    pol = np.linalg.norm(dual_matrix(model.Q, As, y_pol) @ np.ravel(x))
    assert pol <= 1e-6 * off
    assert abs(b @ y_pol - loc.cost) <= 1e-8 * abs(loc.cost)
    assert abs(b @ y_off - loc.cost) > 1e-6 * abs(loc.cost)  # the perturbation did move the dual cost
    c_off, c_pol = (certificate(model.Q, cons, y, x) for y in (y_off, y_pol))
    assert c_pol.lambda_min >= c_off.lambda_min
    assert c_pol.certified and not c_off.certified


def test_polished_keeps_the_polish_only_when_it_is_no_worse():
    p, inst, model, loc, cons, res = _setup({"M": 10, "sigma": 0.001}, "paper")
    x = p.lift(inst, loc.state)
    rng = np.random.default_rng(1)
    y_off = res.y + 1e-6 * np.abs(res.y).max() * rng.standard_normal(res.y.size)
    off = replace(res, y=y_off, dual_cost=float(stack(cons)[1] @ y_off))
    kept, cert = polished(model.Q, cons, off, x)
    assert np.isfinite(kept.dual_cost_raw) and kept.dual_cost_raw == off.dual_cost
    assert abs(kept.dual_cost - loc.cost) <= 1e-8 * abs(loc.cost) and cert.dual_value == kept.dual_cost
    assert lower_bound(cert, float(np.trace(res.X))) >= lower_bound(certificate(model.Q, cons, off.y, x),
                                                                    float(np.trace(res.X)))
    assert "polished" in kept.message


def test_polish_is_refused_where_the_relaxation_is_not_tight():
    """Primary constraints only: no y with H(y)x̂ = 0 is near PSD, so the solver's y (and its dual
    cost, a valid lower bound far below f(x̂)) is kept."""
    p, inst, model, loc, cons, res = _setup({"M": 10}, "primary")
    assert res.log_svr < 1
    kept, cert = polished(model.Q, cons, res, p.lift(inst, loc.state))
    assert kept is res and np.isnan(kept.dual_cost_raw)
    assert kept.dual_cost < loc.cost * (1 - 1e-3)
    As, _ = stack(cons)
    forced = certificate(model.Q, cons, polish_dual(model.Q, As, res.y, p.lift(inst, loc.state)),
                         p.lift(inst, loc.state))
    assert forced.lambda_min < -1e-3 * abs(model.Q).max()


def test_pipeline_dual_never_above_the_best_feasible_cost_on_tight_instances():
    """solve_instance at σ = 0.001 and 0.1 (pose averaging, paper set): the reported D is at most U up
    to roundoff (1e-9 relative to max(|U|, tol), as the report's bracket table counts it), and the
    solver's own dual cost is kept beside a polished one."""
    p = load("pose_averaging")
    for sigma in (0.001, 0.1):
        for seed in range(3):
            r = solve_instance(p, p.generate({"M": 5, "sigma": sigma}, seed), "paper")
            assert r.verdict.outcome == "tight", (sigma, seed, r.verdict.reason)
            assert r.sdp.dual_cost - r.upper <= 1e-9 * max(abs(r.upper), r.verdict.tolerance), (sigma, seed)
            if np.isfinite(r.sdp.dual_cost_raw):
                assert r.sdp.dual_cost_raw != r.sdp.dual_cost


def test_lowering_the_h_multiplier_drops_the_dual_cost_and_keeps_h_as_psd():
    """y with bᵀy above f(x̂): lowering the multiplier of h² = 1 by the excess gives bᵀy = f(x̂) and
    H(y) + excess·e_h e_hᵀ, so λ_min does not drop (pose averaging, d = 1; rotation averaging, d = 3)."""
    for name, params, set_name in (("pose_averaging", {"M": 5}, "paper"), ("rotation_averaging", {"M": 5}, "primary")):
        p = load(name)
        inst = p.generate(params, seed=0)
        model = p.build(inst)
        loc = p.local_solve(inst, inst.truth)
        cons = constraint_set(model, set_name)
        assert len(homogenising_rows(cons)) == model.d
        res = solve_model(model, cons)
        x = p.lift(inst, loc.state)
        As, b = stack(cons)
        y_up = res.y.copy()
        y_up[homogenising_rows(cons)] += 1e-3 * abs(loc.cost) / model.d  # a dual cost above f(x̂)
        excess = b @ y_up - loc.cost
        assert excess > 5e-4 * abs(loc.cost)
        y_low = lower_to_cost(cons, y_up, excess)
        assert abs(b @ y_low - loc.cost) <= 1e-12 * max(1.0, abs(loc.cost))
        c_up, c_low = (certificate(model.Q, cons, y, x, d=model.d) for y in (y_up, y_low))
        assert c_low.lambda_min >= c_up.lambda_min - 1e-12
        kept, cert = polished(model.Q, cons, replace(res, y=y_up, dual_cost=float(b @ y_up)),
                              x, d=model.d)
        assert kept.dual_cost <= loc.cost + 1e-12 * max(1.0, abs(loc.cost)) and "y " in kept.message
        assert kept.dual_cost_raw == float(b @ y_up) and cert.dual_value == kept.dual_cost


def test_a_stalled_solve_whose_multipliers_certify_is_not_solved_again(monkeypatch):
    """Rotation averaging (M = 6, primary constraints: tight): the scaled solve is made to end unusable
    (InsufficientProgress, no X) with its real multipliers; their polish certifies the local solution, so
    the plain data is not solved again and the verdict is tight by the certificate.  With multipliers that
    certify nothing (zeros) the plain data is solved, as before."""
    import autotight.pipeline as pipeline

    prob = load("rotation_averaging")
    inst = prob.generate({"M": 6, "sigma": 0.1}, 0)
    real, calls = pipeline.sdp.solve_model, []

    def stalled(y_of):
        def solve(model, cons, config, scale, stop=None, settled=None):
            res = real(model, cons, config, scale, stop=stop, settled=settled)
            calls.append(scale is not None)
            if scale is not None:  # the scaled solve stalls
                return replace(res, status="InsufficientProgress", X=None, y=y_of(res.y))
            return res
        return solve

    monkeypatch.setattr(pipeline.sdp, "solve_model", stalled(lambda y: y))
    out = solve_instance(prob, inst, "primary")
    assert calls == [True] and out.tight and out.certificate.certified and out.certificate.rel_bound <= 1e-5
    assert "not measured" in out.verdict.reason
    calls.clear()
    monkeypatch.setattr(pipeline.sdp, "solve_model", stalled(np.zeros_like))
    out = solve_instance(prob, inst, "primary")
    assert calls == [True, False] and out.sdp.usable and out.tight


def test_large_relaxations_are_certified_by_the_strict_dual_without_estimating_lambda_min(monkeypatch):
    """From ``NEAR_SHIFT_MIN_N`` columns on (lowered here to 0), ``polished`` tries the strict dual first: on a
    tight instance it certifies with no Lanczos estimate of λ_min (seconds per call at discrete K = 10 000),
    and the bound it reports is the one the estimate gives, to the certificate's tolerance."""
    import autotight.certificate as certificate_module

    p, inst, model, loc, cons, res = _setup({"M": 10, "sigma": 0.001}, "paper")
    x = p.lift(inst, loc.state)
    _, estimated = polished(model.Q, cons, res, x)
    calls = []
    real = certificate_module.lambda_min
    monkeypatch.setattr(certificate_module, "lambda_min", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(certificate_module, "NEAR_SHIFT_MIN_N", 0)
    _, cert = polished(model.Q, cons, res, x)
    assert estimated.certified and cert.certified
    assert calls == [] and "not estimated" in cert.method
    assert cert.lambda_lower <= 0.0 and abs(cert.bound - estimated.bound) <= 1e-6 * abs(loc.cost)
