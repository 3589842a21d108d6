"""The discovery engine (autotight.discovery.engine): one flow for a point, a range and a carried set;
tight on every training instance, irreducible over them, validated on fresh held-out instances with every
failing one taken in, saved with its evidence, and passing `check` where it was validated."""

from __future__ import annotations

import dataclasses
import json
import textwrap
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import pytest

import autotight as at
from autotight.check import instance_seed
from autotight.cli import main
from autotight.constraint_set import ConstraintSet
from autotight.discovery.discovered import DiscoveredSet
from autotight.discovery.engine import default_groups, discover
from autotight.discovery.learn import LearnOptions
from autotight.discovery.result import DiscoveryResult
from autotight.discovery.select import reduce as _reduce
from autotight.discovery.trainers import (Solves, Trainer, heldout_seed, make_trainer, training_seed,
                                         valid_pairs)
from autotight.errors import ParameterError
from autotight.pipeline import feasible_points, seeds, solve_instance
from autotight.problem import load as load_problem
from autotight.tightness import Criteria
from autotight.validity import VALID_RTOL, InvalidConstraintError, relative_violations


class _Needs(Solves):
    """A fake solver: trainer s is tight with a set iff the set contains one of needs[s] (monotone)."""

    def __init__(self, needs: dict[int, list[set[str]]]):
        super().__init__(None, None, Criteria())  # type: ignore[arg-type]
        self.needs = needs
        self.calls: list[tuple[int, frozenset]] = []

    def solve(self, tr, chosen, stage, with_ray=True):
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


class _GapOpen(_Needs):
    """_Needs whose loose verdicts all come with the cost gap open (``Trainer.gap_open_sets``)."""

    def solve(self, tr, chosen, stage, with_ray=True):
        tight = super().solve(tr, chosen, stage)
        if not tight:
            tr.gap_open_sets.append(frozenset(chosen))
        return tight


def test_an_open_cost_gap_proves_the_removals_of_the_irreducibility_check_without_a_solve():
    """The same irreducible set as with exact checks, in fewer solves: a pair found necessary while the set was
    larger stays necessary (the smaller set lies inside one whose gap was open), so no set is solved twice and
    no removal of the final set is solved again where a larger one already failed."""
    needs = {1: [{"a", "b"}, {"c"}], 2: [{"b"}], 3: [{"d", "e"}, {"a", "b"}]}
    pairs = list("abcdefgh")
    results = {}
    for cls in (_Needs, _GapOpen):
        run = cls(needs)
        trainers = [_trainer(s) for s in needs]
        for tr in trainers:
            tr.tight_sets.append(frozenset(pairs))
        got, dropped = _reduce(run, trainers, pairs, lambda *a: None)
        results[cls.__name__] = (set(got), run.n_solves, sum(1 for _, k in run.calls if len(k) == len(got) - 1))
    (exact_set, exact_n, exact_verify), (gap_set, gap_n, gap_verify) = results["_Needs"], results["_GapOpen"]
    assert gap_set == exact_set
    for p_ in gap_set:  # still irreducible
        assert any(not any(n <= gap_set - {p_} for n in needs[s]) for s in needs)
    assert gap_n < exact_n and gap_verify < exact_verify


def test_an_open_gap_on_a_real_instance_holds_for_every_subset_and_a_better_point_voids_it():
    """Pose averaging (M = 5, σ = 0.5): the primary constraints with two learned pairs leave the cost gap open;
    the set with one of them, inside it, is then known not tight without a solve, and its solve agrees: an
    open gap, at an SDP optimum no higher (to the two solves' accuracy)."""
    prob = load_problem("pose_averaging")
    tr = make_trainer(prob, prob.parse_params({"M": 5, "sigma": 0.5}), 0, 0, default_groups(prob, None),
                      LearnOptions(), 1)
    run = Solves(prob, None, Criteria())
    larger = list(tr.pairs)[:2]
    assert not run.solve(tr, larger, "reduce")
    big = tr.last.verdict
    assert big.cost_outcome == "not tight" and tr.gap_open_sets == [frozenset(larger)]
    assert tr.known(frozenset(larger[:1]), exact=True) is False  # no solve needed
    assert not run.solve(tr, larger[:1], "reduce")  # solved anyway: the inference against the solve
    small = tr.last.verdict
    assert small.cost_outcome == "not tight"
    assert small.primal <= big.primal + big.accuracy + small.accuracy
    tr.gap_open_sets.clear()  # as ``Solves.solve`` does when the SDP's estimate refines to a lower cost
    tr.loose_sets.clear()
    assert tr.known(frozenset(larger[:1]), exact=True) is None


