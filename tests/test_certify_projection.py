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


def test_projection_certifies_a_chain_far_from_the_origin():
    """A helix climbing 1 per step over 300 poses: positions up to 150 beside rotations of 1.  On the data as
    given the rounds found no feasible point (137 rounds, then the barrier broke down); on the data scaled by
    x̂'s block magnitudes (``certify_model``'s default) they do, and the polished y certifies x̂ with a
    relative bound ≤ 1e-6."""
    p = load("discrete_trajectory")
    inst = p.generate(p.parse_params({"K": 300, "climb": 1.0}), 0)
    model = p.build(inst)
    loc = p.local_solve(inst, inst.truth)
    Th = p.lift(inst, loc.state)
    assert np.abs(Th).max() > 100
    cert = certify_model(model, constraint_set(model, "paper"), Th, method="projection")
    assert "feasible" in cert.method
    assert cert.certified and cert.rel_bound <= 1e-6
    assert cert.dual_value <= cert.cost + 1e-9 * abs(cert.cost)


def test_congruence_scales_every_block_entry():
    """CliqueProgram.congruence(D): the blocks of the scaled program at the correspondingly scaled w are
    D_k S_k D_k (S_k the blocks of the given program), to roundoff."""
    from autotight.certifier import default_cliques
    from autotight.certificate import stack
    from autotight.sdp.clique_program import clique_program
    from autotight.sdp.schur_ipm import _Blocks, svec_to_vec

    p, inst, model, cons = _chain(4)
    As, b = stack(cons)
    prog = clique_program(model.Q, As, b, default_cliques(model.Q, As, model.d))
    rng = np.random.default_rng(3)
    D = 10.0 ** rng.uniform(-2, 2, model.variables.N)
    scaled = prog.congruence(D)
    w = rng.standard_normal(prog.F.shape[1])
    ratio = scaled.scale / prog.scale  # the scaled program's w for the same y
    blocks = _Blocks(prog.sizes)
    P = svec_to_vec(prog.sizes)
    S = blocks.split(P @ (prog.c - prog.F @ w))
    S2 = blocks.split(P @ (scaled.c - scaled.F @ (ratio * w)))
    for (n, ids, _), Sg, S2g in zip(blocks.groups, S, S2):
        Dk = np.stack([D[prog.cliques[k]] for k in ids])  # (B, n)
        expect = ratio * Dk[:, :, None] * Sg * Dk[:, None, :]
        assert np.abs(S2g - expect).max() <= 1e-12 * np.abs(expect).max()
    assert np.abs(scaled.c).max() == pytest.approx(1.0)


def test_certificate_without_a_lambda_estimate_states_a_valid_bound():
    """estimate_lambda=False (certify's choice): the same verdict and bound as with the Lanczos estimate, and the
    lower bound on λ_min(H) it states instead, −(δ/d)·λ_max(E_h) from the strict dual, is below λ_min(H)."""
    from autotight.certificate import certificate, dual_matrix, polish_dual, stack

    p, inst, model, cons = _chain(12)
    loc = p.local_solve(inst, inst.truth)
    Th = np.atleast_2d(p.lift(inst, loc.state))
    res = solve_model(model, cons)
    As, _ = stack(cons)
    y = polish_dual(model.Q, As, res.y, Th)
    full = certificate(model.Q, cons, y, Th, d=model.d)
    quick = certificate(model.Q, cons, y, Th, d=model.d, estimate_lambda=False)
    assert quick.certified == full.certified and quick.certified
    assert "not estimated" in quick.method and "not estimated" not in full.method
    assert quick.bound == pytest.approx(full.bound, rel=1e-6, abs=1e-9 * abs(full.cost))
    lam = np.linalg.eigvalsh(dual_matrix(model.Q, As, y).toarray())[0]
    assert quick.lambda_lower <= lam + 1e-12 * abs(model.Q).max()


def _carry_set_k50():
    """Discrete trajectory K = 50 (seed 3) with the 5-pair set ``discover discrete_trajectory`` hands back
    (benchmarks/results/discrete_carry_set.json): problem, instance, model, constraints, local solution."""
    from pathlib import Path

    from autotight.constraint_set import ConstraintSet, resolve
    from autotight.pipeline import seeds

    p = load("discrete_trajectory")
    inst = p.generate(p.parse_params({"K": 50}), 3)
    model = p.build(inst)
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "discrete_carry_set.json"
    cons = resolve(ConstraintSet.load(path), p, inst, model, seeds(3).constraints())
    return p, inst, model, cons, p.local_solve(inst, inst.truth)


