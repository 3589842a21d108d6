"""Rotation averaging (paper §3.1) end to end.

Tolerances and what they mean:
- constraint residuals: |⟨A,X⟩ − b| / (‖A‖_F ‖X‖_F) ≤ 1e-10 (rounding gives ~1e-16);
- lifted cost vs original cost: relative 1e-10;
- Jacobians vs central differences (step 1e-6): relative 1e-6 of the Jacobian's norm
  (truncation ~1e-12, rounding ~1e-10);
- SDP vs local solution from the ground truth: relative 1e-6 (the SDP solver tolerance is 1e-9);
- tight: log10(λ₁/λ₂) > 5, as in the paper.
"""

from __future__ import annotations

import numpy as np
import pytest

import problems.rotation_averaging as ra_mod
from autotight import lie, sdp

COST_REL = 1e-6


def _x(ra, inst, state) -> np.ndarray:
    T = np.atleast_2d(ra.lift(inst, state))
    assert T.shape[0] == 1
    return T[0]


# ----------------------------------------------------------------------------- the QCQP


def test_primary_constraints_vanish_on_fresh_samples(ra, relative_violation, lifted_violations):
    rng = np.random.default_rng(2024)
    inst = ra.generate({"M": 10, "sigma": 0.1}, seed=3)
    model = ra.build(inst)
    cons = model.primary()
    assert len(cons) == 1 + 6 + 9 * 10  # h² = 1, orthonormality, Cayley relation per measurement
    N = model.variables.N
    assert N == 10 + 3 * 10
    xs = np.array([_x(ra, inst, ra.sample(inst, rng, spread=0.5)) for _ in range(100)])
    assert xs.shape == (100, N) and np.all(xs[:, 0] == 1.0)
    worst = lifted_violations(cons, xs).max()
    assert worst <= 1e-10, worst
    x = xs[-1]
    # control: the same check sees a lifted point whose φ₁ is off by 1e-4
    x_bad = x.copy()
    x_bad[model.variables.slice("phi_0")] += 1e-4
    X_bad = np.outer(x_bad, x_bad)
    assert max(relative_violation(c.A, c.b, X_bad) for c in cons) > 1e-6


def test_lifted_cost_equals_original_cost(ra):
    """xᵀQx (+ the model's constant) equals Σ φ_mᵀ W_m φ_m at lifted points, incl. anisotropic W_m."""
    rng = np.random.default_rng(7)
    for params in ({"M": 10, "sigma": 0.1}, {"M": 4, "sigma": 0.3, "anisotropy": 20.0}):
        inst = ra.generate(params, seed=11)
        model = ra.build(inst)
        Q = model.Q.toarray()
        for _ in range(30):
            state = ra.sample(inst, rng, spread=1.0)
            x = _x(ra, inst, state)
            f = ra.cost(inst, state)
            # independent evaluation of the original cost, from the residual definition
            f_direct = sum(p @ W @ p for p, W in zip(
                [lie.cay_inv(state["C"] @ Cm.T) for Cm in inst.measurements["C_meas"]], inst.measurements["W"]))
            assert f == pytest.approx(f_direct, rel=1e-12)
            assert x @ Q @ x + model.cost_offset == pytest.approx(f, rel=1e-10)


def test_gauss_newton_jacobian_matches_finite_differences(ra):
    """J of the stacked residuals w.r.t. ψ, C = cay(ψ^∧) C_op, and the cost gradient 2JᵀWe."""
    rng = np.random.default_rng(5)
    inst = ra.generate({"M": 6, "sigma": 0.3, "anisotropy": 3.0}, seed=2)
    h = 1e-6
    for _ in range(5):
        C0 = ra.sample(inst, rng, spread=0.4)["C"]
        e, J, W = ra_mod._linearize(inst, C0)
        assert J.shape == (3 * 6, 3)
        J_fd = np.zeros_like(J)
        g_fd = np.zeros(3)
        for k in range(3):
            d = np.zeros(3)
            d[k] = h
            ep, _, _ = ra_mod._linearize(inst, lie.cay(d) @ C0)
            em, _, _ = ra_mod._linearize(inst, lie.cay(-d) @ C0)
            J_fd[:, k] = (ep - em) / (2 * h)
            g_fd[k] = (ra.cost(inst, {"C": lie.cay(d) @ C0}) - ra.cost(inst, {"C": lie.cay(-d) @ C0})) / (2 * h)
        assert np.linalg.norm(J - J_fd) <= 1e-6 * np.linalg.norm(J)
        g = 2 * J.T @ W @ e
        assert np.linalg.norm(g - g_fd) <= 1e-6 * max(np.linalg.norm(g), 1.0)
        assert e @ W @ e == pytest.approx(ra.cost(inst, {"C": C0}), rel=1e-12)
        # a Gauss-Newton step with this J goes downhill (the sign of paper (73) is easy to get wrong)
        psi = -np.linalg.solve(J.T @ W @ J, J.T @ W @ e)
        assert ra.cost(inst, {"C": lie.cay(psi) @ C0}) < ra.cost(inst, {"C": C0})


