"""Discovery over a range (autotight.discovery.range): tight on every training instance, irreducible over
the range, saved with its range, and passing `check` at every point it was learned for."""

from __future__ import annotations

import json

import pytest

import autotight as at
from autotight.check import instance_seed
from autotight.cli import main
from autotight.constraint_set import ConstraintSet
from autotight.discovery.range import RangeDiscoveryResult, Trainer, _reduce, _Run, discover_range, training_seed
from autotight.errors import ParameterError
from autotight.pipeline import solve_instance
from autotight.tightness import Criteria


class _Needs(_Run):
    """A fake oracle: trainer s is tight with a set iff the set contains one of needs[s] (monotone)."""

    def __init__(self, needs: dict[int, list[set[str]]]):
        super().__init__(None, None, Criteria())  # type: ignore[arg-type]
        self.needs = needs
        self.calls: list[tuple[int, frozenset]] = []

    def solve(self, tr, chosen, stage):
        key = frozenset(chosen)
        self.calls.append((tr.seed, key))
        self.n_solves += 1
        tight = any(n <= key for n in self.needs[tr.seed])
        (tr.tight_sets if tight else tr.loose_sets).append(key)
        return tight


def _trainer(seed: int) -> Trainer:
    return Trainer(0, seed, None, None, None, {})  # type: ignore[arg-type]


def test_reduction_is_irreducible_over_all_trainers_and_never_solves_a_set_twice():
    needs = {1: [{"a", "b"}, {"c"}], 2: [{"b"}], 3: [{"d", "e"}, {"a", "b"}]}
    run = _Needs(needs)
    trainers = [_trainer(s) for s in needs]
    for tr in trainers:  # the greedy's final tight result on each trainer
        tr.tight_sets.append(frozenset("abcdef"))
    pairs, dropped = _reduce(run, trainers, list("abcdef"), lambda *a: None)
    final = set(pairs)
    assert all(any(n <= final for n in needs[s]) for s in needs)  # tight on every trainer
    for p in final:  # removing any pair breaks tightness on at least one trainer
        assert any(not any(n <= final - {p} for n in needs[s]) for s in needs)
    assert "f" not in final and dropped == []  # f is needed nowhere
    assert len(run.calls) == len(set(run.calls))  # the cache never re-solves a set on a trainer
    assert run.n_solves < 2 ** 6


def test_reduction_removes_on_the_hardest_instance_and_widens_only_where_the_result_breaks():
    """Twelve instances, 48 pairs: ten need only "a", the hardest needs "a" and "b", one needs "c" as well.
    A removal is solved on the probe (the hardest, then the one that broke), not on all twelve."""
    pairs = [f"p{i}" for i in range(45)] + ["a", "b", "c"]
    needs = {s: [{"a"}] for s in range(10)} | {10: [{"a", "b"}], 11: [{"a", "c"}]}
    run = _Needs(needs)
    trainers = [_trainer(s) for s in needs]
    for tr in trainers:
        tr.tight_sets.append(frozenset(pairs))
    trainers[10].loose_sets.append(frozenset(["a"]))  # the hardest: a set of one pair is known loose on it
    got, dropped = _reduce(run, trainers, pairs, lambda *a: None)
    assert set(got) == {"a", "b", "c"} and dropped == []
    assert run.calls[0][0] == 10  # the first removal is tried on the hardest instance
    # before: every successful removal was solved on all twelve instances (≥ 12 per success)
    assert run.n_solves <= 45


class _Blind(_Needs):
    """_Needs whose solves of a loose set return no usable X (a NumericalError)."""

    def solve(self, tr, chosen, stage):
        from types import SimpleNamespace

        tight = super().solve(tr, chosen, stage)
        tr.last = SimpleNamespace(sdp=SimpleNamespace(X=None, usable=tight, status="Solved" if tight else
                                                      "NumericalError"))
        return tight


def test_a_solve_without_usable_x_adds_every_candidate_and_the_reduction_prunes():
    """Discrete K = 20 at σ = 0.316 fails with the primary constraints (NumericalError): nothing ranks
    the candidates, so all are added, and the reduction keeps only what is needed."""
    from autotight.discovery.range import _tighten

    run = _Blind({1: [{"b", "d"}], 2: [{"z"}]})  # trainer 2 needs a pair that is not a candidate
    trainers = [_trainer(1), _trainer(2)]
    chosen = _tighten(run, trainers, list("abcde"), 1e-7, lambda *a: None)
    assert set(chosen) == set("abcde") and trainers[0].reached
    assert not trainers[1].reached and "NumericalError with every candidate added" in trainers[1].message
    pairs, _ = _reduce(run, [trainers[0]], chosen, lambda *a: None)
    assert set(pairs) == {"b", "d"}


