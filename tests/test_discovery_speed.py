"""The shortcuts that make discovery fast give what the full computation gives: the held-out certificate
decides only "tight", and only where the full SDP says tight too; span tests with a shared cache, template
samples without checks and batched pose residuals equal their plain versions."""

from __future__ import annotations

import numpy as np
import pytest

from autotight import lie
from autotight.check import PointResult
from autotight.constraint_set import resolve
from autotight.discovery import compare
from autotight.errors import ParameterError
from autotight.discovery.catalog import learn
from autotight.discovery.engine import discover, shortcut_pays
from autotight.discovery.heldout import hopeless, solve_batch
from autotight.discovery.shortcut import certified_tight
from autotight.pipeline import local_search, seeds, solve_instance
from autotight.problem import load
from autotight.sdp.config import SolverConfig
from autotight.tightness import Criteria


@pytest.fixture(scope="module")
def pose():
    return load("pose_averaging")


def _case(prob, params, seed, name):
    inst = prob.generate(params, seed)
    model = prob.build(inst)
    loc = local_search(prob, inst, seeds(seed).local(), 1)
    cons = resolve(name, prob, inst, model, seeds(seed).constraints())
    return inst, model, loc, cons


@pytest.mark.parametrize("sigma", [0.1, 1.0])
def test_the_certificate_proves_the_paper_set_tight_where_the_full_sdp_does(pose, sigma):
    params = {"M": 4, "sigma": sigma}
    for seed in (3, 4):
        inst, model, loc, cons = _case(pose, params, seed, "paper")
        proof = certified_tight(model, cons, pose.lift(inst, loc.best.state), Criteria())
        full = solve_instance(pose, inst, "paper", model=model, local=loc)
        assert proof is not None and 0 <= proof.rel_bound <= Criteria().gap_tol and proof.margin > 0
        assert full.outcome == "tight" and full.log_svr > Criteria().min_log_svr


def test_the_certificate_never_decides_a_loose_relaxation(pose):
    """Primary constraints only: the relaxation is not tight (full SDP), and the shortcut says nothing."""
    for seed in (3, 4):
        inst, model, loc, cons = _case(pose, {"M": 4}, seed, "primary")
        assert certified_tight(model, cons, pose.lift(inst, loc.best.state), Criteria()) is None
        assert solve_instance(pose, inst, "primary", model=model, local=loc, raise_unbounded=False).outcome != "tight"


def test_above_the_barriers_size_douglas_rachford_decides_only_where_the_full_sdp_says_tight(monkeypatch):
    """Above ``shortcut.MAX_N`` columns y comes from Douglas–Rachford: a chain with the paper's set is proved tight
    (as the full SDP finds it), the primary constraints alone never are."""
    import autotight.discovery.shortcut as shortcut

    prob = load("discrete_trajectory")
    monkeypatch.setattr(shortcut, "MAX_N", 100)
    for seed in (3, 4):
        inst, model, loc, cons = _case(prob, {"K": 15}, seed, "paper")
        assert model.variables.N > shortcut.MAX_N
        proof = certified_tight(model, cons, prob.lift(inst, loc.best.state), Criteria())
        full = solve_instance(prob, inst, "paper", model=model, local=loc)
        assert proof is not None and 0 <= proof.rel_bound <= Criteria().gap_tol and proof.margin > 0
        assert full.outcome == "tight"
        inst, model, loc, cons = _case(prob, {"K": 15}, seed, "primary")
        assert certified_tight(model, cons, prob.lift(inst, loc.best.state), Criteria()) is None


