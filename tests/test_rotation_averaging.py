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

from pathlib import Path

import numpy as np
import pytest

import problems.rotation_averaging as ra_mod
from autotight import lie, sdp
from autotight.graph.assemble import Graph
from model_equal import assert_same_layout, assert_same_span

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


def _linearize(inst, C: np.ndarray):
    """The layer's stacked (e, J, W) of the module's factors at C (J dense), J w.r.t. ε for C ← exp(ε^∧) C."""
    e, J, W = Graph(ra_mod.VARIABLES, inst.truth, ra_mod.factors(inst)).linearize([C])
    return e, J.toarray(), W.toarray()


def test_gauss_newton_jacobian_matches_finite_differences(ra):
    """J of the stacked residuals w.r.t. ε, C = exp(ε^∧) C_op (the layer's retraction), and the cost gradient 2JᵀWe."""
    rng = np.random.default_rng(5)
    inst = ra.generate({"M": 6, "sigma": 0.3, "anisotropy": 3.0}, seed=2)
    h = 1e-6
    for _ in range(5):
        C0 = ra.sample(inst, rng, spread=0.4)["C"]
        e, J, W = _linearize(inst, C0)
        assert J.shape == (3 * 6, 3)
        J_fd = np.zeros_like(J)
        g_fd = np.zeros(3)
        for k in range(3):
            d = np.zeros(3)
            d[k] = h
            ep, _, _ = _linearize(inst, lie.exp_so3(d) @ C0)
            em, _, _ = _linearize(inst, lie.exp_so3(-d) @ C0)
            J_fd[:, k] = (ep - em) / (2 * h)
            g_fd[k] = (ra.cost(inst, {"C": lie.exp_so3(d) @ C0}) - ra.cost(inst, {"C": lie.exp_so3(-d) @ C0})) / (2 * h)
        assert np.linalg.norm(J - J_fd) <= 1e-6 * np.linalg.norm(J)
        g = 2 * J.T @ W @ e
        assert np.linalg.norm(g - g_fd) <= 1e-6 * max(np.linalg.norm(g), 1.0)
        assert e @ W @ e == pytest.approx(ra.cost(inst, {"C": C0}), rel=1e-12)
        # a Gauss-Newton step with this J goes downhill (the sign of paper (73) is easy to get wrong)
        psi = -np.linalg.solve(J.T @ W @ J, J.T @ W @ e)
        assert ra.cost(inst, {"C": lie.exp_so3(psi) @ C0}) < ra.cost(inst, {"C": C0})


# ----------------------------------------------------------------------------- against the hand-written module


def _hand_written_model(inst):
    """Cost and primary constraints as the module wrote them by hand before it moved onto the factor-graph layer
    (``autotight.constraints``), with its factors' names, types and roles."""
    from autotight.constraints import (Factor, Model, Variables, measured_columns, orthonormality, rot_blocks,
                                       rotation_cayley, state_columns, weighted_norm)

    Cm, Ws = inst.measurements["C_meas"], inst.measurements["W"]
    V = Variables([(c, 3) for c in rot_blocks()] + [(f"phi_{m}", 3) for m in range(len(Cm))])
    factors = [Factor("rotation", "so3", ("h", *rot_blocks()), constraints=orthonormality(V, factor="rotation"))]
    for m in range(len(Cm)):
        cons = rotation_cayley(V, state_columns(), measured_columns(Cm[m]), f"phi_{m}", f"meas_{m}")
        factors.append(Factor(f"meas_{m}", "rotation_meas", ("h", *rot_blocks(), f"phi_{m}"),
                              cost=weighted_norm(V, f"phi_{m}", Ws[m]), constraints=cons,
                              roles=("h", "c1", "c2", "c3", "phi")))
    return Model(V, factors)


