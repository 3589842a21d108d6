"""Continuous-time trajectory with a WNOA prior (paper §5): constraints, the Schur complement,
Jacobians, cliques, tightness of the paper's families and where it ends, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import lie
from autotight.errors import ParameterError
from autotight.problem import load
from autotight.sdp import ClarabelOptions, SolverConfig, solve_model
from autotight.sdp.chordal import has_running_intersection
from autotight.tightness import relative_gap
from problems import continuous_trajectory as ct

PROB = load("continuous_trajectory")
#: |xᵀAx − b| / (‖A‖_F ‖xxᵀ‖_F) on an exact sample: rounding only
CONSTRAINT_RTOL = 1e-10
#: two evaluations of the same cost (different formulas), relative to the cost: rounding only
COST_RTOL = 1e-9
#: SDP cost against the local optimum from the ground truth, relative to the cost.  The optimum is
#: ~1 % of the terms that cancel in ⟨Q, X⟩ (constant velocity is nearly free under the WNOA prior),
#: so Clarabel's default accuracy (1e-9) gives the cost to ~1e-6 … 5e-6 (measured, SDP above local);
#: a tolerance of 1e-10 gets ≤ 1.3e-6 but often ends AlmostSolved.  A relaxation gap where the
#: families fail is ≥ 1e-3 (K = 17: 2.5e-3 … 3.6e-2), so 1e-5 separates the two cleanly.
TIGHT_COST_RTOL = 1e-5
#: preset long_horizon: the largest K at which the paper's families are tight for every seed tried
#: (0–4); at K = 17 only seed 0 of 0–4 is tight (see the slow tests)
TIGHT_K = 15
#: preset long_horizon: a K at which they are tight for every seed and which solves in a few seconds
FAST_TIGHT_K = 11
LOOSE_K = 17


def _instance(seed: int, **params):
    """An instance of the long-horizon setting (preset long_horizon: Δt = 1, random-walk twist), on which
    the structural tests and the tightness boundary below were measured, with ϖ marginalised (the
    paper's SDP), unless params say otherwise."""
    return PROB.generate({"preset": "long_horizon", "marginalize": True, **params}, seed)


def _relative_violations(model, x: np.ndarray) -> np.ndarray:
    return np.array([abs(x @ (c.A @ x) - c.b) / (np.sqrt((c.A.multiply(c.A)).sum()) * (x @ x))
                     for c in model.all_constraints()])


def _paper_cost(inst, T: np.ndarray, w: np.ndarray) -> float:
    """The cost (46)–(47) written out directly from the paper, independently of the module."""
    m = inst.measurements
    out = 0.0
    for k, Tm, W in zip(m["measured"], m["T_meas"], m["W"]):
        xi = lie.cay_inv_se3(T[k] @ lie.inv_se3(Tm))
        out += xi @ W @ xi
    dp = m["w_prior"] - w[0]
    out += dp @ np.linalg.solve(m["Q1"], dp)
    for k in range(len(T) - 1):
        dt = m["times"][k + 1] - m["times"][k]
        e = np.concatenate([dt * w[k] - lie.cay_inv_se3(T[k + 1] @ lie.inv_se3(T[k])), w[k] - w[k + 1]])
        Qk = np.block([[dt**3 / 3 * m["Qc"], dt**2 / 2 * m["Qc"]], [dt**2 / 2 * m["Qc"], dt * m["Qc"]]])
        out += e @ np.linalg.solve(Qk, e)
    return float(out)


# ----------------------------------------------------------------------------- structure


def test_structure_counts_and_roles():
    inst = _instance(0, K=7)
    model = PROB.build(inst)
    K, M = 7, 3
    assert list(inst.measurements["measured"]) == [0, 3, 6]
    assert model.variables.N == 1 + 12 * K + 6 * M + 6 * (K - 1)
    counts = {f: len(model.paper[f]) for f in model.paper}
    assert counts == {"R1": 3 * M, "R2": M, "R3": 3 * (K - 1), "R4": 3 * M, "R5": M, "R6": 4 * (K - 1),
                      "R7": 3 * M, "R8": K - 1}
    types = model.factor_types()
    assert [len(types[t]) for t in ("so3", "pose_meas", "motion")] == [K, M, K - 1]
    assert all(len(f.constraints) == 12 for t in ("pose_meas", "motion") for f in types[t])
    assert {f.roles for f in types["motion"]} == {ct.MOTION_ROLES}
    kept = PROB.build(_instance(0, K=7, marginalize=False))
    assert kept.variables.N == model.variables.N + 6 * K


@pytest.mark.parametrize("params", [{"K": 6}, {"K": 5, "sigma": 1.0, "preset": "long_horizon"},
                                    {"K": 4, "times": (0.0, 0.5, 2.0, 2.7), "qc_diag": (1, 2, 3, 0.5, 0.1, 4)}])
def test_the_declared_factors_are_the_hand_written_model_to_the_bit(params):
    """The ϖ-kept cost the factor-graph layer sums from the declared factors is the form ``_full_cost`` assembles
    block by block for the Schur complement (``marginal``), bit for bit, on the same blocks; the constraints keep
    their names (the rotations' by block, the Cayley rows by column, R6 and R7 by row)."""
    inst = PROB.generate(params, 1)
    model = PROB.build(inst)
    d = ct._data(inst)
    V = ct._variables(d, True)
    assert model.variables.names == V.names
    assert (sp.csr_array(ct._full_cost(d, V)) != model.Q).nnz == 0
    names = [c.name for c in model.primary()]
    assert names[1:4] == ["orth(p0_c1,p0_c1)", "orth(p0_c1,p0_c2)", "orth(p0_c1,p0_c3)"]
    assert "meas_0:col3[2]" in names and "motion_1_0:r[2]" in names
    assert [c.name for c in model.paper["R6"][:4] + model.paper["R7"][:3]] == \
        [f"motion_1_0:R6[{i}]" for i in ("1", "2", "3", "r")] + [f"meas_0:R7[{r}]" for r in ("123", "231", "312")]
    assert all(f.data is None for f in model.factors)


@pytest.mark.parametrize("marginalize", [True, False])
def test_every_constraint_vanishes_on_fresh_so3_samples(marginalize, lifted_violations):
    inst = _instance(3, K=7, marginalize=marginalize)
    model = PROB.build(inst)
    rng = np.random.default_rng(7)
    samples = [PROB.sample(inst, rng, spread=0.3) for _ in range(30)]
    assert min(np.linalg.det(T[:3, :3]) for s in samples for T in s["T"]) > 0.999  # R7 needs SO(3)
    xs = np.array([np.ravel(PROB.lift(inst, s)) for s in samples])
    assert lifted_violations(model.all_constraints(), xs).max() < CONSTRAINT_RTOL
    z = np.concatenate([[1.0], rng.standard_normal(model.variables.N - 1)])
    fams = np.array([c.family for c in model.all_constraints()])
    assert _relative_violations(model, z)[fams != "homogenisation"].min() > 1e-6


def test_r7_fails_off_so3_while_the_other_constraints_hold():
    """R7 uses c_ℓ × c_m = c_n: reflect every C and C̃ (C ← C F, det −1) and all else still holds."""
    F = np.diag([1.0, 1.0, -1.0])
    inst = _instance(1, K=3, measured=(1,))
    T = inst.truth["T"]
    meas, motion = ct.residuals(inst, T)  # unchanged by the reflection: C F (C̃ F)ᵀ = C C̃ᵀ
    Tm = inst.measurements["T_meas"][0]
    inst.measurements["T_meas"] = np.array([lie.make_pose(Tm[:3, :3] @ F, Tm[:3, 3])])
    model = PROB.build(inst)
    vals = ct.xi_values(meas[0], ct.meas_xi(1))
    for k in range(3):
        vals |= ct.pose_values(T[k][:3, :3] @ F, T[k][:3, 3], ct.pose_prefix(k))
    for k in range(2):
        vals |= ct.xi_values(motion[k], ct.motion_xi(k))
    viol = _relative_violations(model, model.variables.assemble(vals)[0])
    is_r7 = np.array([c.family == "R7" for c in model.all_constraints()])
    assert viol[~is_r7].max() < CONSTRAINT_RTOL
    assert viol[is_r7].min() > 1e-6


# ----------------------------------------------------------------------------- cost and Schur complement


@pytest.mark.parametrize("seed", [0, 1])
def test_schur_cost_is_the_full_cost_at_the_optimal_twists(seed):
    inst = _instance(seed, K=9)
    model = PROB.build(inst)
    rng = np.random.default_rng(10 + seed)
    s = PROB.sample(inst, rng, spread=0.3)
    w_opt = ct.optimal_twists(inst, s["T"])
    full = _paper_cost(inst, s["T"], w_opt)
    x = PROB.lift(inst, s)
    assert abs(x @ (model.Q @ x) + model.cost_offset - full) <= COST_RTOL * full
    assert abs(PROB.cost(inst, {"T": s["T"]}) - full) <= COST_RTOL * full
    # w_opt is the minimiser: the cost is quadratic in ϖ, so its central-difference gradient is exact
    h = 1e-3
    grad = np.array([(_paper_cost(inst, s["T"], w_opt + h * E) - _paper_cost(inst, s["T"], w_opt - h * E)) / (2 * h)
                     for E in np.eye(w_opt.size).reshape(-1, *w_opt.shape)])
    assert np.abs(grad).max() <= 1e-6 * full
    # any other ϖ costs more, by exactly the quadratic form of the deviation
    assert _paper_cost(inst, s["T"], w_opt + 0.1 * rng.standard_normal(w_opt.shape)) > full


def test_kept_twist_lifting_gives_the_full_cost_for_any_twists():
    inst = _instance(2, K=6, marginalize=False)
    model = PROB.build(inst)
    rng = np.random.default_rng(5)
    for _ in range(5):
        s = PROB.sample(inst, rng, spread=0.5)
        x = PROB.lift(inst, s)
        full = _paper_cost(inst, s["T"], s["w"])
        assert abs(x @ (model.Q @ x) + model.cost_offset - full) <= COST_RTOL * full
        assert abs(PROB.cost(inst, s) - full) <= COST_RTOL * full


def test_schur_complement_couples_the_whole_chain_with_geometric_decay():
    """Q_ww⁻¹ is dense: far motion blocks are coupled, decaying by 2 − √3 per step (uniform Δt, Q_c ∝ I)."""
    K = 15
    mg = ct.marginal(_instance(0, K=K))
    S = mg.S.toarray()
    V = mg.Vx

    def block(a: int, b: int) -> float:
        return np.abs(S[np.ix_(V.index(ct.xi_blocks(ct.motion_xi(a))), V.index(ct.xi_blocks(ct.motion_xi(b))))]).max()

    assert block(0, K - 2) > 0
    mid = K // 2 - 1
    ratios = [block(mid, mid + j + 1) / block(mid, mid + j) for j in range(1, 4)]
    assert np.allclose(ratios, 2 - np.sqrt(3), rtol=2e-2)
    # with Q_c diagonal the 6 components decouple: ρ never couples with φ in the Schur complement
    rho, phi = V.index([ct.xi_blocks(ct.motion_xi(k))[0] for k in range(K - 1)]), \
        V.index([ct.xi_blocks(ct.motion_xi(k))[1] for k in range(K - 1)])
    assert np.abs(S[np.ix_(rho, phi)]).max() == 0.0


@pytest.mark.parametrize("marginalize", [True, False])
def test_cliques_cover_every_nonzero_and_form_a_clique_tree(marginalize):
    inst = _instance(0, K=8, measured=(0, 2, 7), marginalize=marginalize)
    model = PROB.build(inst)
    if marginalize:
        assert model.cliques is None  # Clarabel's entry-level decomposition is used instead
        cl = [model.variables.index(c) for c in ct.marginalized_cliques(inst)]
    else:
        cl = model.clique_indices()
    assert has_running_intersection(cl)
    covered = np.zeros((model.variables.N,) * 2, bool)
    for c in cl:
        covered[np.ix_(c, c)] = True
    for A in [model.Q] + [c.A for c in model.all_constraints()]:
        r, c = sp.coo_array(A).nonzero()
        assert covered[r, c].all()
    largest = max(len(c) for c in cl)
    assert largest == (1 + 24 + 6 * 7 if marginalize else 1 + 24 + 6 + 12)


# ----------------------------------------------------------------------------- local solver


def test_jacobians_match_finite_differences():
    inst = _instance(4, K=5, measured=(0, 2, 4))
    rng = np.random.default_rng(11)
    s = PROB.sample(inst, rng, spread=0.4)
    state = (s["T"], s["w"])
    e0, J, _ = ct.linearize(inst, state)
    J = J.toarray()
    h = 1e-6
    num = np.column_stack([(ct.linearize(inst, ct.retract(state, h * d), jacobian=False)[0]
                            - ct.linearize(inst, ct.retract(state, -h * d), jacobian=False)[0]) / (2 * h)
                           for d in np.eye(J.shape[1])])
    assert np.abs(num - J).max() <= 1e-6 * np.abs(J).max()
    assert np.abs(J).max() > 1.0  # not vacuous


def test_local_solver_from_truth_is_stationary_and_beats_the_truth():
    inst = _instance(0, K=11)
    res = PROB.local_solve(inst, inst.truth)
    assert res.converged
    assert res.cost < PROB.cost(inst, inst.truth)
    e, J, W = ct.linearize(inst, (res.state["T"], res.state["w"]))
    grad = J.T @ (W @ e)
    assert np.abs(grad).max() <= 1e-6 * np.abs(J.T @ (W @ np.abs(e))).max()
    # the twists it returns are the optimal ones for its poses
    np.testing.assert_allclose(res.state["w"], ct.optimal_twists(inst, res.state["T"]), atol=1e-6)


# ----------------------------------------------------------------------------- tightness


def _solve(inst, with_paper: bool = True):
    model = PROB.build(inst)
    cons = model.primary() + (model.paper_constraints() if with_paper else [])
    # Clarabel's chordal decomposition with its clique-graph merging: on this problem (a Schur
    # complement that couples the whole chain) it is faster than parent-child merging
    return solve_model(model, cons, SolverConfig(decompose=False,
                                                        clarabel=ClarabelOptions(merge="clique_graph")))


def _assert_tight(inst) -> None:
    res = _solve(inst)
    local = PROB.local_solve(inst, inst.truth)
    assert res.status == "Solved", res.summary()
    assert res.log_svr > 5.0, res.summary()
    assert abs(relative_gap(res.primal_cost, local.cost)) < TIGHT_COST_RTOL, (res.primal_cost, local.cost)
    est = PROB.recover(inst, res.Theta)
    assert np.all(est["det_raw"] > 0.999)  # det C = +1 comes out although the QCQP only has O(3)
    pos = lambda T: np.array([-t[:3, :3].T @ t[:3, 3] for t in T])  # noqa: E731
    assert np.abs(pos(est["T"]) - pos(local.state["T"])).max() < 1e-3
    np.testing.assert_allclose(est["w"], local.state["w"], atol=1e-3)


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow), pytest.param(2, marks=pytest.mark.slow)])
def test_paper_families_tight_long_horizon_small_k(seed):
    _assert_tight(_instance(seed, K=FAST_TIGHT_K))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paper_families_tight_at_the_largest_tight_k(seed):
    _assert_tight(_instance(seed, K=TIGHT_K))


