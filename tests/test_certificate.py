"""Certificates for local solutions: certified on tight instances, never on non-tight or worse ones."""

import numpy as np
import pytest

from autotight.certificate import certificate, lambda_min, trace_bound, stack
from autotight.certifier import certify_model
from autotight.problem import load
from autotight.constraint_set import named as constraint_set
from autotight.sdp import solve_model
import scipy.sparse as sp


def _local(name, params, seed):
    p = load(name)
    inst = p.generate(params, seed=seed)
    model = p.build(inst)
    return p, inst, model, p.local_solve(inst, inst.truth)


def _certify_tight(name, params, set_name, seeds):
    for seed in seeds:
        p, inst, model, loc = _local(name, params, seed)
        cons = constraint_set(model, set_name)
        cert = certify_model(model, cons, p.lift(inst, loc.state))
        assert cert.certified, (name, seed, cert)
        assert cert.rel_bound <= 1e-6 and cert.lambda_lower > -1e-6
        assert abs(cert.cost - loc.cost) <= 1e-9 * max(1.0, abs(loc.cost))  # the lifted cost is f(x̂)


def test_rotation_averaging_certified():
    _certify_tight("rotation_averaging", {"M": 10}, "primary", range(10))


def test_pose_averaging_certified():
    _certify_tight("pose_averaging", {"M": 10}, "paper", range(10))


def test_discrete_trajectory_certified_small():
    """Seeds 4 and 6 jam the barrier's long steps (a fake optimum at λ < 0): the centred retry certifies."""
    _certify_tight("discrete_trajectory", {"K": 10}, "paper", (0, 4, 6))


@pytest.mark.slow
def test_discrete_trajectory_certified_k20():
    _certify_tight("discrete_trajectory", {"K": 20}, "paper", range(10))


def test_not_tight_set_is_not_certified():
    """(a) Pose averaging with the primary constraints only: the SDP is not tight, nothing is certified."""
    p, inst, model, loc = _local("pose_averaging", {"M": 10}, 0)
    cons = constraint_set(model, "primary")
    res = solve_model(model, cons)
    assert res.log_svr < 1  # the full SDP agrees: not tight
    cert = certify_model(model, cons, p.lift(inst, loc.state))
    assert not cert.certified and not np.isfinite(cert.bound) and cert.lambda_min < -1e-3


def test_worse_local_minimum_is_not_certified():
    """(b) A converged local solve from a random start, far worse than the one from the truth."""
    p, inst, model, best = _local("pose_averaging", {"M": 10, "sigma": 0.3}, 0)
    rng = np.random.default_rng(0)
    worse = [p.local_solve(inst, p.random_state(inst, rng)) for _ in range(3)][2]
    assert worse.converged and worse.cost > 10 * best.cost
    cons = constraint_set(model, "paper")
    cert = certify_model(model, cons, p.lift(inst, worse.state))
    assert not cert.certified
    assert cert.bound >= worse.cost - best.cost - 1e-6  # a valid bound is at least the true gap
    assert certify_model(model, cons, p.lift(inst, best.state)).certified


def test_bound_is_valid_for_the_sdp_dual():
    """The SDP's own y: f(x̂) − bound ≤ p* ≤ P, and the trace bound holds at the SDP's X."""
    p, inst, model, loc = _local("pose_averaging", {"M": 5}, 1)
    cons = constraint_set(model, "paper")
    res = solve_model(model, cons)
    x = p.lift(inst, loc.state)
    cert = certificate(model.Q, cons, res.y, x)
    assert cert.certified
    assert cert.cost - cert.bound <= res.primal_cost + 1e-9
    As, b = stack(cons)
    T = trace_bound(model.Q, As, b, 2 * loc.cost)
    assert T is not None and np.trace(res.X) <= T
    # a y pushed off the certificate (scaled) breaks it, with a negative λ_min
    bad = certificate(model.Q, cons, 1.5 * res.y, x)
    assert not bad.certified and bad.lambda_min < 0


@pytest.fixture(params=["default shift", "near shift"])
def shift(request, monkeypatch):
    """Both of ``lambda_min``'s shifts: the near one is used from NEAR_SHIFT_MIN_N columns on."""
    if request.param == "near shift":
        monkeypatch.setattr("autotight.certificate.NEAR_SHIFT_MIN_N", 0)
    return request.param