def test_a_candidate_off_at_a_local_solution_is_left_out_of_the_instance_s_pairs():
    """A pair with one constraint that does not hold at the instance's local solutions (its b shifted by 1e-4 of
    its scale, as an inexact template might be) is not a candidate there: its solves would fail the check
    before every verdict.  The other pairs stay, every one holding at the points to the tool's tolerance."""
    prob = load_problem("pose_averaging")
    tr = make_trainer(prob, prob.parse_params({"M": 5}), 0, 0, default_groups(prob, None), LearnOptions(), 1)
    points = feasible_points(prob, tr.inst, tr.local, seeds(0).validity())
    cons = [c for cs in tr.pairs.values() for c in cs]
    assert np.max(relative_violations(cons, list(points.values()))) <= VALID_RTOL
    bad = next(iter(tr.pairs))
    off = dict(tr.pairs)
    c0 = off[bad][0]
    scale = float(np.abs(c0.A.data).sum()) + abs(c0.b)
    off[bad] = [dataclasses.replace(c0, b=c0.b + 1e-4 * scale)] + off[bad][1:]
    kept = valid_pairs(off, points)
    assert set(kept) == set(tr.pairs) - {bad}


class _Scored(_Needs):
    """_Needs that leaves an SDP solution whose violation by a pair is 1 for the pairs of needs[s], else 0.1."""

    def solve(self, tr, chosen, stage, with_ray=True):
        from types import SimpleNamespace

        tight = super().solve(tr, chosen, stage)
        tr.last = SimpleNamespace(sdp=SimpleNamespace(X=tr.seed, usable=True, status="Solved"))
        return tight


class _ScoredTrainer(Trainer):
    def violations(self, X, pairs):
        return {p: 1.0 if any(p in n for n in _Scored.current.needs[X]) else 0.1 for p in pairs}


def test_instances_taken_in_together_are_tightened_one_at_a_time(monkeypatch):
    """Five held-out failures that all need pair "b": the first is tightened (2 solves), the other four are
    tight with its result (1 solve each); tightening them together solves each of the five twice."""
    import autotight.discovery.select as select

    monkeypatch.setattr(select, "unbounded_blocks", lambda model, res: [])
    needs = {s: [{"b"}] for s in range(1, 6)}
    counts = {}
    for fn in (select.tighten_each, select.tighten):
        run = _Scored(needs)
        _Scored.current = run
        trainers = [_ScoredTrainer(0, s, None, None, None, {}) for s in needs]  # type: ignore[arg-type]
        chosen = fn(run, trainers, list("abcde"), lambda *a: None, ["a"], "validate")
        assert "b" in chosen and all(any(n <= set(chosen) for n in needs[s]) for s in needs)
        counts[fn.__name__] = run.n_solves
    assert counts == {"tighten_each": 6, "tighten": 10}


class _Blind(_Needs):
    """_Needs whose solves of a loose set return no usable X (a NumericalError)."""

    def solve(self, tr, chosen, stage, with_ray=True):
        from types import SimpleNamespace

        tight = super().solve(tr, chosen, stage)
        tr.last = SimpleNamespace(sdp=SimpleNamespace(X=None, usable=tight, status="Solved" if tight else
                                                      "NumericalError"))
        return tight


def test_a_solve_without_usable_x_adds_every_candidate_and_the_reduction_prunes():
    """Discrete K = 20 at σ = 0.316 fails with the primary constraints (NumericalError): nothing ranks
    the candidates, so all are added, and the reduction keeps only what is needed."""
    from autotight.discovery.select import tighten

    run = _Blind({1: [{"b", "d"}], 2: [{"z"}]})  # trainer 2 needs a pair that is not a candidate
    trainers = [_trainer(1), _trainer(2)]
    chosen = tighten(run, trainers, list("abcde"), lambda *a: None)
    assert set(chosen) == set("abcde") and trainers[0].reached
    assert not trainers[1].reached and "NumericalError with every candidate added" in trainers[1].message
    pairs, _ = _reduce(run, [trainers[0]], chosen, lambda *a: None)
    assert set(pairs) == {"b", "d"}


def test_training_heldout_and_check_seeds_differ():
    train = {training_seed(0, i, t) for i in range(5) for t in range(2)}
    held = {heldout_seed(0, i, t) for i in range(5) for t in range(50)}
    check = {instance_seed(0, i, t) for i in range(5) for t in range(10)}
    assert not train & held and not train & check and not held & check