def _assert_not_tight(inst, min_gap: float) -> None:
    res = _solve(inst)
    local = PROB.local_solve(inst, inst.truth)
    assert res.log_svr < 3.0, res.summary()
    assert relative_gap(res.primal_cost, local.cost) > min_gap, res.summary()  # SDP strictly below


def test_boundary_not_tight_at_high_noise():
    """K = 7, σ = 1 (seed 1): the paper's families leave a relaxation gap (measured 8 %, log SVR 0.65)."""
    _assert_not_tight(_instance(1, K=7, sigma=1.0), 1e-2)


@pytest.mark.slow
def test_boundary_not_tight_beyond_the_largest_tight_k():
    """K = 17, seed 1: measured log SVR 1.5, SDP 1.6 % below the local optimum."""
    _assert_not_tight(_instance(1, K=LOOSE_K), 1e-3)


@pytest.mark.slow
def test_boundary_not_tight_at_the_paper_k21_long_horizon():
    """K = 21 (the paper's size) over a 20 s horizon, seed 0: measured log SVR ≈ 1–2, Clarabel stops at
    AlmostSolved."""
    res = _solve(_instance(0, K=21))
    assert not (res.status == "Solved" and res.log_svr > 5.0), res.summary()
    assert res.log_svr < 3.0, res.summary()


