"""AutoTight's benchmark problems as modules: range-only, Wahba (PPR), robust Wahba (TLS), stereo 1-D/2-D/3-D,
monocular localisation.

Tolerances: primary constraints on fresh samples to 1e-10 *relative* (``samples.relative_violation``:
relative to Σ|A_ij||θ_i||θ_j| + |b|, so independent of the lifting's scale); counts of quadratic relations
from the spectrum of column-normalised monomial data with the discovery's own gap rule (≥ 6 decades).
The counts the peer prints (stereo-2D, N = 3: 35 and 191; range-only "quad" in 3-D: 6 known + 14 learned
per position; PPR: 20 + h²) are properties of the lifted variety, so a wrong lifting changes them.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from autotight.checks import check_problem
from autotight.discovery.samples import draw, relative_violation
from autotight.problem import load

CASES = [
    ("range_only", {"dim": 2, "n_positions": 2}),
    ("range_only", {"dim": 3, "n_positions": 2}),
    ("wahba", {"dim": 3}),
    ("wahba", {"dim": 2}),
    ("mono_localization", {}),
    ("stereo_1d", {}),
    ("stereo_2d", {"level": "no"}),
    ("stereo_2d", {"level": "urT"}),
    ("stereo_3d", {"level": "no"}),
    ("stereo_3d", {"level": "urT"}),
    ("robust_wahba", {"n_points": 3}),
    ("robust_wahba", {"dim": 2, "n_points": 3}),
]


def _id(case: tuple[str, dict]) -> str:
    return case[0] + "".join(f"-{k}={v}" for k, v in case[1].items())


def _benchmark():
    """benchmarks/peer_benchmark.py as a module (it holds ``relation_count`` and the report generator)."""
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "peer_benchmark.py"
    if "peer_benchmark" not in sys.modules:
        spec = importlib.util.spec_from_file_location("peer_benchmark", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules["peer_benchmark"] = mod  # dataclasses look their module up there
        spec.loader.exec_module(mod)
    return sys.modules["peer_benchmark"]


def relation_count(name: str, params: dict) -> int:
    return _benchmark().relation_count(name, params)


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_module_contract(case):
    name, params = case
    res = check_problem(name, params, seed=3)
    assert res.ok, res.lines()


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_fresh_samples_satisfy_primary_constraints(case):
    name, params = case
    prob = load(name)
    inst = prob.generate(params, 7)
    model = prob.build(inst)
    bank = draw(prob, inst, 30, np.random.default_rng(11), None)
    viol = relative_violation(model.primary(), bank.thetas)
    assert viol.max() <= 1e-10


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_local_solve_beats_perturbed_start(case):
    name, params = case
    prob = load(name)
    inst = prob.generate(params, 5)
    rng = np.random.default_rng(2)
    start = prob.sample(inst, rng, inst.truth, 0.1)
    res = prob.local_solve(inst, start)
    c0 = prob.cost(inst, start)
    assert res.cost < c0 * (1 - 1e-3)  # the start is far from stationary: a real decrease
    assert res.cost <= prob.cost(inst, inst.truth) * (1 + 1e-6)  # at least as good as the truth
    assert abs(prob.cost(inst, res.state) - res.cost) <= 1e-9 * max(1.0, res.cost)


@pytest.mark.parametrize("level, expected", [("no", 35), ("urT", 191)])
def test_stereo_2d_relation_counts_match_the_peer(level, expected):
    assert relation_count("stereo_2d", {"n_landmarks": 3, "level": level}) == expected


@pytest.mark.parametrize("dim, expected", [(2, 6), (3, 20)])
def test_range_only_relation_count_per_position(dim, expected):
    """One position: (1, p, vech ppᵀ) has monomials of degree ≤ 4 in p, C(d+4, 4) of them, among the
    svec of n = 1 + d + d(d+1)/2 columns: 21 − 15 = 6 (d = 2), 55 − 35 = 20 (d = 3; the peer: 6 + 14)."""
    assert relation_count("range_only", {"dim": dim, "n_positions": 1}) == expected


def test_wahba_relation_count_matches_the_peer():
    """[h, t, vec C], C ∈ SO(3): 20 relations, the peer's 21 learned less h² = 1."""
    assert relation_count("wahba", {"dim": 3}) == 20


