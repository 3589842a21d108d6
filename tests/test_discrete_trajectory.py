"""Discrete-time trajectory (paper §4): constraints on samples, lifted cost, sparse Jacobian, cliques, tightness."""

from __future__ import annotations

import numpy as np
import pytest

from autotight import lie
from autotight.errors import ParameterError
from autotight.model import Variables
from autotight.problem import load
from autotight.sdp import SolverConfig, solve_model
from autotight.sdp.chordal import has_running_intersection
from autotight.testing import assert_sufficient
from autotight.tightness import Criteria, relative_gap
from problems import _pose
from problems import discrete_trajectory as dt

PROB = load("discrete_trajectory")
#: relative size of a constraint's value on an exact sample, |⟨A,X⟩ − b| / (‖A‖_F ‖X‖_F)
CONSTRAINT_RTOL = 1e-10


def _instance(seed: int, **params) -> object:
    return PROB.generate({"K": 20, "sigma": 0.1} | params, seed)


def _relative_violations(constraints, x: np.ndarray) -> np.ndarray:
    """|xᵀAx − b| / (‖A‖_F ‖xxᵀ‖_F) for each constraint."""
    return np.array([abs(x @ (c.A @ x) - c.b) / (np.sqrt(c.A.multiply(c.A).sum()) * (x @ x)) for c in constraints])


def test_structure_and_counts():
    K = 4
    model = PROB.build(_instance(0, K=K))
    assert model.variables.N == 1 + 12 * K + 6 * K + 6 * (K - 1)
    assert {f: len(model.paper[f]) for f in model.paper} == {"R1": 3 * K, "R2": K, "R3": 3 * (K - 1)}
    types = model.factor_types()
    assert [len(types[t]) for t in ("so3", "pose_meas", "odometry")] == [K, K, K - 1]
    assert all(len(f.constraints) == 12 for t in ("pose_meas", "odometry") for f in types[t])
    assert types["pose_meas"][2].blocks == ("h", "T2_c1", "T2_c2", "T2_c3", "T2_r", "rho_2", "phi_2")
    assert types["odometry"][1].blocks == ("h", "T1_c1", "T1_c2", "T1_c3", "T1_r", "T2_c1", "T2_c2", "T2_c3",
                                           "T2_r", "rho_2_1", "phi_2_1")
    assert types["odometry"][1].roles == dt.ODOMETRY_ROLES


def test_every_constraint_vanishes_on_fresh_samples(lifted_violations):
    inst = _instance(1, K=6)
    model = PROB.build(inst)
    cons = [c for c in model.all_constraints() if c.family != "homogenisation"]
    rng = np.random.default_rng(21)
    xs = np.array([PROB.lift(inst, PROB.sample(inst, rng, spread=0.4)).ravel() for _ in range(100)])
    assert lifted_violations(cons, xs).max() < CONSTRAINT_RTOL
    z = np.concatenate([[1.0], rng.standard_normal(model.variables.N - 1)])
    assert lifted_violations(cons, z).min() > 1e-6  # none is vacuous


def test_binary_relation_without_measurement():
    """_pose with T̃ = I (the continuous-time relation T₂ = cay(ξ^∧) T₁): Cayley rows and R3 vanish."""
    V = Variables(_pose.declare_pose("a_") + _pose.declare_pose("b_") + _pose.declare_xi("ba"))
    cons = _pose.binary_cayley(V, "a_", "b_", None, "ba", "rel") + _pose.r3_binary(V, "a_", "b_", None, "ba", "rel")
    rng = np.random.default_rng(5)
    for _ in range(20):
        T1, xi = lie.random_pose(rng, 2.0), 0.5 * rng.standard_normal(6)
        T2 = lie.cay_se3(xi) @ T1
        vals = (_pose.pose_values(T1[:3, :3], T1[:3, 3], "a_") | _pose.pose_values(T2[:3, :3], T2[:3, 3], "b_")
                | _pose.xi_values(lie.cay_inv_se3(T2 @ lie.inv_se3(T1)), "ba"))
        x = V.assemble(vals).ravel()
        assert _relative_violations(cons, x).max() < CONSTRAINT_RTOL


def test_lifted_cost_equals_cost():
    inst = _instance(2, K=5)
    Q = PROB.build(inst).Q
    rng = np.random.default_rng(8)
    for _ in range(20):
        state = PROB.sample(inst, rng, spread=0.5)
        x = PROB.lift(inst, state).ravel()
        f = PROB.cost(inst, state)
        assert f > 0
        assert abs(x @ (Q @ x) - f) <= 1e-12 * f


def test_sparse_jacobian_matches_finite_differences():
    inst = _instance(3, K=4)
    rng = np.random.default_rng(13)
    Ts = dt._poses(PROB.sample(inst, rng, spread=0.3))
    e0, J, _ = dt.linearize(inst, Ts)
    assert J.shape == (6 * 7, 6 * 4) and J.nnz <= 36 * (4 + 2 * 3)
    step = 1e-6
    num = np.column_stack([(dt.linearize(inst, dt.retract(Ts, step * d))[0] -
                            dt.linearize(inst, dt.retract(Ts, -step * d))[0]) / (2 * step) for d in np.eye(24)])
    assert np.abs(e0).max() > 0.1
    assert np.linalg.norm(num - J.toarray()) <= 1e-6 * np.linalg.norm(J.toarray())