def test_primary_constraints_alone_are_not_tight():
    inst = _instance(0, K=7)
    res = _solve(inst, with_paper=False)
    local = PROB.local_solve(inst, inst.truth)
    assert res.log_svr < 2.0, res.summary()  # measured 0.32
    assert relative_gap(res.primal_cost, local.cost) > 0.1, res.summary()  # measured: SDP 54 % below


def test_random_start_trapped_where_the_sdp_is_not():
    """K = 7, seed 0: random starts (independent uniform rotations, spread translations) end in poor
    local minima (measured: 4 of 5, costs 23× and 47× the optimum); the SDP is tight and its
    recovered estimate attains the optimum."""
    inst = _instance(0, K=7)
    res = _solve(inst)
    assert res.status == "Solved" and res.log_svr > 5.0, res.summary()
    rng = np.random.default_rng(2024)
    runs = [PROB.local_solve(inst, PROB.random_state(inst, rng)) for _ in range(5)]
    assert all(r.converged for r in runs)
    trapped = [r.cost for r in runs if r.cost > 1.01 * res.primal_cost]
    assert len(trapped) >= 1
    est = PROB.recover(inst, res.Theta)
    assert abs(PROB.cost(inst, est) - res.primal_cost) <= TIGHT_COST_RTOL * res.primal_cost
    assert min(trapped) > 10 * PROB.cost(inst, est)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("params, message", [
    ({"K": 1}, "K"),
    ({"K": 4, "times": (0.0, 1.0, 1.0, 2.0)}, "increase"),
    ({"K": 3, "times": (0.0, 1.0)}, "timestamps"),
    ({"qc_diag": (1, 1, 1, 1, 1, -1)}, "positive definite"),
    ({"qc": 0.0}, "qc"),
    ({"K": 5, "measured": (0, 5)}, "outside the trajectory"),
    ({"K": 5, "measured": (-1, 2)}, "outside the trajectory"),
    ({"K": 5, "measured": (1.5,)}, "integers"),
])
def test_bad_input_gets_a_one_line_error(params, message):
    with pytest.raises(ParameterError, match=message) as info:
        PROB.generate(params, 0)
    assert "\n" not in str(info.value)