def test_training_and_heldout_seeds_differ():
    train = {training_seed(0, i, t) for i in range(5) for t in range(2)}
    held = {instance_seed(0, i, t) for i in range(5) for t in range(10)}
    assert not train & held


def test_range_set_is_tight_irreducible_saved_and_passes_check(tmp_path, capsys):
    """Pose averaging M = 3 over σ ∈ {0.01, 0.316}: learn on one instance per σ, save, then `check` the file."""
    out = tmp_path / "range.json"
    assert main(["discover", "pose_averaging", "-p", "M=3", "--sigmas", "0.01,0.316", "--train", "1",
                 "--heldout", "2", "--json", "--out", str(out)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["tight"] and s["irreducible"] and s["n_pairs"] >= 1
    assert [p["reached"] for p in s["points"]] == [[True], [True]]
    assert [p["heldout_fraction"] for p in s["points"]] == [1.0, 1.0]
    assert s["n_solves"] == sum(s["solves_by_stage"].values())
    cs = ConstraintSet.load(out)
    assert cs.discovered.info["range"]["over"] == {"sigma": [0.01, 0.316]}
    assert len(cs) == s["n_pairs"]
    # the saved set passes `check` at every σ it was learned for (its recorded range is the default)
    assert main(["check", "pose_averaging", "-p", "M=3", "--set", str(out), "--instances", "3", "--seed", "5"]) == 0
    table = capsys.readouterr().out
    assert "sigma=0.01" in table and "sigma=0.316" in table and "PASSED" in table


def test_each_pair_is_needed_on_some_training_instance():
    """Irreducibility re-checked independently, through the pipeline, on the training instances."""
    prob = at.load_problem("pose_averaging")
    res = at.discover(prob, {"M": 3}, seed=1, over={"sigma": [0.1, 1.0]}, n_train=1, n_heldout=0)
    assert isinstance(res, RangeDiscoveryResult) and res.tight and res.pairs
    insts = [prob.generate({"M": 3, "sigma": sg}, training_seed(1, i, 0)) for i, sg in enumerate([0.1, 1.0])]
    sets = [ConstraintSet(type(res.discovered)(prob.name, {}, 1, pairs, res.discovered.learn_options))
            for pairs in [res.pairs] + [[q for q in res.pairs if q != p] for p in res.pairs]]

    def tight(cs, inst):
        return solve_instance(prob, inst, cs, n_random=2).outcome == "tight"

    assert all(tight(sets[0], inst) for inst in insts)
    for cs in sets[1:]:
        assert not all(tight(cs, inst) for inst in insts)


def test_a_range_no_candidate_can_tighten_is_reported_point_by_point():
    """Learning on the rotation blocks only: no candidate closes pose averaging's gap, at any σ."""
    res = discover_range("pose_averaging", {"M": 2}, {"sigma": [0.1]}, groups=[("c1", "c2", "c3")],
                         n_train=1, n_heldout=0)
    assert not res.tight and res.pairs == []
    assert res.points[0].reached == [False]
    assert res.points[0].messages[0].startswith("not tight with 0 pairs")
    assert "not reached at {'sigma': 0.1}" in res.table()


def test_bad_range_input():
    with pytest.raises(ParameterError, match="both"):
        discover_range("pose_averaging", {"M": 2}, {"M": [2, 3]})
    with pytest.raises(ParameterError, match="n_train"):
        discover_range("pose_averaging", None, {"sigma": [0.1]}, n_train=0)
    assert main(["discover", "pose_averaging", "--range", "sigma"]) == 2
    assert main(["discover", "pose_averaging", "-p", "M=2", "--train", "0"]) == 2


def test_validation_rounds_add_training_instances_the_set_is_then_tight_on():
    prob = at.load_problem("pose_averaging")
    res = discover_range(prob, {"M": 3}, {"sigma": [1.0]}, seed=0, n_train=1, n_validate=1, max_rounds=1,
                         n_heldout=0)
    assert len(res.validation) == 1 and res.validation[0]["new_instances"] == 1
    assert res.points[0].train_seeds == [training_seed(0, 0, 0), training_seed(0, 0, 1)]
    assert res.points[0].reached == [True, True]
    inst = prob.generate({"M": 3, "sigma": 1.0}, training_seed(0, 0, 1))
    assert solve_instance(prob, inst, res.constraint_set, n_random=2).outcome == "tight"
    assert res.solves_by_stage["validate"] == 1 and res.n_solves == sum(res.solves_by_stage.values())


def test_validate_params_need_validation_instances_and_a_fixed_parameter():
    with pytest.raises(ParameterError, match="n_validate"):
        discover_range("pose_averaging", {"M": 2}, {"sigma": [0.1]}, validate_params={"M": 4})
    with pytest.raises(ParameterError, match="validation"):
        discover_range("pose_averaging", {"M": 2}, {"M": [2, 3]}, n_validate=1, validate_params={"M": 4})
    with pytest.raises(ParameterError):
        discover_range("pose_averaging", {"M": 2}, {"sigma": [0.1]}, n_validate=1, validate_params={"Q": 4})


def test_learn_params_select_at_a_larger_size_what_was_learned_at_a_small_one(tmp_path):
    """Candidates learned once at K = 5 and carried by their templates to a K = 12 training instance: they
    hold there, the selected set is tight on it, and the saved set's templates are those of K = 5."""
    from autotight.discovery.discovered import DiscoveredSet
    from autotight.problem import load

    res = discover_range("discrete_trajectory", {"K": 12}, {}, 0, n_train=1, n_heldout=0, learn_params={"K": 5},
                         solver=at.SolverConfig(backend="ipm"))
    assert res.tight and res.pairs and res.learn_params == {"K": 5}
    assert len(res.candidates) >= 20  # every pair of the K = 5 instance, carried
    prob = load("discrete_trajectory")
    model, cons = res.example
    tr_inst = prob.generate(prob.parse_params({"K": 12}), training_seed(0, 0, 0))
    theta = prob.lift(tr_inst, tr_inst.truth).reshape(1, -1)
    X = theta.T @ theta
    assert len(cons) == 12 * sum(1 for t, _ in res.pairs if t == "pose_meas") + \
        11 * sum(1 for t, _ in res.pairs if t == "odometry") + 12 * sum(1 for t, _ in res.pairs if t == "so3")
    assert max(abs(c.value(X)) for c in cons) < 1e-9 * abs(X).max()
    path = tmp_path / "set.json"
    res.save(str(path))
    ds = DiscoveredSet.load(path)
    assert ds.params["K"] == 5 and ds.info["range"]["selected_at"]["K"] == 12
    assert set(ds.templates.templates) == {t for t, _ in res.pairs} and not ds.templates.fallback
    inst = prob.generate(prob.parse_params({"K": 12}), 7)  # another instance of the selection size
    out = solve_instance(prob, inst, ConstraintSet(ds), config=at.SolverConfig(backend="ipm"), n_random=0)
    assert out.tight, out.verdict.reason
    with pytest.raises(ParameterError, match="unknown parameter"):
        discover_range("discrete_trajectory", {"K": 12}, {}, 0, n_train=1, n_heldout=0, learn_params={"Q": 5})


def test_the_committed_set_learned_at_k5_and_selected_at_k20_is_tight_at_k100():
    """The discrete carry-over file (benchmarks/results/scale_set_discrete_learnK5.json: learned at
    K = 5, selected over σ on K = 20 instances): its templates are those of K = 5, every template is
    exact (no per-factor fallback), and on a fresh K = 100 instance (5× the selection size) it is tight,
    where the set selected at K = 5 alone is not (docs/performance.md, "Limits")."""
    from pathlib import Path

    from autotight.problem import load

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "results" / "scale_set_discrete_learnK5.json"
    cs = ConstraintSet.load(path)
    rec = json.loads(path.read_text(encoding="utf-8"))
    assert rec["params"]["K"] == 5 and rec["info"]["range"]["selected_at"]["K"] == 20
    assert rec["info"]["range"]["over"]["sigma"][-1] == 0.316 and not rec["fallback"]
    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": 100, "sigma": 0.1}), 11)
    out = solve_instance(prob, inst, cs, config=at.SolverConfig(backend="ipm"), n_random=0)
    assert out.verdict.outcome == "tight" and out.verdict.log_svr > 5, out.verdict.reason
