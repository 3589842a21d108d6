"""Discovery on the landmark problems where Shor with the primary constraints is not tight.

Cases (landmark SLAM, K = L = 3, σ = 1; benchmarks/landmark_liftings.py scans these problems and runs the default
discovery on them, reports/landmark_liftings/README.md):

- d = 2, matrix lifting, seed 9: the primary SDP is rank 2 but two of its poses are reflections
  (det C = −1), so its cost is below every rotation.  Discovery learns one identity of the odometry
  factor, (C_iᵀC_j)_xx = (C_iᵀC_j)_yy, which forbids a relative reflection and tightens it.
- d = 3, seed 4: the matrix lifting cannot express handedness in 3D (no quadratic constraint in the
  columns of Θ separates SO(3) from O(3)); discovery reports "not tightenable".  The vector lifting
  learns handedness constraints (c_a × c_b = c_c) and is tight.

Held-out verification as in discovery: the set is re-instantiated with
DiscoveredSet.instantiate on fresh instances at the same parameters (seeds seed+1 … seed+10) and each
is judged against its best local solution (truth + 2 random starts).  What we find at σ = 1: the
irreducible set is specific to its learning instance (it cuts that instance's reflection), so on these
held-out seeds it is tight exactly where the primary set already is (90 % for d = 2 matrix, 60 % for
d = 3 vector): here there are no held-out rounds (n_heldout=0), whose failures the default discovery takes in.
The tests assert the floors found and that the set never does worse than the primary set on the same
instances, and print the fractions.

Tolerances: tightness as in autotight.tightness (log SVR > 5, relative cost gap 1e-5 + solver
accuracy); learned constraints vanish on fresh samples to a relative violation of 1e-9 (they are
exact relations; rounding gives ~1e-14).
"""

from __future__ import annotations

import numpy as np
import pytest

from autotight.discovery import discover, learn
from autotight.discovery.samples import draw, relative_violation
from autotight.problem import load
from autotight.pipeline import local_search
from autotight.sdp import solve_model
from autotight.tightness import judge

PROBLEM = "landmark_slam"
SIGMA = 1.0
N_HELDOUT = 10


@pytest.fixture(scope="module")
def slam():
    return load(PROBLEM)


def _discover(d: int, lifting: str, seed: int):
    # held-out checking is done by the tests themselves, through DiscoveredSet.instantiate
    return discover(PROBLEM, {"dim": d, "lifting": lifting, "sigma": SIGMA}, seed, n_heldout=0, compare=False)


@pytest.fixture(scope="module")
def slam2_matrix():
    return _discover(2, "matrix", 9)


@pytest.fixture(scope="module")
def slam3_vector():
    return _discover(3, "vector", 4)


def heldout_fractions(prob, res) -> tuple[float, float]:
    """(tight fraction with primary + re-instantiated discovered set, with primary alone)."""
    tight_disc, tight_prim = [], []
    for s in range(res.seed + 1, res.seed + 1 + N_HELDOUT):
        inst = prob.generate(res.params, s)
        model = prob.build(inst)
        extra = res.discovered.instantiate(prob, inst, np.random.default_rng([s, 7]), model)
        assert len(extra) > 0
        best = local_search(prob, inst, np.random.default_rng([s, 1]), 2).best.cost
        tight_disc.append(judge(solve_model(model, model.primary() + extra), best).tight)
        tight_prim.append(judge(solve_model(model, model.primary()), best).tight)
    return float(np.mean(tight_disc)), float(np.mean(tight_prim))


def assert_tight_with_discovered(prob, res) -> None:
    """Rank d (log SVR > 5) and the cost of the local solver started at the ground truth (rel. 1e-5)."""
    assert res.tight and res.constraints
    out = solve_model(res.model, res.model.primary() + res.constraints)
    assert out.log_svr > 5
    f_truth = prob.local_solve(res.instance, res.instance.truth).cost
    assert abs(out.primal_cost - f_truth) <= 1e-5 * abs(f_truth)