def test_custom_timestamps_are_used():
    inst = _instance(0, K=4, times=(0.0, 0.5, 2.0, 2.5), measured=(0, 3))
    np.testing.assert_allclose(inst.measurements["times"], [0.0, 0.5, 2.0, 2.5])
    model = PROB.build(inst)
    s = PROB.sample(inst, np.random.default_rng(0), spread=0.2)
    w = ct.optimal_twists(inst, s["T"])
    x = PROB.lift(inst, s)
    full = _paper_cost(inst, s["T"], w)
    assert abs(x @ (model.Q @ x) - full) <= COST_RTOL * full


def test_keeping_the_twists_gives_the_marginalised_sdp_optimum():
    """With Q_ww ≻ 0, ⟨Q_full, X⟩ minimised over the ϖ rows and columns of X ⪰ 0 is ⟨S, X_xx⟩: the
    SDP with ϖ kept (solved on our clique cover) and the marginalised SDP have the same optimal cost
    (to 1e-6 relative, Clarabel's tolerance being 1e-8), and its x-block matches the marginalised
    rank-1 solution (entries to 1e-4 of max|X|)."""
    out = {}
    for marginalize in (True, False):
        inst = _instance(4, K=6, marginalize=marginalize)
        model = PROB.build(inst)
        res = solve_model(model, model.primary() + model.paper_constraints(), SolverConfig(decompose=not marginalize))
        assert res.status == "Solved" and res.log_svr > 5, res.summary()
        out[marginalize] = (res, model)
    (m_res, m_model), (k_res, k_model) = out[True], out[False]
    assert abs(k_res.primal_cost - m_res.primal_cost) <= 1e-6 * m_res.primal_cost
    ix = k_model.variables.index(m_model.variables.names)
    assert np.abs(k_res.X[np.ix_(ix, ix)] - m_res.X).max() <= 1e-4 * np.abs(m_res.X).max()