# ----------------------------------------------------------------------------- tightness


def _solve(ra, inst):
    model = ra.build(inst)
    res = sdp.solve(model.Q, model.primary(), d=model.d)
    return model, res


@pytest.mark.parametrize("seed", range(10))
def test_tight_at_sigma_0_1(ra, seed):
    inst = ra.generate({"M": 10, "sigma": 0.1}, seed)
    _, res = _solve(ra, inst)
    loc = ra.local_solve(inst, inst.truth)
    assert loc.converged
    assert res.status == "Solved"
    assert res.log_svr > 5, res.log_svr
    assert abs(res.primal_cost - loc.cost) <= COST_REL * loc.cost, (res.primal_cost, loc.cost)
    est = ra.recover(inst, res.Theta)
    assert abs(float(est["det_raw"]) - 1.0) <= 1e-6  # the SDP's own C block is a rotation, not a reflection
    assert np.linalg.det(est["C"]) == pytest.approx(1.0, abs=1e-12)
    # the SDP estimate is the local optimum, and is close to the truth at this noise level
    assert np.linalg.norm(est["C"] - loc.state["C"]) <= 1e-5
    assert ra.errors(inst, est)["rotation_deg"] < 10.0


def _is_local_minimum(ra, inst, C: np.ndarray, cost: float, rng: np.random.Generator) -> bool:
    """No perturbation C ← cay(δ^∧) C with |δ| = 1e-2 (20 random directions) lowers the cost."""
    for _ in range(20):
        d = rng.standard_normal(3)
        d *= 1e-2 / np.linalg.norm(d)
        if ra.cost(inst, {"C": lie.cay(d) @ C}) < cost:
            return False
    return True


def test_large_noise_random_start_trapped_but_sdp_tight(ra):
    """σ = 1: search instances and random starts for a local solve that converges to a worse local
    minimum; the SDP on that instance is tight and its cost is the global one (lower)."""
    rng = np.random.default_rng(31415)
    trapped = []
    for seed in range(6):
        inst = ra.generate({"M": 10, "sigma": 1.0}, seed)
        _, res = _solve(ra, inst)
        for _ in range(4):
            r = ra.local_solve(inst, ra.random_state(inst, rng))
            if r.converged and r.cost > res.primal_cost * (1 + 1e-3) and \
                    _is_local_minimum(ra, inst, r.state["C"], r.cost, rng):
                trapped.append((inst, res, r))
        if trapped:
            break
    assert trapped, "no random start ended in a worse local minimum"
    inst, res, r = trapped[0]
    best = ra.local_solve(inst, inst.truth)
    assert res.status == "Solved"
    assert res.log_svr > 5, res.log_svr
    assert res.primal_cost < r.cost * (1 - 1e-3)
    assert abs(res.primal_cost - best.cost) <= COST_REL * best.cost
    est = ra.recover(inst, res.Theta)
    assert abs(float(est["det_raw"]) - 1.0) <= 1e-6
    assert ra.cost(inst, est) == pytest.approx(best.cost, rel=COST_REL)


@pytest.mark.parametrize("seed", range(3))
def test_anisotropic_weights_tight(ra, seed):
    inst = ra.generate({"M": 10, "sigma": 0.1, "anisotropy": 10.0}, seed)
    ev = np.linalg.eigvalsh(inst.measurements["W"][0])
    assert ev[-1] / ev[0] == pytest.approx(100.0, rel=1e-6)  # W_m really is anisotropic (std ratio 10)
    _, res = _solve(ra, inst)
    loc = ra.local_solve(inst, inst.truth)
    assert res.status == "Solved"
    assert res.log_svr > 5, res.log_svr
    assert abs(res.primal_cost - loc.cost) <= COST_REL * loc.cost
    est = ra.recover(inst, res.Theta)
    assert abs(float(est["det_raw"]) - 1.0) <= 1e-6
    assert np.linalg.norm(est["C"] - loc.state["C"]) <= 1e-5


def test_local_solver_from_nearby_start_reaches_truth_solution(ra):
    rng = np.random.default_rng(8)
    inst = ra.generate({"M": 10, "sigma": 0.1}, seed=4)
    ref = ra.local_solve(inst, inst.truth)
    for _ in range(3):
        r = ra.local_solve(inst, ra.sample(inst, rng, spread=0.3))
        assert r.converged
        assert r.cost == pytest.approx(ref.cost, rel=1e-9)
        assert np.linalg.norm(r.state["C"] - ref.state["C"]) <= 1e-6