def test_stereo_1d_relation_count():
    """N = 3: three substitutions x z_j = 1 + a_j z_j and three pair relations z_i − z_j = (a_i − a_j) z_i z_j."""
    assert relation_count("stereo_1d", {"n_landmarks": 3}) == 6


@pytest.mark.parametrize("name", ["stereo_2d", "stereo_3d"])
@pytest.mark.parametrize("level, factor_type", [("no", "stereo"), ("urT", "stereo_urT")])
def test_stereo_transport_checked(name, level, factor_type):
    """check-module carries one landmark's learned relations to another's by TRANSPORTS and compares them
    with those learned there (1e-8 relative): the change of variables is exact at both levels."""
    res = check_problem(name, {"level": level, "n_landmarks": 3}, seed=1)
    assert any(line.startswith(f"PASS transport: TRANSPORTS['{factor_type}']") for line in res.lines()), res.lines()


def test_stereo_1d_transports_checked():
    res = check_problem("stereo_1d", {"n_landmarks": 4}, seed=2)
    for t in ("stereo1d", "stereo1d_pair"):
        assert any(line.startswith(f"PASS transport: TRANSPORTS['{t}']") for line in res.lines()), res.lines()


def test_robust_wahba_local_solver_finds_the_outliers():
    prob = load("robust_wahba")
    inst = prob.generate({"n_points": 6, "n_outliers": 2, "sigma": 0.005}, 4)
    res = prob.local_solve(inst, prob.random_state(inst, np.random.default_rng(0)))
    assert np.array_equal(res.state["w"], inst.truth["w"])
    assert prob.errors(inst, res.state)["rotation_deg"] < 2.0


def test_benchmark_report_numbers_come_from_its_run(tmp_path):
    """The generator on one cheap problem: the report's held-out fraction is the one its own results.json
    records, computed from the per-instance verdicts (not a constant), and the peer's figure is cited."""
    bench = _benchmark()
    assert bench.main(["--out", str(tmp_path), "--only", "wahba", "--instances", "3", "--carry-instances", "1"]) == 0
    data = json.loads((tmp_path / "results.json").read_text())
    row = data["rows"][0]
    held = row["heldout"]
    assert len(held["instances"]) == 3
    assert held["rank_tight"] == sum(i["rank_tight"] for i in held["instances"]) / 3
    assert row["relations"]["[h, t, vec C]"]["count"] == 20
    report = (tmp_path / "report.md").read_text()
    assert f"| wahba | 3 | {100 * held['accepted']:.0f} %" in report
    assert "21 → 7" in report and "terminal_output.log" in report
    assert (tmp_path / row["set_file"]).exists()


def test_stereo_pair_relations_learned_at_n20_hold_far_from_their_samples():
    """The stereo-2D set learned at N = 3 (reports/peer_benchmark/sets/stereo_2d.json) applied at N = 20: its pair
    relations, learned there pair by pair (no template fits them), hold to 1e-9 relative at a feasible point far
    from the samples (the camera 5·10⁴ away, where a refined SDP estimate at N = 20 went), not only near them.
    Learning refits each relation on its own support, so the nullspace's roundoff leaves no terms that such a
    point magnifies (before, 2.4e-4 there: a violation that stopped ``solve``)."""
    from autotight.constraint_set import ConstraintSet, resolve
    from autotight.pipeline import seeds
    from autotight.validity import relative_violations

    p = load("stereo_2d")
    cs = ConstraintSet.load(Path(__file__).resolve().parents[1] / "reports/peer_benchmark/sets/stereo_2d.json")
    inst = p.generate({"n_landmarks": 20}, 0)
    model = p.build(inst)
    pair = [c for c in resolve(cs, p, inst, model, seeds(0).constraints()) if str(c.factor).startswith("pair_")]
    assert len({c.factor for c in pair}) == 190  # every landmark pair
    far = {"C": inst.truth["C"], "t": inst.truth["t"] + np.array([3821.0, 46810.0])}
    near = p.sample(inst, np.random.default_rng(1))
    worst = [float(np.max(relative_violations(pair, [p.lift(inst, s)]))) for s in (near, far)]
    assert worst[0] <= 1e-9 and worst[1] <= 1e-9, worst