# ----------------------------------------------------------------------------- presets and the paper default


def test_default_keeps_varpi_and_advises_our_cover_which_gives_the_marginalised_optimum():
    """The default solves the ϖ-kept SDP on our clique cover (the model's ``decompose`` advice, taken
    only when the user left ``SolverConfig.decompose`` open); its x-block has the marginalised SDP's
    optimum (costs equal to the verdict's gap_tol, 1e-5 relative, K = 6; measured 1.4e-6) and its
    marginal log SVR is high."""
    from autotight import sdp

    kept_inst = PROB.generate({"K": 6}, 3)
    assert kept_inst.params["marginalize"] is False
    kept = PROB.build(kept_inst)
    marg = PROB.build(PROB.generate({"K": 6, "marginalize": True}, 3))
    assert (kept.decompose, marg.decompose) == (True, None)
    res = sdp.solve_model(kept, kept.primary() + kept.paper_constraints())
    assert res.solver == "clarabel-cliques", res.solver
    forced = sdp.solve_model(kept, kept.primary() + kept.paper_constraints(), sdp.SolverConfig(decompose=False))
    assert forced.solver == "clarabel-chordal", forced.solver
    ref = sdp.solve_model(marg, marg.primary() + marg.paper_constraints())
    assert abs(res.primal_cost - ref.primal_cost) <= 1e-5 * abs(ref.primal_cost), (res.primal_cost, ref.primal_cost)
    assert ct.marginal_log_svr(kept_inst, res.X, res.cliques) > 5.0