def test_lambda_min_sparse_matches_dense(shift):
    rng = np.random.default_rng(3)
    n = 400
    A = sp.random(n, n, density=0.01, random_state=rng)
    H = sp.csc_array(A + A.T + sp.identity(n) * 0.5)
    w = np.linalg.eigvalsh(H.toarray())[0]
    lam, low, method = lambda_min(H)
    assert "Lanczos" in method or "inertia" in method
    assert abs(lam - w) <= 1e-8 * abs(H).max() and low <= w


def test_lambda_min_of_an_indefinite_matrix_is_bracketed_with_capped_lanczos(shift):
    """An indefinite sparse H above DENSE_MAX columns (a relaxation that is not tight): the lower bound
    confirmed by LDLᵀ inertia is below the true λ_min, and the estimate is within 1e-6 of it, with
    the Lanczos iterations capped by LANCZOS_MAXITER."""
    from autotight.certificate import DENSE_MAX, LANCZOS_MAXITER, lambda_min

    rng = np.random.default_rng(3)
    n = 600
    assert n > DENSE_MAX and 10 * n > LANCZOS_MAXITER
    B = sp.random(n, n, density=0.01, random_state=np.random.RandomState(3))
    H = sp.csr_array(B + B.T + sp.diags(rng.uniform(-0.5, 2.0, n)))
    true = float(np.linalg.eigvalsh(H.toarray())[0])
    est, lower, _ = lambda_min(H)
    assert true < 0 and lower <= true and abs(est - true) <= 1e-6 * max(1.0, abs(true))


def test_lambda_min_of_a_chain_with_no_spectral_gap(shift):
    """H like a tight dual on a long chain: PSD with λ₁ = 0 and λ₂ ≈ π²/n² ≪ 1e-3·max|H| (a path
    graph's Laplacian, n = 1500, scaled by 1e3).  Both shifts find λ₁ to 1e-9·max|H|, and the lower bound
    is below it."""
    n = 1500
    L = sp.diags([-np.ones(n - 1), np.r_[1.0, 2.0 * np.ones(n - 2), 1.0], -np.ones(n - 1)], [-1, 0, 1])
    H = sp.csc_array(1e3 * L)
    w = np.linalg.eigvalsh(H.toarray())[:2]
    assert abs(w[0]) < 1e-9 and w[1] < 1e-5 * abs(H).max()
    lam, low, method = lambda_min(H)
    assert "Lanczos" in method
    assert abs(lam - w[0]) <= 1e-9 * abs(H).max() and low <= w[0]


def test_lambda_min_by_components_is_the_dense_lambda_min():
    """``_lambda_min_blocks`` (the trace bound's λ_min of a large item, its components stacked by size) equals the
    dense λ_min of the whole matrix to 1e-12 of its largest entry: block-diagonal matrices with components of
    sizes 1 to 12 (isolated and empty columns included), permuted; and −inf once a component exceeds 400."""
    from autotight.certificate import _lambda_min_blocks

    rng = np.random.default_rng(7)
    for _ in range(30):
        sizes = rng.integers(1, 13, rng.integers(1, 40))
        blocks = [rng.standard_normal((s, s)) for s in sizes]
        M = sp.block_diag([b + b.T if rng.random() < 0.8 else np.zeros((s, s)) for b, s in zip(blocks, sizes)])
        perm = rng.permutation(M.shape[0])
        A = sp.csr_array(sp.csr_array(M)[perm][:, perm])
        want = np.linalg.eigvalsh(A.toarray())[0]
        assert abs(_lambda_min_blocks(A) - want) <= 1e-12 * max(1.0, abs(A).max())
    chain = sp.diags_array([np.ones(400), 2 * np.ones(401), np.ones(400)], offsets=[-1, 0, 1], format="csr")
    assert _lambda_min_blocks(chain) == -np.inf


def test_trace_bound_returns_to_an_item_once_one_of_its_columns_is_bounded():
    """⟨diag(−1, 1), X⟩ = 2 comes first and is indefinite on both its columns; ⟨e₀e₀ᵀ, X⟩ = 1 bounds X₀₀; on
    the next pass the first item, definite on its one free column, bounds X₁₁.  Every feasible X has
    tr X = 1 + 3 = 4, and so is the bound here (to roundoff); an item skipped for good would leave X₁₁ unbounded."""
    Q = sp.coo_array((2, 2))
    As = [sp.coo_array(np.diag([-1.0, 1.0])), sp.coo_array(np.diag([1.0, 0.0]))]
    T = trace_bound(Q, As, np.array([2.0, 1.0]), 1.0)
    assert T is not None and abs(T - 4.0) <= 1e-12
    assert trace_bound(Q, As[:1], np.array([2.0]), 1.0) is None  # X₀₀ = X₁₁ − 2 alone bounds neither