def test_the_barrier_is_not_run_where_its_factorisation_would_cost_more_than_it_saves(monkeypatch):
    """``certifier.newton_flops`` is M·b² for the Newton matrix's pattern (each clique block's variables, all pairs)
    in ``band_order``'s order, b its half bandwidth there; the shortcut declines a program whose estimate is above
    ``NEWTON_MAX_FLOPS`` without one Newton step (continuous time K = 21 with a learned 2-pair set: 9.7 s a step,
    the full SDP 9 s), and runs the barrier below it."""
    import scipy.sparse as sp

    import autotight.certifier as certifier
    import autotight.discovery.shortcut as shortcut
    from autotight.certificate import stack
    from autotight.certifier import default_cliques, newton_flops, newton_incidence
    from autotight.sdp.clique_program import clique_program
    from autotight.sdp.schur_ipm import band_order

    prob = load("continuous_trajectory")
    inst, model, loc, cons = _case(prob, {"K": 6}, 0, "paper")
    As, b = stack(cons)
    Q = sp.csr_array(model.Q)
    prog = clique_program(Q, As, b, [np.asarray(c) for c in default_cliques(Q, As, model.d)])
    inc = newton_incidence(prog)
    M = prog.F.shape[1]
    pos = band_order(inc, M)[0]
    rows = np.concatenate([np.repeat(i, i.size) for i in inc])
    cols = np.concatenate([np.tile(i, i.size) for i in inc])
    width = int(np.max(np.abs(pos[rows] - pos[cols])))
    flops = newton_flops(prog)
    assert width > 0 and flops == float(M) * width ** 2
    calls = []
    run = shortcut.phase_one

    def counted(*a, **k):
        calls.append(1)
        return run(*a, **k)

    monkeypatch.setattr(shortcut, "phase_one", counted)
    theta = prob.lift(inst, loc.best.state)
    monkeypatch.setattr(certifier, "NEWTON_MAX_FLOPS", flops / 2)
    assert certified_tight(model, cons, theta, Criteria()) is None and calls == []
    monkeypatch.setattr(certifier, "NEWTON_MAX_FLOPS", flops * 2)
    certified_tight(model, cons, theta, Criteria())
    assert calls == [1]


def test_a_held_out_batch_has_the_same_outcomes_with_and_without_the_shortcut(pose):
    points = [(pose.parse_params({"M": 4}), {})]
    kw = dict(min_fraction=0.9, criteria=Criteria(), config=SolverConfig())
    sets = {"paper": "paper", "primary": "primary"}
    fast, n_fast = solve_batch(pose, sets, points, [[11, 12]], shortcut=True, **kw)
    full, n_full = solve_batch(pose, sets, points, [[11, 12]], shortcut=False, **kw)
    for name in sets:
        assert fast[name][0].outcomes == full[name][0].outcomes and fast[name][0].seeds == [11, 12]
    assert fast["paper"][0].statuses == ["certified"] * 2 and n_fast["paper"] == 0 < n_full["paper"]
    assert n_fast["primary"] == n_full["primary"]  # not tight: always the full SDP


@pytest.mark.parametrize("outcomes, planned, fraction, expected", [
    (["not tight"], 10, 0.9, False),  # 9 of 10 can still pass
    (["tight", "not tight", "not tight"], 10, 0.9, True),  # at best 8 of 10
    (["undecided", "not tight"], 10, 0.9, True),  # at best 8 of 9 decided
    (["not tight"] * 5, 10, 0.5, False),  # 5 of 10 passes at 0.5
    (["not tight"] * 6, 10, 0.5, True),
    (["not tight"] * 3, 3, 0.0, False),  # a fraction of 0 always passes
    (["undecided"] * 10, 10, 1.0, False),  # no failure: nothing is hopeless
])
def test_a_batch_is_hopeless_exactly_when_its_best_completion_fails_the_rule(outcomes, planned, fraction, expected):
    assert hopeless(outcomes, planned, fraction) is expected
    if expected:  # the best completion (every other instance tight) indeed fails check's rule
        t, f = outcomes.count("tight") + planned - len(outcomes), outcomes.count("not tight")
        assert t / (t + f) < fraction