def test_default_preset_is_the_paper_setting_and_explicit_params_win():
    inst = PROB.generate({"K": 5}, 0)
    assert inst.params["preset"] == "paper"
    assert {k: inst.params[k] for k in ct.PRESETS["paper"]} == ct.PRESETS["paper"]
    np.testing.assert_allclose(inst.measurements["times"], 0.1 * np.arange(5))
    long = PROB.generate({"K": 5, "preset": "long_horizon"}, 0)
    assert {k: long.params[k] for k in ct.PRESETS["long_horizon"]} == ct.PRESETS["long_horizon"]
    np.testing.assert_allclose(long.measurements["times"], np.arange(5.0))
    mixed = PROB.generate({"K": 5, "preset": "long_horizon", "dt": 0.3, "geometry": "arc"}, 0)
    assert (mixed.params["dt"], mixed.params["geometry"], mixed.params["qc"]) == (0.3, "arc", 1.0)
    np.testing.assert_allclose(mixed.measurements["times"], 0.3 * np.arange(5))
    with pytest.raises(ParameterError, match="preset"):
        PROB.generate({"preset": "fig10"}, 0)
    with pytest.raises(ParameterError, match="geometry"):
        PROB.generate({"geometry": "spiral"}, 0)
    with pytest.raises(ParameterError, match="dt"):
        PROB.generate({"dt": -0.1}, 0)


def test_arc_geometry_is_the_same_for_every_seed_and_only_the_noise_changes():
    a, b = PROB.generate({"K": 7}, 0), PROB.generate({"K": 7}, 1)
    np.testing.assert_array_equal(a.truth["T"], b.truth["T"])
    np.testing.assert_array_equal(a.truth["w"], np.tile(ct.BASE_TWIST, (7, 1)))
    assert np.abs(a.measurements["T_meas"] - b.measurements["T_meas"]).max() > 1e-3
    assert np.abs(a.measurements["w_prior"] - b.measurements["w_prior"]).max() > 1e-3
    r1, r2 = (PROB.generate({"K": 7, "preset": "long_horizon"}, s).truth["T"] for s in (0, 1))
    assert np.abs(r1 - r2).max() > 1e-2  # the random walk draws a new geometry per seed


def _chain_rank1(N: int = 30, width: int = 8, step: int = 5, rank: int = 1, seed: int = 0):
    rng = np.random.default_rng(seed)
    F = rng.standard_normal((rank, N))
    cliques = [np.r_[0, np.arange(s, min(s + width, N))] for s in range(1, N - 1, step)]
    return F.T @ F, cliques


def test_psd_completion_recovers_low_rank_data_and_stays_psd():
    X, cliques = _chain_rank1()
    on = np.zeros_like(X, dtype=bool)
    for c in cliques:
        on[np.ix_(c, c)] = True
    assert not on.all()
    partial = np.where(on, X, 123.0)  # entries off the cover are ignored, whatever they hold
    np.testing.assert_allclose(ct.complete_psd(partial, cliques), X, atol=1e-10 * np.abs(X).max())
    X2, _ = _chain_rank1(rank=3, seed=1)
    Y = ct.complete_psd(np.where(on, X2, 0.0), cliques)
    np.testing.assert_allclose(Y[on], X2[on], atol=1e-12 * np.abs(X2).max())
    assert np.linalg.eigvalsh(Y)[0] > -1e-10 * np.abs(X2).max()
    # every separator (h and 3 shared columns) has the data's rank 3: the completion is unique, X2 itself
    np.testing.assert_allclose(Y, X2, atol=1e-8 * np.abs(X2).max())
    # separators {h} only: rank adds up over the cliques (max-det adds no correlation beyond h)
    X3, narrow = _chain_rank1(rank=3, width=5, step=5, seed=2)
    Z = ct.complete_psd(X3, narrow)
    assert np.linalg.matrix_rank(Z, tol=1e-8 * np.abs(Z).max()) > 3