def test_local_solver_reaches_a_stationary_point():
    inst = _instance(4, K=8)
    res = PROB.local_solve(inst, inst.truth)
    assert res.converged
    # the truth does not minimise noisy data, so the solver must lower its cost (≤ would hold by
    # construction: Gauss-Newton never increases the cost)
    assert res.cost < 0.99 * PROB.cost(inst, inst.truth)
    e, J, W = dt.linearize(inst, dt._poses(res.state))
    grad = J.T @ (W @ e)
    assert np.linalg.norm(grad) <= 1e-6 * np.linalg.norm(e) * np.linalg.norm(J.toarray(), 2) ** 2


def test_cliques_cover_every_term_and_form_a_clique_tree():
    inst = _instance(5, K=5)
    model = PROB.build(inst)
    cliques = model.clique_indices()
    assert has_running_intersection(cliques)
    covered = np.zeros((model.variables.N, model.variables.N), bool)
    for C in cliques:
        covered[np.ix_(C, C)] = True
    for A in [model.Q] + [c.A for c in model.all_constraints()]:
        r, c = A.nonzero()
        assert covered[r, c].all()


@pytest.mark.parametrize("seed", [1, 6])
def test_clique_solve_equals_dense_solve(seed):
    inst = _instance(seed, K=3)
    model = PROB.build(inst)
    cons = model.primary() + model.paper_constraints()
    dense = solve_model(model, cons, SolverConfig(decompose=False))
    split = solve_model(model, cons, SolverConfig(decompose=True))
    assert dense.status == "Solved" and split.status == "Solved", (dense.summary(), split.summary())
    assert split.solver == "clarabel-cliques"
    assert abs(dense.primal_cost - split.primal_cost) <= 1e-6 * dense.primal_cost
    local = PROB.local_solve(inst, inst.truth)
    assert abs(relative_gap(split.primal_cost, local.cost)) < 1e-6


def test_primary_alone_is_not_tight():
    inst = _instance(7, K=5)
    model = PROB.build(inst)
    res = solve_model(model, model.primary())
    local = PROB.local_solve(inst, inst.truth)
    assert np.isfinite(res.primal_cost), res.summary()
    assert relative_gap(res.primal_cost, local.cost) > 0.05
    assert res.log_svr < 5  # on the clique blocks (decomposed solve): not rank 1


def test_paper_constraints_make_it_tight():
    """Regression over 2 fresh instances (K = 20, σ = 0.1): R1–R3 are tight on each (Solved on a
    decomposed cone, log SVR > 5, gap ≤ 1e-6) and the recovered trajectory is the local optimum."""

    def recovered(out) -> None:
        assert out.sdp.solver in ("clarabel-chordal", "clarabel-cliques")  # never one dense 475×475 cone
        assert out.sdp.status == "Solved", out.sdp.summary()
        est, local = out.estimate, out.local.from_truth
        assert local.converged
        assert np.abs(est["det_raw"] - 1.0).max() < 1e-6
        assert abs(PROB.cost(out.instance, est) - local.cost) <= 1e-6 * local.cost
        err = PROB.errors(out.instance, est)
        assert err["rotation_deg"] < 20 and err["translation"] < 1.0

    rep = assert_sufficient(PROB, "paper", sigmas=[0.1], instances=2, params={"K": 20}, n_random=0,
                            criteria=Criteria(gap_tol=1e-6), on_result=recovered)
    assert min(rep.points[0].log_svr) > 5 and max(np.abs(rep.points[0].rel_gap)) < 1e-6


def test_bad_input_is_refused():
    with pytest.raises(ParameterError, match="K=1"):
        PROB.generate({"K": 1}, 0)
    with pytest.raises(ParameterError, match="turn_rate"):
        PROB.generate({"turn_rate": 3.5}, 0)
    inst = _instance(0, K=3)
    with pytest.raises(ParameterError, match="C \\(K, 3, 3\\)"):
        PROB.cost(inst, {"C": np.eye(3), "r": np.zeros(3)})


def test_vectorised_lift_and_sample_equal_the_per_pose_construction():
    """The lift writes every block by position: it equals assembling the named blocks one pose at a time
    (to the last bit), and a sample equals perturbing each pose in turn with the same draws."""
    inst = _instance(4, K=7)
    state = PROB.sample(inst, np.random.default_rng(5), spread=0.3)
    un, bi = dt.residuals(inst, state)
    K = 7
    vals = {}
    for k in range(K):
        vals |= _pose.pose_values(state["C"][k], state["r"][k], dt.pose_prefix(k))
        vals |= _pose.xi_values(un[k], dt.unary_name(k))
        ref = lie.cay_inv_se3(dt._poses(state)[k] @ lie.inv_se3(inst.measurements["T_meas"][k]))
        assert np.array_equal(un[k], ref)
    for k in range(K - 1):
        vals |= _pose.xi_values(bi[k], dt.binary_name(k))
    ref_x = PROB.build(inst).variables.assemble(vals)
    assert np.array_equal(PROB.lift(inst, state), ref_x)
    rng_a, rng_b = np.random.default_rng(6), np.random.default_rng(6)
    got = dt.sample(inst, rng_a, state, 0.2)
    T0 = dt._poses(state)
    want = np.array([lie.exp_se3(0.2 * rng_b.standard_normal(6)) @ T for T in T0])
    assert np.array_equal(got["C"], want[:, :3, :3]) and np.array_equal(got["r"], want[:, :3, 3])
    short = {"C": state["C"][:-1], "r": state["r"][:-1]}
    with pytest.raises(ParameterError, match="a state of 6 poses for an instance of K = 7"):
        PROB.lift(inst, short)
