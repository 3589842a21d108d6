"""Landmark problems of the lifting appendix: terms, constraints, local solver, Shor tightness.

Tolerances: costs are compared relative to the cost itself (floating-point sums, 1e-10); constraint
values relative to 1 (their constants are O(1)); SDP costs to 2e-7·max|Q_ij|, because Clarabel solves
the problem scaled by 1/max|Q_ij| to 1e-9 and the observed gaps are ≤ 4e-8·max|Q_ij| (the costs at low
noise are tiny differences of O(‖ℓ‖²) terms, so a gap relative to the cost alone is not meaningful).
"""

from __future__ import annotations

import numpy as np
import pytest

from autotight.errors import ParameterError, ProblemDefinitionError
from autotight.problem import load
from autotight.sdp import solve_model
from problems import _landmark_terms as lt

PROBLEMS = ("landmark_localization", "landmark_slam", "pose_graph")
DIMS = (2, 3)
LIFTINGS = ("matrix", "vector")


def fro2(A: np.ndarray) -> float:
    return float(np.sum(np.asarray(A) ** 2))


def lifted_cost(Q, Theta: np.ndarray) -> float:
    """⟨Q, ΘᵀΘ⟩."""
    return float(Q.multiply(Theta.T @ Theta).sum())


# ----------------------------------------------------------------------------- terms


def _term_case(kind: str, d: int, rng: np.random.Generator, orthogonal: bool):
    """A term with random data, its block values, and the cost computed directly."""
    C = lt.random_rotation(rng, d) if orthogonal else rng.standard_normal((d, d))
    C2 = lt.random_rotation(rng, d) if orthogonal else rng.standard_normal((d, d))
    r, r2, ell, y, dr = (rng.standard_normal(d) for _ in range(5))
    dC, Cp = lt.random_rotation(rng, d), lt.random_rotation(rng, d)
    vals = {"C": C, "r": r[:, None], "C2": C2, "r2": r2[:, None], "l": ell[:, None]}
    if kind == "landmark":
        return lt.landmark_term("t", "C", "r", "l", y), vals, fro2((ell - r) - C @ y)
    if kind == "known_landmark":
        return lt.known_landmark_term("t", "C", "r", ell, y), vals, fro2((ell - r) - C @ y)
    if kind == "relative_pose":
        direct = fro2(r2 - r - C @ dr) + fro2(C2 - C @ dC)
        return lt.relative_pose_term("t", "C", "r", "C2", "r2", dC, dr), vals, direct
    return lt.prior_term("t", "C", "r", Cp, dr), vals, fro2(C - Cp) + fro2(r - dr)


@pytest.mark.parametrize("lifting", LIFTINGS)
@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("kind", ["landmark", "known_landmark", "relative_pose", "prior"])
def test_term_cost_equals_direct_cost(kind, d, lifting):
    """⟨Q, ΘᵀΘ⟩ = the expanded cost, on rotations and (the identity is exact) on arbitrary matrices."""
    L = lt.Lifting(lifting, d)
    rng = np.random.default_rng(10 * d + len(kind))
    for s in range(6):
        term, vals, direct = _term_case(kind, d, rng, orthogonal=s % 2 == 0)
        V = L.variables([(b, d if b.startswith("C") else 1) for b in term.blocks])  # the term's local columns
        cols = {b: np.asarray(vals[b], float).reshape(d, -1) for b in term.blocks}
        if lifting == "vector":
            cols = {b: v.ravel(order="F") for b, v in cols.items()}
        Theta = V.assemble(cols)
        assert Theta.shape == ((d, V.N) if lifting == "matrix" else (1, V.N))
        assert lifted_cost(term.cost_matrix(L), Theta) == pytest.approx(direct, rel=1e-10)
        assert fro2(term.evaluate(vals | {"h": np.eye(d)})) == pytest.approx(direct, rel=1e-10)


def test_vector_lifting_layout_is_vec_by_columns():
    P = load("landmark_localization")
    inst = P.generate({"dim": 3, "lifting": "vector"}, seed=0)
    C, r = np.arange(9.0).reshape(3, 3), np.array([9.0, 10.0, 11.0])
    x = P.module.lift(inst, {"C": C[None], "r": r[None]})[0]
    np.testing.assert_array_equal(x, np.r_[1.0, C[:, 0], C[:, 1], C[:, 2], r])
    R = lt.random_rotation(np.random.default_rng(0), 3)
    np.testing.assert_allclose(P.module.recover(inst, 2.0 * P.module.lift(inst, {"C": R[None], "r": r[None]}))["C"][0],
                               R, atol=1e-12)