def test_a_thin_set_is_certified_in_the_unscaled_frame_where_the_full_sdp_says_tight():
    """The 5-pair set ``discover discrete_trajectory`` hands back (benchmarks/results/discrete_carry_set.json)
    leaves few multipliers: at K = 50 Douglas–Rachford in the scaled frame does not reach the cone, the unscaled
    frame with a small μ does, and the certificate agrees with the full SDP's verdict and bound."""
    from autotight.certificate import stack
    from autotight.certifier import model_cliques
    from autotight.dual_projection import project_multipliers
    from autotight.sdp.clique_program import clique_program
    from autotight.sdp.scaling import block_scale

    p, inst, model, cons, loc = _carry_set_k50()
    theta = p.lift(inst, loc.state)
    cert = certify_model(model, cons, theta, method="projection")
    assert cert.certified and cert.rel_bound <= 1e-6 and "unscaled frame" in cert.method
    res = solve_model(model, cons)
    verdict = judge(res, loc.cost, Criteria(), Q=model.Q, constraints=cons)
    assert verdict.outcome == "tight"
    assert cert.cost - cert.bound <= res.primal_cost + 1e-6 * abs(res.primal_cost)
    # the scaled frame alone does not reach the cone with this set (which is why the unscaled one is tried)
    Th = np.asarray(theta, float).reshape(model.d, -1)
    D = block_scale(model.variables, [Th])
    As, b = stack(cons)
    prog = clique_program(model.Q, As, b, [np.asarray(c) for c in model_cliques(model, As)])
    assert project_multipliers(prog.congruence(D), Th / D[None, :]).margin < 0


def test_from_the_fallback_size_on_a_failed_projection_is_the_answer(monkeypatch):
    """From ``FALLBACK_MAX_N`` columns on, a Douglas–Rachford that does not certify is certify's answer: neither the
    barrier nor the full SDP follows (at K = 500 the barrier's 100 Newton steps took 8 min without certifying).
    The point certified here is the truth, not a minimiser at σ = 0.1, so no certificate exists."""
    import autotight.certifier as certifier

    p, inst, model, cons = _chain(60)
    monkeypatch.setattr(certifier, "FALLBACK_MAX_N", model.variables.N)

    def forbidden(*args, **kwargs):
        raise AssertionError("the barrier ran")

    monkeypatch.setattr(certifier, "phase_one", forbidden)
    monkeypatch.setattr("autotight.sdp.solve", forbidden)
    Th = np.asarray(p.lift(inst, inst.truth))
    cert = certify_model(model, cons, Th)
    assert model.variables.N >= certifier.PROJECTION_MIN_N
    assert not cert.certified and cert.bound > 1e-3 * abs(cert.cost)
    assert "Douglas–Rachford" in cert.method and "`autotight solve` decides" in cert.method


def test_both_frames_share_one_trace_bound(monkeypatch):
    """When neither frame's multipliers prove H ⪰ 0 (the strict dual, the bounded shift and the λ_min estimate made
    to fail), the certificate falls back on the trace bound in both: the bound (the same data and x̂) is derived
    once and the second frame reuses it."""
    from types import SimpleNamespace

    import autotight.certificate as certificate_module
    import autotight.certifier as certifier_module
    import autotight.strict_dual as strict_dual_module

    def recording(module, name: str) -> list:
        """Every value ``module.name`` returns, in a list, from here on."""
        seen, fn = [], getattr(module, name)

        def recorded(*a, **k):
            seen.append(fn(*a, **k))
            return seen[-1]

        monkeypatch.setattr(module, name, recorded)
        return seen

    calls, judged = recording(certificate_module, "trace_bound"), recording(certifier_module, "certificate")
    monkeypatch.setattr(strict_dual_module, "strict_dual", lambda *a, **k: SimpleNamespace(ok=False, message="off"))
    monkeypatch.setattr(strict_dual_module, "bounded_shift", lambda *a, **k: SimpleNamespace(ok=False, message="off"))
    monkeypatch.setattr(certificate_module, "lambda_min", lambda H: (-1e-6, -1e-6, "forced"))
    p, inst, model, cons, loc = _carry_set_k50()
    cert = certify_model(model, cons, p.lift(inst, loc.state), method="projection")
    assert len(judged) == 2 and all(c.argument == "trace bound" and not c.certified for c in judged)
    assert not cert.certified and len(calls) == 1 and calls[0] is not None
    assert judged[0].trace == judged[1].trace == calls[0]
