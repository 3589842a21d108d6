"""Pose averaging (paper §3.2): constraints on samples, lifted cost, Jacobians, and tightness of the paper's set."""

from __future__ import annotations

import numpy as np
import pytest

from autotight import lie
from autotight.errors import ParameterError
from autotight.problem import load
from autotight.check import check_sufficient
from autotight.sdp import SolverConfig, solve_model
from autotight.testing import assert_sufficient
from autotight.tightness import Criteria
from problems import pose_averaging as pa

PROB = load("pose_averaging")
#: relative size of a constraint's value on an exact sample, |⟨A,X⟩ − b| / (‖A‖_F ‖X‖_F)
CONSTRAINT_RTOL = 1e-10


def _instance(seed: int, **params) -> object:
    return PROB.generate({"M": 10, "sigma": 0.1} | params, seed)


def test_structure_and_counts():
    inst = _instance(0, M=4)
    model = PROB.build(inst)
    assert model.variables.N == 13 + 6 * 4
    assert [len(model.paper[f]) for f in ("R1", "R2")] == [3 * 4, 4]
    assert all(c.family == f for f in ("R1", "R2") for c in model.paper[f])
    types = model.factor_types()
    assert len(types["so3"]) == 1 and len(types["pose_meas"]) == 4
    for f in types["pose_meas"]:
        assert f.roles == ("h", "c1", "c2", "c3", "r", "rho", "phi")
        assert len(f.constraints) == 12
    assert len(types["so3"][0].constraints) == 6


@pytest.mark.parametrize("seed", [0, 1])
def test_every_constraint_vanishes_on_fresh_samples(seed, lifted_violations):
    inst = _instance(seed)
    model = PROB.build(inst)
    rng = np.random.default_rng(100 + seed)
    xs = np.array([PROB.lift(inst, PROB.sample(inst, rng, spread=0.5)).ravel() for _ in range(100)])
    assert lifted_violations(model.all_constraints(), xs).max() < CONSTRAINT_RTOL
    # the constraints are not vacuous: a generic (infeasible) vector with h = 1 violates each of them
    z = np.concatenate([[1.0], rng.standard_normal(model.variables.N - 1)])
    fams = np.array([c.family for c in model.all_constraints()])
    assert lifted_violations(model.all_constraints(), z)[fams != "homogenisation"].min() > 1e-6


def test_lifted_cost_equals_cost():
    inst = _instance(3)
    model = PROB.build(inst)
    Q = model.Q
    rng = np.random.default_rng(7)
    for _ in range(20):
        state = PROB.sample(inst, rng, spread=0.8)
        x = PROB.lift(inst, state).ravel()
        f = PROB.cost(inst, state)
        assert f > 0
        assert abs(x @ (Q @ x) - f) <= 1e-12 * f


def test_jacobian_matches_finite_differences():
    inst = _instance(4)
    rng = np.random.default_rng(11)
    state = PROB.sample(inst, rng, spread=0.4)
    T = lie.make_pose(state["C"], state["r"])
    e0, J, _ = pa.linearize(inst, T)
    step = 1e-6
    num = np.column_stack([(pa.linearize(inst, pa.retract(T, step * d))[0] -
                            pa.linearize(inst, pa.retract(T, -step * d))[0]) / (2 * step) for d in np.eye(6)])
    assert np.abs(e0).max() > 0.1  # a point away from the optimum, so the test is informative
    assert np.linalg.norm(num - J) <= 1e-6 * np.linalg.norm(J)


def test_local_solver_reaches_a_stationary_point():
    inst = _instance(5)
    res = PROB.local_solve(inst, inst.truth)
    assert res.converged
    # the truth does not minimise noisy data, so the solver must lower its cost (≤ would hold by
    # construction: Gauss-Newton never increases the cost)
    assert res.cost < 0.99 * PROB.cost(inst, inst.truth)
    e, J, W = pa.linearize(inst, lie.make_pose(res.state["C"], res.state["r"]))
    grad = J.T @ W @ e
    assert np.linalg.norm(grad) <= 1e-6 * np.linalg.norm(J.T @ W @ J, 2) * max(np.linalg.norm(e), 1e-12)


def test_primary_not_tight_paper_tight():
    """Regression over 3 fresh instances (M = 10, σ = 0.1): primary alone is loose on each (cost gap
    > 5 %, log SVR < 2); the paper's R1+R2 are tight on each (Solved, log SVR > 5, gap ≤ 1e-6) and
    the recovered pose is the local optimum."""
    prim = check_sufficient(PROB, "primary", [0.1], 3, params={"M": 10}, n_random=0).points[0]
    assert prim.outcomes == ["not tight"] * 3
    assert all(np.isfinite(prim.log_svr)) and max(prim.log_svr) < 2 and min(prim.rel_gap) > 0.05

    def recovered(out) -> None:
        assert out.sdp.status == "Solved", out.sdp.summary()
        est, local = out.estimate, out.local.from_truth
        assert local.converged
        assert abs(float(est["det_raw"]) - 1.0) < 1e-6
        # the recovered pose is the local optimum
        assert abs(PROB.cost(out.instance, est) - local.cost) <= 1e-6 * local.cost
        err = PROB.errors(out.instance, est)
        assert err["rotation_deg"] < 10 and err["translation"] < 0.5

    rep = assert_sufficient(PROB, "paper", sigmas=[0.1], instances=3, params={"M": 10}, n_random=0,
                            criteria=Criteria(gap_tol=1e-6), on_result=recovered)
    assert min(rep.points[0].log_svr) > 5 and max(np.abs(rep.points[0].rel_gap)) < 1e-6


def test_clique_solve_equals_dense_solve():
    inst = _instance(6)
    model = PROB.build(inst)
    cons = model.primary() + model.paper_constraints()
    dense = solve_model(model, cons, SolverConfig(decompose=False))
    split = solve_model(model, cons, SolverConfig(decompose=True))
    assert dense.status == "Solved" and split.status == "Solved", (dense.summary(), split.summary())
    assert split.solver == "clarabel-cliques" and len(split.clique_log_svr) > 1
    assert abs(dense.primal_cost - split.primal_cost) <= 1e-6 * dense.primal_cost
    assert abs(split.dual_cost - split.primal_cost) <= 1e-6 * dense.primal_cost
    assert split.log_svr > 5 and min(split.clique_log_svr) == split.log_svr
    for c in cons:  # the completed X satisfies every constraint, on and off the clique blocks
        assert abs(c.value(split.X)) <= 1e-6 * (1 + abs(c.A).sum()), c.name


def test_bad_parameters_are_refused():
    with pytest.raises(ParameterError, match="M=0"):
        PROB.generate({"M": 0}, 0)
    with pytest.raises(ParameterError, match="sigma"):
        PROB.generate({"sigma": -0.1}, 0)