def _hand_written_local_solve(inst, C0: np.ndarray):
    """The hand-written Gauss-Newton (App. A.2): residuals φ_m, Jacobians J_c(φ_m)⁻¹, C ← cay(ψ^∧) C."""
    from scipy.linalg import block_diag

    from autotight.gauss_newton import gauss_newton

    def linearize(C):
        es, Js = zip(*(lie.residual_so3(C, Cm) for Cm in inst.measurements["C_meas"]))
        return np.concatenate(es), np.vstack(Js), block_diag(*inst.measurements["W"])

    return gauss_newton(linearize, lambda C, psi: lie.cay(psi) @ C, C0)


@pytest.mark.parametrize("params, seed", [({"M": 10, "sigma": 0.1}, 0), ({"M": 3, "sigma": 1.0}, 1),
                                          ({"M": 7, "sigma": 0.3, "anisotropy": 20.0}, 2), ({"M": 1, "sigma": 0.0}, 3)])
def test_the_model_is_the_hand_written_one(ra, params, seed):
    """Same lifted vector (block names, sizes, order), same factors (names of the measurement factors, types,
    blocks, roles), the same cost matrix to rounding, and primary constraints spanning the same space factor by
    factor (rank of each set = rank of both stacked)."""
    inst = ra.generate(params, seed)
    new, old = ra.build(inst), _hand_written_model(inst)
    assert_same_layout(new, old)
    for fn, fo in zip(new.factors, old.factors):
        assert_same_span(fn.constraints, fo.constraints)


def test_the_derived_local_solver_reaches_the_hand_written_ones_optima(ra):
    """From the truth and from random starts, the layer's Gauss-Newton (exp retraction, the auxiliary's declared
    Jacobian) ends at the hand-written solver's cost (relative 1e-9) and rotation (1e-3°), at σ up to 1 where
    random starts end in different local minima."""
    rng = np.random.default_rng(12)
    compared = 0
    for sigma in (0.1, 1.0):
        for seed in range(3):
            inst = ra.generate({"M": 10, "sigma": sigma}, seed)
            for start in [inst.truth["C"]] + [ra.random_state(inst, rng)["C"] for _ in range(3)]:
                new, old = ra.local_solve(inst, {"C": start}), _hand_written_local_solve(inst, start)
                assert new.converged == old.converged  # both stop, or both run out of iterations (1 start here)
                if not old.converged:
                    continue
                compared += 1
                assert abs(new.cost - old.cost) <= 1e-9 * old.cost, (sigma, seed, new.cost, old.cost)
                # the stopping rule (relative decrease ≤ 1e-12) fixes C to about √1e-12 rad; distinct minima lie
                # degrees apart
                assert lie.rotation_error_deg(new.state["C"], old.state) <= 1e-3
    assert compared >= 20


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


def test_recomputed_trials_have_the_committed_reports_verdicts(tmp_path):
    """The first trial at every σ of reports/rotation_averaging, recomputed now (same seeds), has its verdict,
    outcome and certificate, and its SDP and local costs to 1e-6 relative (the SDP's accuracy; the committed
    solves agree with these to about 1e-10)."""
    pd = pytest.importorskip("pandas")  # the report extra
    pytest.importorskip("matplotlib")
    from autotight.cli import main

    committed = Path(__file__).resolve().parents[1] / "reports" / "rotation_averaging" / "trials.csv"
    out = tmp_path / "rep"
    assert main(["report", "rotation_averaging", "--trials", "1", "--sets", "primary", "--jobs", "1",
                 "--no-progress", "--out", str(out)]) == 0
    new, old = pd.read_csv(out / "trials.csv"), pd.read_csv(committed)
    both = new.merge(old, on=["sigma_index", "trial", "constraint_set"], suffixes=("", "_committed"))
    assert len(both) == len(new) == 7
    for col in ("seed", "verdict", "outcome", "tight", "certified", "trapped", "n_constraints"):
        assert (both[col] == both[col + "_committed"]).all(), col
    for col in ("sdp_cost", "local_cost_truth", "local_cost_random", "global_cost"):
        assert np.allclose(both[col], both[col + "_committed"], rtol=1e-6, atol=0), col