# ----------------------------------------------------------------------------- problems


def direct_cost(name: str, inst, st: dict) -> float:
    """The problem's cost written out from its measurements (independent of the term code)."""
    m, C, r = inst.measurements, st["C"], st["r"]
    f = fro2(C[0] - m["prior_C"]) + fro2(r[0] - m["prior_r"])
    if name == "landmark_localization":
        f += sum(fro2((m["landmarks"][j] - r[0]) - C[0] @ y) for j, y in zip(m["obs_landmark"], m["y"]))
    if name == "landmark_slam":
        f += sum(fro2((st["l"][j] - r[k]) - C[k] @ y) for k, j, y in zip(m["obs_pose"], m["obs_landmark"], m["y"]))
        f += sum(fro2(r[j] - r[i] - C[i] @ t) + fro2(C[j] - C[i] @ R)
                 for i, j, R, t in zip(m["odo_from"], m["odo_to"], m["odo_C"], m["odo_r"]))
    if name == "pose_graph":
        f += sum(fro2(r[j] - r[i] - C[i] @ t) + fro2(C[j] - C[i] @ R)
                 for i, j, R, t in zip(m["rel_from"], m["rel_to"], m["rel_C"], m["rel_r"]))
    return f


@pytest.mark.parametrize("lifting", LIFTINGS)
@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", PROBLEMS)
def test_model_cost_and_primary_constraints_on_samples(name, d, lifting):
    P = load(name)
    inst = P.generate({"dim": d, "lifting": lifting, "sigma": 0.1}, seed=3)
    model = P.build(inst)
    assert model.d == (d if lifting == "matrix" else 1)
    K = len(inst.truth["C"])
    # one orthonormality factor per pose with d(d+1)/2 constraints; homogenisation d(d+1)/2 (or 1)
    assert len(model.factor_types()["pose"]) == K
    assert len(model.primary()) == (K + (lifting == "matrix")) * d * (d + 1) // 2 + (lifting == "vector")
    rng = np.random.default_rng(7)
    for _ in range(5):
        st = P.sample(inst, rng, spread=0.5)
        Theta = P.lift(inst, st)
        X = Theta.T @ Theta
        direct = direct_cost(name, inst, st)
        assert lifted_cost(model.Q, Theta) + model.cost_offset == pytest.approx(direct, rel=1e-10)
        assert P.cost(inst, st) == pytest.approx(direct, rel=1e-10)
        worst = max(abs(c.value(X)) for c in model.primary())
        assert worst < 1e-12


@pytest.mark.parametrize("lifting", LIFTINGS)
@pytest.mark.parametrize("name", PROBLEMS)
def test_recover_inverts_lift(name, lifting):
    P = load(name)
    inst = P.generate({"dim": 3, "lifting": lifting}, seed=1)
    U = lt.random_rotation(np.random.default_rng(0), 3) if lifting == "matrix" else -np.eye(1)
    est = P.recover(inst, U @ P.lift(inst, inst.truth))  # a rank-d factor is defined up to a left factor
    for k, v in inst.truth.items():
        np.testing.assert_allclose(est[k], v, atol=1e-12)
    np.testing.assert_allclose(est["det_raw"], 1.0, atol=1e-12)
    assert P.errors(inst, est)["rotation_deg"] < 1e-6


def test_factor_types_and_roles_are_consistent():
    P = load("landmark_slam")
    inst = P.generate({"dim": 2, "n_poses": 3, "n_landmarks": 4, "obs_per_pose": 2}, seed=0)
    types = P.build(inst).factor_types()
    assert set(types) == {"pose", "landmark", "relative_pose", "prior"}
    assert {f.roles for f in types["landmark"]} == {("h", "C", "r", "l")}
    assert {f.roles for f in types["relative_pose"]} == {("h", "C_i", "r_i", "C_j", "r_j")}
    assert len(types["relative_pose"]) == 2
    seen = set(inst.measurements["obs_landmark"].tolist())
    assert seen == {0, 1, 2, 3}  # every landmark is observed


# ----------------------------------------------------------------------------- local solver


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", PROBLEMS)
def test_local_solver_jacobian_matches_finite_differences(name, d):
    P = load(name)
    inst = P.generate({"dim": d, "sigma": 0.2}, seed=4)
    g = lt.PoseTerms(P.module.terms(inst), *P.module.counts(inst), d)  # the terms' own cost and Gauss-Newton
    st = P.sample(inst, np.random.default_rng(1), spread=0.3)
    e, J, _ = g.linearize(st)
    h = 1e-6
    cols = []
    for i in range(J.shape[1]):
        step = np.zeros(J.shape[1])
        step[i] = h
        cols.append((g.linearize(g.retract(st, step))[0] - g.linearize(g.retract(st, -step))[0]) / (2 * h))
    num = np.column_stack(cols)
    assert np.max(np.abs(num - J)) <= 1e-6 * max(1.0, np.max(np.abs(J)))
    assert e @ e == pytest.approx(P.cost(inst, st), rel=1e-12)