def test_range_set_is_tight_irreducible_saved_with_evidence_and_passes_check(tmp_path, capsys):
    """Pose averaging M = 3 over σ ∈ {0.01, 0.316}: one training instance per σ, save, then `check` the file."""
    out = tmp_path / "range.json"
    assert main(["discover", "pose_averaging", "-p", "M=3", "--sigmas", "0.01,0.316", "--heldout", "3",
                 "--json", "--out", str(out)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["tight"] and s["irreducible"] and s["validated"] is True and s["n_pairs"] >= 1
    assert all(all(p["reached"]) for p in s["points"])
    last = s["validation"]["rounds"][-1]
    assert last["passed"] and all(p["instances"] == 3 for p in last["points"])
    for p in s["points"]:
        ev = p["heldout"]
        assert ev["instances"] == 3 and ev["tight"] + ev["undecided"] + ev["not_tight"] == 3
        assert ev["not_tight"] == len(ev["failing_seeds"]) and ev["passed"]
    assert s["n_solves"] == sum(s["solves_by_stage"].values())
    cs = ConstraintSet.load(out)
    assert cs.discovered.info["range"]["over"] == {"sigma": [0.01, 0.316]}
    assert cs.discovered.info["validation"]["passed"] is True
    assert len(cs) == s["n_pairs"]
    # the saved set passes `check` at every σ it was learned for (its recorded range is the default)
    assert main(["check", "pose_averaging", "-p", "M=3", "--set", str(out), "--instances", "3", "--seed", "5"]) == 0
    table = capsys.readouterr().out
    assert "sigma=0.01" in table and "sigma=0.316" in table and "PASSED" in table


@pytest.mark.slow  # ~25 s; irreducibility over the trainers: test_reduction_is_irreducible_* above
def test_each_pair_is_needed_on_some_training_instance():
    """Irreducibility re-checked independently, through the pipeline, on the training instances."""
    prob = at.load_problem("pose_averaging")
    res = at.discover(prob, {"M": 3}, seed=1, over={"sigma": [0.1, 1.0]}, n_heldout=0)
    assert isinstance(res, DiscoveryResult) and res.tight and res.pairs and res.validated is None
    insts = [prob.generate({"M": 3, "sigma": sg}, training_seed(1, i, 0)) for i, sg in enumerate([0.1, 1.0])]
    sets = [ConstraintSet(type(res.discovered)(prob.name, {}, 1, pairs, res.discovered.learn_options))
            for pairs in [res.pairs] + [[q for q in res.pairs if q != p] for p in res.pairs]]

    def tight(cs, inst):
        return solve_instance(prob, inst, cs, n_random=2).outcome == "tight"

    assert all(tight(sets[0], inst) for inst in insts)
    for cs in sets[1:]:
        assert not all(tight(cs, inst) for inst in insts)


def test_a_range_no_candidate_can_tighten_is_reported_point_by_point():
    """Learning on the rotation blocks only: no candidate closes pose averaging's gap, on the training instance nor
    on the fresh ones drawn in its place; nothing is validated."""
    from autotight.discovery.engine import MAX_SET_ASIDE

    res = discover("pose_averaging", {"M": 2}, over={"sigma": [0.1]}, groups=[("c1", "c2", "c3")])
    assert not res.tight and res.pairs == [] and res.validated is None
    assert res.points[0].reached == [False] * (1 + MAX_SET_ASIDE)
    assert res.points[0].messages[0].startswith("not tight with 0 pairs")
    assert "not reached at sigma=0.1" in res.table()


def test_bad_input():
    with pytest.raises(ParameterError, match="both"):
        discover("pose_averaging", {"M": 2}, over={"M": [2, 3]})
    with pytest.raises(ParameterError, match="n_train"):
        discover("pose_averaging", None, over={"sigma": [0.1]}, n_train=0)
    with pytest.raises(ParameterError, match="min_fraction"):
        discover("pose_averaging", None, min_fraction=1.5)
    with pytest.raises(ParameterError, match="unknown parameter"):
        discover("discrete_trajectory", {"K": 5}, carry_to={"Q": 5})
    assert main(["discover", "pose_averaging", "--range", "sigma"]) == 2
    with pytest.raises(SystemExit) as e:  # argparse's own refusal of the option's type
        main(["discover", "pose_averaging", "-p", "M=2", "--train", "0"])
    assert e.value.code == 2


def test_failing_heldout_instances_become_training_instances_the_set_is_then_tight_on():
    """σ = 1, every held-out instance must pass: the first rounds fail, their failing instances are taken in,
    and the final set is tight on each of them (and on every training instance)."""
    prob = at.load_problem("pose_averaging")
    res = discover(prob, {"M": 3, "sigma": 1.0}, 0, n_heldout=6, min_fraction=1.0, max_rounds=3, compare=False)
    rounds = res.validation["rounds"]
    failing = [s for r in rounds if r["taken_in"] for p in r["points"] for s in p["failing_seeds"]]
    taken = [tr.seed for tr in res.trainers if tr.origin == "held-out"]
    assert failing and taken == failing  # every failing held-out instance of a round that takes them in
    # every round with a failing instance but the last takes it in (a clean round asks for a confirming one)
    assert all(r["taken_in"] for r in rounds[:-1] if any(p["failing_seeds"] for p in r["points"]))
    assert sum(r["taken_in"] for r in rounds) == len(taken)
    seen = [s for r in rounds for s in [heldout_seed(0, 0, 6 * (r["round"] - 1) + t) for t in range(6)]]
    assert len(seen) == len(set(seen))  # every round is a fresh batch
    for tr in res.trainers:
        assert tr.reached and solve_instance(prob, tr.inst, res.constraint_set, n_random=2).outcome == "tight"
    if res.validated:
        assert rounds[-1]["passed"] and res.points[0].heldout.passed
    else:
        assert len(rounds) == 3 and "FAILED" in res.validation["message"]


def test_a_heldout_instance_taken_in_keeps_the_constraints_its_check_solved():
    """The trainer made of a failing held-out instance holds, for the set's own pairs, exactly the constraints the
    held-out check instantiated (``DiscoveredSet.apply`` with the instance's constraint generator), not a re-learned
    copy; its other candidates are learned on it."""
    from autotight.evaluate import instantiate

    prob = at.load_problem("stereo_3d")  # its landmark-pair relations are re-learned per factor by ``apply``
    cs = ConstraintSet.load(Path(__file__).parents[1] / "reports" / "peer_benchmark" / "sets" / "stereo_3d.json")
    params = prob.parse_params(dict(cs.discovered.params))
    seed = heldout_seed(0, 0, 3)
    checked = instantiate(prob, prob.generate(params, seed), prob.build(prob.generate(params, seed)), cs,
                          seeds(seed).constraints())
    plain = make_trainer(prob, params, 0, seed, "factors", LearnOptions(), 1, origin="held-out")
    taken = make_trainer(prob, params, 0, seed, "factors", LearnOptions(), 1, origin="held-out", given=cs.discovered)
    own = {(p["factor_type"], p["identity"]) if isinstance(p, dict) else tuple(p) for p in cs.discovered.pairs}
    got = [c for pair in taken.pairs if pair in own for c in taken.pairs[pair]]
    assert len(got) == len(checked) > 0
    key = {c.name: c for c in checked}
    assert all((abs(c.A - key[c.name].A)).max() == 0 for c in got)  # the very constraints check solved
    relearned = [c for pair in plain.pairs if pair in own for c in plain.pairs[pair]]
    assert len(relearned) == len(got)
    assert max(float(abs(c.A - key[c.name].A).max()) if c.name in key else 1.0 for c in relearned) > 0  # not a copy
    assert set(plain.pairs) - own and set(plain.pairs) - own == set(taken.pairs) - own  # the rest: learned
    assert np.isclose(plain.local.best.cost, taken.local.best.cost)


def test_the_confirmation_bounds_the_chance_that_a_set_at_the_threshold_passes_it():
    """A set tight on each instance with probability just min_fraction passes confirm_count clean instances with
    probability ≤ CONFIRM_RISK, while one batch fewer would let it through more often (above the two-batch
    minimum); at 0.9 with batches of 10 that is 30 instances: 0.9²⁰ = 0.12 let a 90 % set through."""
    from autotight.discovery.engine import CONFIRM_RISK, MIN_CONFIRM_BATCHES, confirm_count

    assert confirm_count(0.9, 10) == 30 and 0.9 ** 20 > 0.1
    for f in (0.5, 0.8, 0.9, 0.93, 0.95):
        for n in (1, 4, 10):
            need = confirm_count(f, n)
            assert need % n == 0 and need >= MIN_CONFIRM_BATCHES * n and f ** need <= CONFIRM_RISK
            assert need == MIN_CONFIRM_BATCHES * n or f ** (need - n) > CONFIRM_RISK
    assert confirm_count(1.0, 10) == confirm_count(0.0, 10) == MIN_CONFIRM_BATCHES * 10


def test_a_clean_first_batch_is_confirmed_by_more_fresh_ones():
    """Pose averaging M = 3 (tight on every instance at σ = 0.1): the first fresh batch of 4 has no failing
    instance, yet the point holds 4 < confirm_count tight held-out instances, so fresh batches follow until it
    holds them; with one round allowed the set is validated with a message that says the confirmation is short."""
    from autotight.discovery.engine import confirm_count

    prob = at.load_problem("pose_averaging")
    need = confirm_count(0.5, 4)
    res = discover(prob, {"M": 3}, 0, n_heldout=4, min_fraction=0.5, compare=False)
    rounds = res.validation["rounds"]
    assert res.validated and len(rounds) == need // 4 > 1 and res.validation["confirm"] == need
    assert [r["tight_since_last_failure"][0] for r in rounds] == [4 * (k + 1) for k in range(need // 4)]
    seen = [heldout_seed(0, 0, t) for t in range(4 * len(rounds))]
    assert len(set(seen)) == len(seen) and f"at least {need} decided" in res.validation["message"]
    short = discover(prob, {"M": 3}, 0, n_heldout=4, max_rounds=1, compare=False)
    assert short.validated and len(short.validation["rounds"]) == 1
    assert f"short of the {confirm_count(0.9, 4)}" in short.validation["message"]


def test_a_spent_budget_exits_1_records_the_failure_and_solve_warns(tmp_path, capsys):
    """One round at σ = 1 where every held-out instance must pass: validation fails; the set is still saved,
    records it, and `solve --set` warns."""
    out = tmp_path / "set.json"
    code = main(["discover", "pose_averaging", "-p", "M=3", "-p", "sigma=1", "--heldout", "6", "--min-fraction", "1",
                 "--max-rounds", "1", "--out", str(out), "--no-progress"])
    cap = capsys.readouterr()
    assert code == 1 and cap.err.count("\n") == 1 and "validation FAILED" in cap.err
    assert "the held-out evidence covers the points above only" in cap.out
    rec = json.loads(out.read_text(encoding="utf-8"))
    assert rec["info"]["validation"]["passed"] is False and rec["summary"]["validated"] is False
    assert main(["solve", "pose_averaging", "-p", "M=3", "--set", str(out)]) in (0, 1)
    assert "failed validation" in capsys.readouterr().err


def test_a_set_used_outside_its_validated_points_is_noted(capsys):
    """The committed pose-averaging set (M = 10, validated at σ = 0.1 only): `check` over σ = 0.1 and 1 notes σ = 1
    (once, on stderr) and not 0.1; at another M the note names M; at its own parameters there is none."""
    path = str(Path(__file__).resolve().parents[1] / "reports" / "pose_averaging" / "discovered.json")
    ds = ConstraintSet.load(path).discovered
    here = load_problem("pose_averaging").parse_params({"M": 10})
    assert ds.validated_points() == [here] and ds.scope_note([here]) == ""
    assert "not at M = 4, sigma = 0.5" in ds.scope_note([here | {"M": 4, "sigma": 0.5}])
    main(["check", "pose_averaging", "--set", path, "--sigmas", "0.1,1", "--instances", "1"])
    err = capsys.readouterr().err
    assert err.count("note:") == 1 and "not at sigma = 1.0:" in err and "not at sigma = 0.1" not in err
    # a range set: every point it was validated at counts, an instance without held-out solves does not
    points = [{"varied": {"sigma": 0.01}, "instances": 10}, {"varied": {"sigma": 1.0}, "instances": 10},
              {"varied": {"sigma": 0.1}, "instances": 0}]
    rng = DiscoveredSet("pose_averaging", here, 0, [], info={"validation": {"rounds": [{"points": points}]}})
    assert rng.scope_note([here | {"sigma": 0.01}, here | {"sigma": 1.0 + 1e-12}]) == ""
    note = rng.scope_note([here | {"sigma": 0.01}, here | {"sigma": 0.1}])
    assert "ran at sigma = 0.01; sigma = 1.0 only, not at sigma = 0.1:" in note


def test_a_held_out_instance_that_rejects_the_set_fails_validation_plainly_and_keeps_the_set(tmp_path, capsys,
                                                                                               monkeypatch):
    """A held-out instance whose validity check rejects the set (an inexact template where it was carried) ends
    the loop: exit 1, one line naming the constraint, and the set saved with validation failed."""
    import autotight.discovery.engine as engine

    solve_batch = engine.solve_batch

    def reject(prob, sets, *a, **k):
        if "set" not in sets:  # the paper's families, on the (empty) batches kept
            return solve_batch(prob, sets, *a, **k)
        raise InvalidConstraintError("pose_averaging: constraint 'x' (learned, factor m0) does not hold at the "
                                     "local solution from random start 0 (relative violation 2e-06 > 1e-06)")

    monkeypatch.setattr(engine, "solve_batch", reject)
    out = tmp_path / "set.json"
    code = main(["discover", "pose_averaging", "-p", "M=3", "--out", str(out), "--no-progress"])
    cap = capsys.readouterr()
    assert code == 1 and cap.err.count("\n") == 1
    assert "validation FAILED" in cap.err and "rejects the set" in cap.err and "'x'" in cap.err
    rec = json.loads(out.read_text(encoding="utf-8"))
    assert rec["info"]["validation"]["passed"] is False and rec["pairs"]


def test_a_set_not_tight_on_its_training_exits_1_with_the_reason_and_its_closed_forms(tmp_path, capsys):
    """Stereo 1-D under the default --accept rank: rank 1 is out of reach (X_xx is free), so nothing is tight on
    the training instance.  The table says to use --accept cost, the set is saved and its closed form printed
    (a factor type without primary relations of its own), and the exit code is 1 with one line on stderr."""
    out = tmp_path / "set.json"
    code = main(["discover", "stereo_1d", "--out", str(out), "--no-progress"])
    cap = capsys.readouterr()
    assert code == 1 and cap.err.count("\n") == 1 and "not tight on every training instance" in cap.err
    assert "use --accept cost" in cap.out and "closed forms" in cap.out
    rec = json.loads(out.read_text(encoding="utf-8"))
    assert rec["summary"]["tight"] is False and rec["summary"]["validated"] is None
    # every instance shares the reason (X_xx is bounded by nothing): no replacement is drawn
    assert len(rec["summary"]["points"][0]["train_seeds"]) == 1


BINARY = str(Path(__file__).parent / "binary_quadratic_module.py")


def _loose_seed(params: dict) -> tuple[int, float]:
    """The first seed whose ±1 program (no quadratic relation but s_i² = h² holds on {±1}ⁿ) has a relaxation
    below its optimum by more than 1e-3 relative, and that gap."""
    for s in range(40):
        r = at.solve(BINARY, params, s, constraints="primary")
        if r.verdict.rel_gap > 1e-3:
            return s, r.verdict.rel_gap
    raise AssertionError("no loose instance in 40 seeds")


def test_a_training_instance_no_candidate_makes_tight_is_set_aside_and_replaced():
    """A ±1 quadratic program has no valid relation beyond s_i² = h², so an instance whose relaxation is loose stays
    loose with every candidate.  Trained on such a seed, discovery sets it aside, draws a fresh instance in its
    place and learns there: the set is tight on the replacement and the message names the seed set aside."""
    s0, gap = _loose_seed({})
    res = discover(BINARY, {}, s0, n_heldout=10, min_fraction=0.5, max_rounds=1, compare=False)
    p = res.points[0]
    assert gap > 1e-3 and p.train_seeds[0] == s0 and not p.reached[0] and p.origins[0] == "training"
    assert "no remaining candidate cuts its SDP solution" in p.messages[0]
    assert p.origins[1] == "replacement" and p.train_seeds[1] == training_seed(s0, 0, 1) and res.tight
    first = next(tr for tr in res.trainers if tr.reached)
    assert first.origin == "replacement"
    assert solve_instance(at.load_problem(BINARY), first.inst, res.constraint_set).outcome == "tight"
    assert f"training seed(s) {s0} set aside" in res.validation["message"]
    assert f"set aside at params (training seed {s0}): not tight with 0 pairs" in res.table()


def test_failing_instances_no_candidate_makes_tight_count_against_the_fraction_without_restarting_it():
    """±1 programs, loose on about a third of the instances whatever the set: at min_fraction 0.5 each batch's
    loose instances are taken in, none is reached, the set stays as it was, and the point is confirmed after
    confirm_count batches instead of restarting its count at every failure."""
    from autotight.discovery.engine import confirm_count

    s0 = next(s for s in range(40) if at.solve(BINARY, {}, s, constraints="primary").verdict.rel_gap < 1e-6)
    res = discover(BINARY, {}, s0, n_heldout=10, min_fraction=0.5, compare=False)
    rounds = res.validation["rounds"]
    taken = [tr for tr in res.trainers if tr.origin == "held-out"]
    assert res.validated and len(rounds) == confirm_count(0.5, 10) // 10 and res.pairs == []
    assert taken and not any(tr.reached for tr in taken)
    loose = rounds[-1]["loose_since_last_failure"][0]
    assert loose == len(taken) == sum(p["not_tight"] for r in rounds for p in r["points"])
    assert rounds[-1]["tight_since_last_failure"][0] + loose == sum(p["tight"] + p["not_tight"]
                                                                    for r in rounds for p in r["points"])
    assert f"{loose} of them not tight with any candidate" in res.validation["message"]


def test_training_instances_all_loose_end_after_the_replacements_budget():
    """Frustrated ±1 programs (every coupling large and positive: no sign pattern of three spins satisfies
    all three) are loose on every instance: discovery draws 1 + MAX_SET_ASIDE training instances, then stops."""
    from autotight.discovery.engine import MAX_SET_ASIDE

    res = discover(BINARY, {"frustration": 5.0}, 0, n_heldout=10, compare=False)
    p = res.points[0]
    assert not res.tight and res.validated is None and not any(p.reached)
    assert len(p.train_seeds) == 1 + MAX_SET_ASIDE and p.origins[1:] == ["replacement"] * MAX_SET_ASIDE
    assert "not tight on every training instance" in res.validation["message"]
    assert res.validation["rounds"] == []


MODULE = textwrap.dedent("""
    from problems.pose_averaging import *  # noqa: F401,F403
    NAME = "my_pose"
""")


def test_a_problem_module_given_by_path_is_discovered_saved_and_solved(tmp_path, capsys, monkeypatch):
    path = tmp_path / "my_pose.py"
    path.write_text(MODULE, encoding="utf-8")
    out = tmp_path / "set.json"
    monkeypatch.chdir(tmp_path)
    assert main(["discover", str(path), "-p", "M=3", "--heldout", "2", "--out", str(out), "--no-progress"]) == 0
    assert "saved to" in capsys.readouterr().out
    rec = json.loads(out.read_text(encoding="utf-8"))
    assert rec["problem"] == "my_pose" and rec["templates"] is not None
    assert main(["solve", str(path), "-p", "M=4", "--seed", "3", "--set", str(out), "--json"]) == 0
    obj = json.loads(capsys.readouterr().out)
    assert obj["tight"] and obj["n_constraints"] > 0


def test_a_failed_write_at_the_end_keeps_the_set_next_to_the_current_folder(tmp_path, capsys, monkeypatch):
    from autotight.cli import discover as dcli

    res = discover("pose_averaging", {"M": 2}, n_heldout=0)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "blocker").write_text("a file, not a folder", encoding="utf-8")
    where, failed = dcli.save_or_fallback(res, str(tmp_path / "blocker" / "set.json"))
    assert failed and where.parent == tmp_path and where.is_file()
    assert ConstraintSet.load(where).pairs == res.pairs


def _same(a: dict, b: dict) -> None:
    """Two records equal but for times and versions."""
    drop = ("times", "versions")
    assert {k: v for k, v in a.items() if k not in drop} == {k: v for k, v in b.items() if k not in drop}


@pytest.mark.slow
def test_jobs_and_a_dask_cluster_give_the_same_set_and_record():
    from autotight.io import jsonable

    kw = dict(over={"sigma": [0.1, 1.0]}, n_heldout=3, compare=False)
    one = jsonable(discover("pose_averaging", {"M": 3}, 2, jobs=1, **kw).record())
    two = jsonable(discover("pose_averaging", {"M": 3}, 2, jobs=2, **kw).record())
    _same(one, two)
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        with distributed.Client(lc) as client:
            dask = jsonable(discover("pose_averaging", {"M": 3}, 2, scheduler=client, **kw).record())
    _same(one, dask)


def test_slow_held_out_batches_move_to_workers_and_give_the_same_record(monkeypatch):
    """With every batch counted slow (``AUTO_JOBS_MIN_S`` = 0) and two CPUs, the discovery that picks its own
    workers runs its first batch here and the later ones in two workers (``jobs_after``); its record equals the
    one of ``jobs=1``, times aside."""
    from autotight import parallel
    from autotight.discovery import engine, heldout
    from autotight.io import jsonable

    kw = dict(n_heldout=3, compare=False)
    one = jsonable(discover("pose_averaging", {"M": 3}, 4, jobs=1, **kw).record())
    monkeypatch.setattr(parallel, "usable_cpus", lambda: 2)
    monkeypatch.setattr(heldout, "AUTO_JOBS_MIN_S", 0.0)
    seen: list[int] = []

    def recorded(*a, **k):
        seen.append(k["jobs"])
        return heldout.solve_batch(*a, **k)

    monkeypatch.setattr(engine, "solve_batch", recorded)
    auto = jsonable(discover("pose_averaging", {"M": 3}, 4, **kw).record())
    assert seen[0] == 1 and len(seen) > 1 and set(seen[1:]) == {2}
    _same(one, auto)
    assert heldout.jobs_after(load_problem("pose_averaging"), 0.0) == 2
    monkeypatch.setattr(heldout, "AUTO_JOBS_MIN_S", 1.0)
    assert heldout.jobs_after(load_problem("pose_averaging"), 0.5) == 1


@pytest.mark.slow
def test_a_set_carried_to_a_larger_size_is_validated_there(tmp_path):
    """Learned at K = 5 and carried by its templates to held-out K = 12 chains: the set passes there, and the
    saved set's templates are those of K = 5."""
    from autotight.discovery.discovered import DiscoveredSet
    from autotight.problem import load

    res = discover("discrete_trajectory", {"K": 5, "sigma": 0.1}, 0, carry_to={"K": 12}, n_heldout=3,
                   solver=at.SolverConfig(backend="ipm"), compare=False)
    assert res.tight and res.pairs and res.carry_to == {"K": 12} and res.validated
    assert [p.carried for p in res.points] == [False, True] and res.points[1].params["K"] == 12
    assert res.points[1].heldout.passed
    path = tmp_path / "set.json"
    res.save(str(path))
    ds = DiscoveredSet.load(path)
    assert ds.params["K"] == 5 and set(ds.templates.templates) == {t for t, _ in res.pairs}
    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": 12, "sigma": 0.1}), 7)
    out = solve_instance(prob, inst, ConstraintSet(ds), config=at.SolverConfig(backend="ipm"), n_random=0)
    assert out.tight, out.verdict.reason


def test_the_committed_set_learned_at_k5_and_selected_at_k20_is_tight_at_k100():
    """The README's discrete carry-over file (benchmarks/results/scale_set_discrete_learnK5.json: learned at
    K = 5, selected over σ on K = 20 instances): its templates are those of K = 5, every template is
    exact (no per-factor fallback), and on a fresh K = 100 instance (5× the selection size) it is tight,
    where the set selected at K = 5 alone is not (README, Limits)."""
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


@pytest.mark.parametrize("hint", [{"K": 200}, {"params": {"Q": 3}}, {"params": {"M": 5}, "when": 1}])
def test_a_malformed_carry_hint_is_a_definition_error(hint):
    import types

    import problems.pose_averaging as base
    from autotight.discovery.engine import carry_hint
    from autotight.errors import ProblemDefinitionError
    from autotight.problem import Meta, Problem

    mod = types.ModuleType("pose_copy")
    mod.__dict__.update({k: v for k, v in base.__dict__.items() if not k.startswith("__")})
    mod.META = Meta(carry_to=hint)
    with pytest.raises(ProblemDefinitionError, match="META.carry_to"):
        carry_hint(Problem(mod))
    mod.META = Meta(carry_to={"params": {"M": 7}, "solver": "ipm"})
    assert carry_hint(Problem(mod)) == ({"M": 7}, "ipm")


def test_held_out_workers_by_default_only_where_the_sdp_is_large(monkeypatch):
    """``auto_jobs``: every usable CPU from AUTO_JOBS_MIN_N columns at the largest point (discrete trajectory
    K = 200: N = 4795), one process below it (pose averaging M = 5), on one CPU, and for a problem a worker
    could not load (no registered name, no module file)."""
    from autotight import parallel
    from autotight.discovery import heldout
    from autotight.problem import load

    monkeypatch.setattr(parallel, "usable_cpus", lambda: 2)
    dt, pa = load("discrete_trajectory"), load("pose_averaging")
    big, small = dt.parse_params({"K": 200}), pa.parse_params({"M": 5})
    assert dt.build(dt.generate(big, 0)).variables.N >= heldout.AUTO_JOBS_MIN_N
    assert heldout.auto_jobs(dt, [dt.parse_params({"K": 20}), big]) == 2
    assert heldout.auto_jobs(pa, [small]) == 1
    assert heldout.auto_jobs(dt, []) == 1
    monkeypatch.setattr(heldout, "registered_name", lambda prob: None)
    monkeypatch.setattr(dt, "path", None)
    assert heldout.auto_jobs(dt, [big]) == 1
    monkeypatch.setattr(parallel, "usable_cpus", lambda: 1)
    assert heldout.auto_jobs(dt, [big]) == 1


def test_violations_are_the_relative_residuals_of_each_pairs_constraints_dense_and_sparse():
    """``Trainer.violations``: per pair max |⟨A,X⟩ − b| / (‖A‖_F ‖X‖_F) computed densely, to 1e-12, for a random
    symmetric X and for the sparse X that holds only the constraints' entries (whose norm is of those entries)."""
    prob = load_problem("pose_averaging")
    tr = make_trainer(prob, prob.parse_params({"M": 5}), 0, 0, default_groups(prob, None), LearnOptions(), 1)
    pairs = list(tr.pairs)
    assert len(pairs) >= 3
    rng = np.random.default_rng(4)
    N = tr.model.variables.N
    G = rng.standard_normal((N, N))
    dense = G + G.T
    mask = sum(sp.csr_array((np.ones(c.A.nnz), (c.A.row, c.A.col)), shape=(N, N)) for p in pairs for c in tr.pairs[p])
    sparse = sp.csr_array(sp.csr_array(dense).multiply(mask != 0))
    for X in (dense, sparse):
        nx = np.linalg.norm(X.toarray() if sp.issparse(X) else X)
        Xd = X.toarray() if sp.issparse(X) else X
        want = {p: max(abs(np.sum(c.A.toarray() * Xd) - c.b) / (np.linalg.norm(c.A.toarray()) * nx)
                       for c in tr.pairs[p]) for p in pairs}
        got = tr.violations(X, pairs)
        assert set(got) == set(pairs)
        assert all(abs(got[p] - want[p]) <= 1e-12 * max(want[p], 1e-3) for p in pairs), (got, want)
        assert max(want.values()) > 1e-3