def assert_vanish_on_fresh_samples(prob, res) -> None:
    fresh = draw(prob, res.instance, 200, np.random.default_rng(2024), spread=0.5)
    assert relative_violation(res.constraints, fresh.thetas).max() < 1e-9


# ----------------------------------------------------------------------------- d = 2, matrix lifting


def test_d2_matrix_primary_is_a_reflection(slam, slam2_matrix):
    """Primary alone: rank 2 but not tight, because the rank-2 solution has det C_k = −1 for some k."""
    res = slam2_matrix
    v = judge(solve_model(res.model, res.model.primary()), res.example.local.best.cost)
    assert not v.tight and v.rank_tight
    Theta = solve_model(res.model, res.model.primary()).Theta
    assert slam.recover(res.instance, Theta)["det_raw"].min() < -0.99


def test_d2_matrix_discovered_set_is_tight(slam, slam2_matrix):
    assert_tight_with_discovered(slam, slam2_matrix)
    assert all(t == "relative_pose" for t, _ in slam2_matrix.discovered.pairs)


def test_d2_matrix_discovered_constraints_vanish_on_fresh_samples(slam, slam2_matrix):
    assert_vanish_on_fresh_samples(slam, slam2_matrix)


def test_d2_matrix_discovered_set_on_heldout_instances(slam, slam2_matrix):
    disc, prim = heldout_fractions(slam, slam2_matrix)
    print(f"\nlandmark SLAM d=2 matrix σ=1: held-out tight fraction {disc:.0%} (primary alone {prim:.0%})")
    assert disc >= 0.8 and disc >= prim


# ----------------------------------------------------------------------------- d = 3: matrix vs vector


def test_d3_matrix_not_tightenable(slam):
    """The same instance the vector lifting tightens: nothing learned on the matrix lifting cuts it, so discovery
    sets it aside (and trains on fresh instances); no learned pair enters the set."""
    res = _discover(3, "matrix", 4)
    p = res.points[0]
    assert res.log[0]["stage"] == "primary" and res.log[0]["outcome"] != "tight"
    assert p.train_seeds[0] == 4 and not p.reached[0] and p.origins[1:] == ["replacement"] * (len(p.origins) - 1)
    assert "no remaining candidate cuts its SDP solution" in p.messages[0]
    assert res.discovered.pairs == []


def test_d3_vector_discovered_set_is_tight(slam, slam3_vector):
    assert slam3_vector.log[0]["stage"] == "primary" and slam3_vector.log[0]["outcome"] != "tight"
    assert_tight_with_discovered(slam, slam3_vector)
    assert all(t == "pose" for t, _ in slam3_vector.discovered.pairs)


def test_d3_vector_discovered_constraints_vanish_on_fresh_samples(slam, slam3_vector):
    assert_vanish_on_fresh_samples(slam, slam3_vector)


def test_d3_vector_discovered_set_on_heldout_instances(slam, slam3_vector):
    disc, prim = heldout_fractions(slam, slam3_vector)
    print(f"\nlandmark SLAM d=3 vector σ=1: held-out tight fraction {disc:.0%} (primary alone {prim:.0%})")
    assert disc >= 0.5 and disc >= prim


# ----------------------------------------------------------------------------- d = 3 matrix learning


@pytest.mark.parametrize("group", ["pose_1", "odometry_0", "landmark_0"])
def test_d3_matrix_learned_constraints_hold_on_fresh_samples(slam, group):
    """Every relation learned on a factor of the matrix lifting (spanned or not) is exact on fresh samples."""
    inst = slam.generate({"dim": 3, "lifting": "matrix", "sigma": 0.1}, 3)
    model = slam.build(inst)
    cat = learn(slam, inst, model, np.random.default_rng(11))
    cons = cat.basic(group)
    if group.startswith("pose"):
        assert len(cons) >= 6  # at least C_kᵀC_k = I (6 equations)
    assert cons
    fresh = draw(slam, inst, 200, np.random.default_rng(12), spread=1.0)
    assert relative_violation(cons, fresh.thetas).max() < 1e-9