def test_a_hopeless_batch_stops_at_the_same_seed_in_process_and_in_workers(pose):
    """σ = 1 with the primary constraints only: instances fail early and the batch stops at the instance that
    makes the point hopeless, with jobs = 1 and 2 alike; the solved prefix has the outcomes of the full batch."""
    points = [(pose.parse_params({"M": 3, "sigma": 1.0}), {})]
    kw = dict(min_fraction=0.9, criteria=Criteria(), config=SolverConfig())
    seeds_ = list(range(40, 48))
    full, _ = solve_batch(pose, {"s": "primary"}, points, [seeds_], **kw)
    one, n_one = solve_batch(pose, {"s": "primary"}, points, [seeds_], stop_hopeless=True, **kw)
    two, n_two = solve_batch(pose, {"s": "primary"}, points, [seeds_], stop_hopeless=True, jobs=2, **kw)
    kept, _ = solve_batch(pose, {"s": "primary"}, points, [seeds_], stop_hopeless=[False], **kw)
    assert kept["s"][0].outcomes == full["s"][0].outcomes  # a point not marked to stop solves its whole batch
    got = one["s"][0].outcomes
    assert hopeless(full["s"][0].outcomes, 8, 0.9)  # the full batch fails, so the stopped one must stop
    assert hopeless(got, 8, 0.9) and not hopeless(got[:-1], 8, 0.9) and len(got) < len(seeds_)
    assert got == full["s"][0].outcomes[:len(got)] and one["s"][0].seeds == seeds_[:len(got)]
    assert two["s"][0].outcomes == got and two["s"][0].seeds == one["s"][0].seeds and n_two == n_one


def test_the_shortcut_is_asked_per_point_and_gives_the_full_sdps_outcomes(pose):
    """The paper set at σ = 0.1: the point that tries the shortcut decides instances by it, without solver calls,
    and the point that does not solves every one; the outcomes agree."""
    params = pose.parse_params({"M": 3, "sigma": 0.1})
    kw = dict(min_fraction=0.9, criteria=Criteria(), config=SolverConfig())
    seeds_ = [5, 6, 7]
    got, _ = solve_batch(pose, {"s": "paper"}, [(params, {}), (params, {})], [seeds_, seeds_],
                         shortcut=[True, False], **kw)
    quick, full = got["s"]
    assert quick.statuses.count("certified") >= 2 and "certified" not in full.statuses
    assert quick.outcomes == full.outcomes == ["tight"] * 3
    with pytest.raises(ParameterError, match="shortcut has 1 entries for 2 points"):
        solve_batch(pose, {"s": "paper"}, [(params, {}), (params, {})], [seeds_, seeds_], shortcut=[True], **kw)


def _batch(outcomes: list[str], statuses: list[str]) -> PointResult:
    pr = PointResult({}, {}, 0.9)
    for s, (o, st) in enumerate(zip(outcomes, statuses)):
        pr.add(s, {"outcome": o, "log_svr": 0.0, "reason": "", "n_constraints": 1, "status": st, "rel_gap": 0.0})
    return pr


@pytest.mark.parametrize("outcomes, statuses, tried, expected", [
    (["tight", "tight"], ["Solved", "AlmostSolved"], True, False),  # tried on tight instances, decided none
    (["tight", "tight"], ["Solved", "certified"], True, True),  # decided one of them
    (["not tight", "undecided"], ["Solved", "AlmostSolved"], True, True),  # no tight instance: no evidence
    (["tight", "not tight"], ["Solved", "Solved"], True, False),
    (["tight"], ["certified"], False, False),  # not tried: stays off until the set grows
])
def test_the_shortcut_is_kept_while_it_decides_tight_instances(outcomes, statuses, tried, expected):
    assert shortcut_pays(_batch(outcomes, statuses), tried) is expected


@pytest.mark.slow  # two discoveries (~1 min); the held-out outcomes themselves: the test above
def test_discovery_with_and_without_the_shortcut_finds_the_same_set():
    kw = dict(n_heldout=3, compare=False)
    fast = discover("pose_averaging", {"M": 3}, 1, **kw)
    full = discover("pose_averaging", {"M": 3}, 1, shortcut=False, **kw)
    assert fast.pairs == full.pairs and fast.validated == full.validated
    assert [p.heldout.outcomes for p in fast.points] == [p.heldout.outcomes for p in full.points]
    assert fast.solves_by_stage["heldout"] <= full.solves_by_stage["heldout"]