@pytest.mark.parametrize("name", PROBLEMS)
def test_local_solver_converges_from_near_truth(name):
    P = load(name)
    inst = P.generate({"dim": 3, "sigma": 0.1}, seed=2)
    ref = P.local_solve(inst, inst.truth)
    near = P.local_solve(inst, P.sample(inst, np.random.default_rng(0), spread=0.1))
    assert ref.converged and near.converged
    assert ref.cost < P.cost(inst, inst.truth)
    assert near.cost == pytest.approx(ref.cost, rel=1e-8)
    diff = lt.state_errors(near.state, ref.state)  # the same minimum, not just the same cost
    assert diff["rotation_deg"] < 1e-4 and diff["position"] < 1e-6


# ----------------------------------------------------------------------------- Shor tightness


@pytest.mark.parametrize("lifting", LIFTINGS)
@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", PROBLEMS)
def test_shor_with_primary_constraints_is_tight_at_low_noise(name, d, lifting):
    """Measured: at σ ≤ 0.1 (default sizes) the primary-only relaxation is rank d (log SVR ≈ 7–10)
    and its cost is the local solver's, for every problem, dimension and lifting (no discovery needed)."""
    P = load(name)
    for sigma in (0.01, 0.1):
        for seed in range(3):
            inst = P.generate({"dim": d, "lifting": lifting, "sigma": sigma, "prior_sigma": sigma}, seed)
            model = P.build(inst)
            res = solve_model(model, model.primary())
            loc = P.local_solve(inst, inst.truth)
            assert res.status == "Solved", res.status
            assert res.log_svr > 5.0
            assert abs(res.primal_cost - loc.cost) <= 2e-7 * abs(model.Q).max()
            est = P.recover(inst, res.Theta)
            assert P.cost(inst, est) == pytest.approx(loc.cost, rel=1e-4)
            np.testing.assert_allclose(est["det_raw"], 1.0, atol=1e-4)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("name", PROBLEMS)
def test_dim_must_be_2_or_3(name):
    P = load(name)
    for bad in (1, 4):
        with pytest.raises(ParameterError, match="dim must be 2 or 3"):
            P.generate({"dim": bad})
    inst = P.generate({"dim": 2})
    inst.params["dim"] = 5
    with pytest.raises(ParameterError, match="dim must be 2 or 3"):
        P.build(inst)
    with pytest.raises(ParameterError, match="lifting"):
        P.generate({"lifting": "tensor"})


def test_landmark_index_out_of_range():
    P = load("landmark_slam")
    inst = P.generate({"n_poses": 2, "n_landmarks": 3}, seed=0)
    inst.measurements["obs_landmark"][1] = 3
    with pytest.raises(ProblemDefinitionError, match="landmark 3, but there are only 3 landmarks"):
        P.build(inst)
    P = load("landmark_localization")
    inst = P.generate({"n_landmarks": 4}, seed=0)
    inst.measurements["obs_landmark"][0] = -1
    with pytest.raises(ProblemDefinitionError, match="landmark -1"):
        P.build(inst)


@pytest.mark.parametrize("name,key", [("landmark_slam", "obs_pose"), ("landmark_slam", "odo_to"),
                                      ("pose_graph", "rel_from")])
def test_measurement_on_missing_pose(name, key):
    P = load(name)
    inst = P.generate({"n_poses": 3}, seed=0)
    inst.measurements[key][0] = 7
    with pytest.raises(ProblemDefinitionError, match="on pose 7, but there are only 3 poses"):
        P.build(inst)


def test_measurement_of_wrong_dimension_is_refused():
    P = load("landmark_slam")
    inst = P.generate({"dim": 3}, seed=0)
    inst.measurements["y"] = inst.measurements["y"][:, :2]
    with pytest.raises(ProblemDefinitionError, match="do not fit d = 3"):
        P.build(inst)


def test_state_of_wrong_shape_is_refused():
    P = load("pose_graph")
    inst = P.generate({"n_poses": 4}, seed=0)
    with pytest.raises(ProblemDefinitionError, match="expected"):
        P.cost(inst, {"C": inst.truth["C"][:2], "r": inst.truth["r"][:2]})
