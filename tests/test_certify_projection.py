"""certify without a Newton matrix (Douglas–Rachford on the clique form) and its size check."""

import numpy as np
import pytest

from autotight import limits
from autotight.certifier import certify_model
from autotight.constraint_set import named as constraint_set
from autotight.problem import load
from autotight.sdp import solve_model
from autotight.tightness import Criteria, judge


def _chain(K, seed=0):
    p = load("discrete_trajectory")
    inst = p.generate(p.parse_params({"K": K}), seed)
    model = p.build(inst)
    return p, inst, model, constraint_set(model, "paper")


def test_projection_path_agrees_with_the_full_sdp():
    """A chain of 12 poses: Douglas–Rachford's y certifies x̂ exactly where the full SDP says tight, and its
    bound is a valid lower bound on the SDP's optimum."""
    p, inst, model, cons = _chain(12)
    loc = p.local_solve(inst, inst.truth)
    cert = certify_model(model, cons, p.lift(inst, loc.state), method="projection")
    assert "Douglas–Rachford" in cert.method and "full SDP" not in cert.method
    res = solve_model(model, cons)
    verdict = judge(res, loc.cost, Criteria(), Q=model.Q, constraints=cons)
    assert cert.certified == (verdict.outcome == "tight")
    assert cert.certified and cert.rel_bound <= 1e-6
    # f(x̂) − bound ≤ p* (the SDP's primal cost, up to its own accuracy)
    assert cert.cost - cert.bound <= res.primal_cost + 1e-6 * abs(res.primal_cost)


def test_projection_path_does_not_certify_a_non_optimal_point():
    """The ground truth is feasible but not optimal (σ = 0.1): no y certifies it, and the bound stated is at
    least its true gap to the local optimum."""
    p, inst, model, cons = _chain(30)
    loc = p.local_solve(inst, inst.truth)
    truth_cost = p.cost(inst, inst.truth)
    assert truth_cost > loc.cost * (1 + 1e-3)
    cert = certify_model(model, cons, p.lift(inst, inst.truth), method="projection")
    assert not cert.certified
    assert cert.bound >= (truth_cost - loc.cost) * (1 - 1e-6)


def test_certify_size_check_counts_sparse_data(monkeypatch):
    """With 8 GB available, discrete K = 1000 is refused for a solve that may hold X dense (N ≈ 24 000: about
    58 GB), but not for certify, whose sparse data fit."""
    monkeypatch.setattr(limits, "available_memory", lambda: 8e9)
    p = load("discrete_trajectory")
    params = p.parse_params({"K": 1000})
    with pytest.raises(limits.SizeError):
        limits.check_size(p, params)
    est = limits.check_certify_size(p, params)
    assert est is not None and est.N > 20_000
    assert est.nonzeros * limits.CERTIFY_BYTES_PER_NONZERO < 8e9
    with pytest.raises(limits.SizeError, match="certify would need"):
        limits.check_certify_size(p, p.parse_params({"K": 10**6}))


def test_certify_rejects_unknown_method():
    p, inst, model, cons = _chain(3)
    with pytest.raises(ValueError, match="method"):
        certify_model(model, cons, np.asarray(p.lift(inst, inst.truth)), method="newton")