def test_span_tests_with_a_shared_cache_equal_fresh_ones(pose):
    inst = pose.generate({"M": 3}, 0)
    model = pose.build(inst)
    cat = learn(pose, inst, model, seeds(0).constraints())
    cache: dict = {}
    assert compare.paper_in_span(cat, cache) == compare.paper_in_span(cat)
    learned = [c for g in cat.groups[:2] for c in cat.basic(g.group.name)][:8]
    assert learned and [compare.resemblance(c, cat, cache=cache) for c in learned] == \
        [compare.resemblance(c, cat) for c in learned]
    for fam, row in compare.paper_in_span(cat).items():  # the paper's families lie in the learned span
        assert row["max_residual"] < 1e-8, fam
    # a residual against the orthonormal basis equals the least-squares one
    g = cat.groups[0]
    basis = compare._homogeneous(model) + cat.basic(g.group.name)
    v, B = compare._local_poly(learned[0], g.columns), np.array(compare._polys(basis, g.columns)).T
    coef, *_ = np.linalg.lstsq(B, v, rcond=None)
    assert compare.span_residual(learned[0], basis, g.columns) == pytest.approx(
        np.linalg.norm(v - B @ coef) / np.linalg.norm(v), abs=1e-12)


def test_unchecked_learning_gives_the_same_basic_solutions(pose):
    inst = pose.generate({"M": 3}, 1)
    model = pose.build(inst)
    a = learn(pose, inst, model, seeds(1).constraints())
    b = learn(pose, inst, model, seeds(1).constraints(), checked=False)
    for ga, gb in zip(a.groups, b.groups):
        assert ga.identities == gb.identities and np.array_equal(ga.coeffs, gb.coeffs)
        assert not gb.passed().any()  # unchecked relations are never offered as candidates


def test_batched_pose_residuals_equal_the_single_pose_map(pose):
    from problems._pose import unary_residuals

    inst = pose.generate({"M": 6}, 2)
    rng = np.random.default_rng(0)
    for _ in range(5):
        s = pose.sample(inst, rng, inst.truth, 0.5)
        T = lie.make_pose(s["C"], s["r"])
        want = np.array([lie.cay_inv_se3(T @ lie.inv_se3(Tm)) for Tm in inst.measurements["T_meas"]])
        assert np.allclose(unary_residuals(T, inst.measurements["T_meas"]), want, rtol=0, atol=1e-13)
    near_pi = lie.make_pose(lie.exp_so3(np.array([np.pi, 0, 0])), np.zeros(3))
    with pytest.raises(lie.CayleySingularityError):
        unary_residuals(near_pi, [np.eye(4)])


def test_template_fits_with_a_shared_cache_equal_fresh_ones(pose):
    """A set that grows (one pair, then two) is fitted from the kept instances: the same templates."""
    from autotight.discovery.templates import learn_templates

    params = pose.parse_params({"M": 3})
    inst = pose.generate(params, 0)
    cat = learn(pose, inst, pose.build(inst), seeds(0).constraints())
    idents = [i for g in cat.groups[:1] for i in g.identities][:2]
    pairs = [("pose_meas", i) for i in idents]
    cache: dict = {}
    learn_templates(pose, params, pairs[:1], 0, cache=cache)
    n_kept = len(cache)
    grown = learn_templates(pose, params, pairs, 0, cache=cache)
    fresh = learn_templates(pose, params, pairs, 0)
    assert n_kept > 0 and len(cache) >= n_kept
    assert set(grown.templates) == set(fresh.templates) == {"pose_meas"} and grown.fallback == fresh.fallback
    a, b = grown.templates["pose_meas"], fresh.templates["pose_meas"]
    assert a.degree == b.degree and np.array_equal(a.W, b.W) and a.check == b.check


def test_no_shortcut_is_tried_where_the_barrier_costs_more_than_the_sdp():
    from autotight.discovery.shortcut import MAX_N

    prob = load("discrete_trajectory")
    inst = prob.generate({"K": 45}, 0)
    model = prob.build(inst)
    assert model.variables.N > MAX_N
    cons = resolve("paper", prob, inst, model, seeds(0).constraints())
    assert certified_tight(model, cons, prob.lift(inst, inst.truth), Criteria()) is None
