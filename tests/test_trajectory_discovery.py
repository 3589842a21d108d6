"""Discovery on trajectories: per-factor learning on the discrete trajectory is tight with no
more constraints than the paper's, every discovered constraint vanishes on fresh feasible samples, the
set carries over to a held-out instance; per-factor learning on the continuous-time problem yields
constraints that hold on fresh samples."""

from __future__ import annotations

import numpy as np
import pytest

from autotight.discovery import discover, instantiate, learn
from autotight.discovery.samples import draw, relative_violation
from autotight.problem import load
from autotight.pipeline import local_search
from autotight.sdp import solve_model
from autotight.tightness import judge

#: a learned relation evaluated on exact feasible samples: rounding only (the learning tolerance is 1e-8)
FRESH_TOL = 1e-9
#: spread of the fresh samples around the ground truth (the learning default is 0.5; use a wider one)
FRESH_SPREAD = 0.8
DISCRETE = load("discrete_trajectory")
CONTINUOUS = load("continuous_trajectory")
K_DISCRETE = 4


@pytest.fixture(scope="module")
def discrete_result():
    return discover(DISCRETE, {"K": K_DISCRETE}, seed=0, groups="factors", n_heldout=2, n_random=1, compare=False,
                    carry_to={})


def test_discrete_discovery_is_tight_and_no_larger_than_paper(discrete_result):
    res = discrete_result
    assert res.tight, res.points[0].messages
    assert res.example.tight_result.log_svr > 5
    n_paper = len(res.model.paper_constraints())
    assert 0 < len(res.constraints) <= n_paper
    assert len(res.discovered.pairs) >= 1
    # every discovered constraint is a learned relation of a trajectory factor type
    types = {t for t, _ in res.discovered.pairs}
    assert types <= set(res.model.factor_types())
    assert res.validated and res.points[0].heldout.fraction >= 0.9, res.validation["message"]


def test_discrete_discovered_constraints_vanish_on_fresh_samples(discrete_result):
    res = discrete_result
    bank = draw(DISCRETE, res.instance, 40, np.random.default_rng(12345), FRESH_SPREAD)
    viol = relative_violation(res.constraints, bank.thetas)
    assert viol.max() < FRESH_TOL, dict(zip([c.name for c in res.constraints], viol))


def test_discrete_discovered_set_carries_over_to_a_heldout_instance(discrete_result):
    res = discrete_result
    seed = 1000  # not a learning or held-out seed of the fixture
    inst = DISCRETE.generate(res.params, seed)
    model = DISCRETE.build(inst)
    rng = np.random.default_rng([seed, 3])
    cons, issues = instantiate(DISCRETE, inst, res.discovered.pairs, rng, res.discovered.options(), model)
    assert not issues, issues
    assert len(cons) == len(res.constraints)
    bank = draw(DISCRETE, inst, 40, np.random.default_rng([seed, 4]), FRESH_SPREAD)
    assert relative_violation(cons, bank.thetas).max() < FRESH_TOL
    sdp = solve_model(model, model.primary() + cons)
    loc = local_search(DISCRETE, inst, rng, 1)
    verdict = judge(sdp, loc.best.cost)
    assert verdict.tight, verdict.reason
    # and the primary constraints alone are not: the discovered set is doing the work
    assert not judge(solve_model(model, model.primary()), loc.best.cost).tight


def test_continuous_per_factor_candidates_hold_on_fresh_samples():
    inst = CONTINUOUS.generate({"K": 3}, 0)
    model = CONTINUOUS.build(inst)
    cat = learn(CONTINUOUS, inst, model, np.random.default_rng(0), "factors")
    cands = cat.candidates()
    types = {c.identity.split(":", 1)[0] for c in cands}
    # the measurement and motion factors both carry relations beyond the primary constraints
    assert {"pose_meas", "motion"} <= types, types
    bank = draw(CONTINUOUS, inst, 40, np.random.default_rng(999), FRESH_SPREAD)
    viol = relative_violation(cands, bank.thetas)
    assert viol.max() < FRESH_TOL, sorted(zip(viol, [c.name for c in cands]))[-3:]
    # the paper's families lie in the span of what was learned (with the primary constraints)
    from autotight.discovery.compare import paper_in_span

    span = paper_in_span(cat)
    assert max(v["max_residual"] for v in span.values()) < 1e-6, span