#: |log SVR (ϖ kept, marginal, from the clique blocks) − log SVR (marginalised SDP)| on tight K = 6, 8
#: instances: two solvers stopping at different points of the same optimum; measured ≤ 0.9 decades
#: (σ = 0.01 … 1, seeds 0–1), against the 5 decades that separate rank 1 from not
MARGINAL_SVR_ATOL = 1.5


def _marginal_svrs(seed: int, with_paper: bool, **params) -> tuple[float, float, float, float]:
    """(marginal log SVR, cost) for the marginalised SDP (Clarabel's chordal decomposition, judged on
    its column cover) and for the ϖ-kept SDP on our clique cover."""
    from autotight import sdp
    from autotight.sdp.chordal import column_cliques

    out = []
    for marginalize in (True, False):
        inst = PROB.generate({"K": 6, "marginalize": marginalize, **params}, seed)
        model = PROB.build(inst)
        cons = model.primary() + (model.paper_constraints() if with_paper else [])
        res = sdp.solve_model(model, cons, sdp.SolverConfig(decompose=not marginalize, scale="none"))
        assert res.status == "Solved", res.summary()
        cl = column_cliques(model.variables.N, [model.Q, *[c.A for c in cons]], always=[0]) if marginalize \
            else res.cliques
        out += [ct.marginal_log_svr(inst, res.X, cl), res.primal_cost]
    return tuple(out)


@pytest.mark.parametrize("seed, sigma", [(0, 0.1), (1, 0.01)])
def test_marginal_log_svr_of_the_kept_solve_matches_the_marginalised_sdp(seed, sigma):
    marg, marg_cost, kept, kept_cost = _marginal_svrs(seed, True, sigma=sigma)
    assert marg > 5 and kept > 5, (marg, kept)
    assert abs(kept - marg) <= MARGINAL_SVR_ATOL, (marg, kept)
    # unscaled solves at σ = 0.01 agree to 1.4e-5 only (ξ_k blocks are σ² below the rest)
    assert abs(kept_cost - marg_cost) <= 5e-5 * marg_cost


def test_marginal_log_svr_is_low_where_the_relaxation_is_not_tight():
    """Primary constraints only (K = 6, seed 0): measured 0.02 (marginalised) and 0.09 (ϖ kept), where
    the minimum over the kept solve's clique blocks reads 0.01 and the rank-1-filled X reads 3.2."""
    marg, _, kept, _ = _marginal_svrs(0, False)
    assert marg < 1.0 and kept < 1.0, (marg, kept)


#: the paper's K = 21 at the default (preset paper, ϖ kept, Clarabel on our cover), seeds 0–2, through the
#: public pipeline: tight by the bracket test and the rank, log SVR on the marginalised X measured 8.5–10.4
#: (seeds 0–9: 8.5–11.1).  Slow: 12–17 s per seed.
@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paper_default_k21_is_tight(seed):
    from autotight import solve

    out = solve(PROB, {}, seed)
    inst = out.instance
    assert (inst.params["K"], inst.params["dt"], inst.params["geometry"]) == (21, 0.1, "arc")
    assert out.tight and out.outcome == "tight", out.verdict.reason
    assert out.log_svr_marginal > 5.0, out.log_svr_marginal
    assert out.sdp.usable and out.verdict.upper - out.verdict.lower <= 1e-4 * abs(out.verdict.upper)


def test_the_cost_only_example_on_the_layer_page_is_the_shipped_module():
    """Every line of docs/factor_graph.md's cost-only snippet is a line of problems/continuous_trajectory.py."""
    from doc_snippets import missing_lines

    lines, missing = missing_lines("cost_only=True", "continuous_trajectory")
    assert len(lines) >= 7 and missing == []
