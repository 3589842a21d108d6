"""``autotight.evaluate``: the loop check, held-out validation and report trials share — one model and one
local search per instance, a failed instantiation confined to its set, the shortcut, the seed scheme."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

import autotight.evaluate as ev_mod
from autotight.constraint_set import ConstraintSet
from autotight.discovery.shortcut import certified_tight
from autotight.errors import AutotightError
from autotight.evaluate import Certified, NotInstantiated, evaluate, evaluate_instance, summary
from autotight.pipeline import SolveResult, seeds, solve_instance
from autotight.problem import load
from autotight.tightness import Criteria

PARAMS = {"M": 3, "sigma": 0.1}


@pytest.fixture(scope="module")
def pose():
    return load("pose_averaging")


@dataclass
class _Learned:
    """A stand-in for a learned set: ``apply`` records the first draw of the generator it is given and adds no
    constraint, or fails."""

    fail: bool = False
    problem: str = "pose_averaging"

    def __post_init__(self) -> None:
        self.draws: list[float] = []

    @property
    def pairs(self) -> list[tuple[str, str]]:
        return []

    def apply(self, problem, inst, model, rng, skip_invalid=False):
        self.draws.append(float(rng.random()))
        if self.fail:
            raise AutotightError("no template fits this instance")
        return []


@dataclass(frozen=True)
class _Proof:
    rel_bound: float = 1e-9

    def reason(self) -> str:
        return "proved by the test"


def test_a_set_that_cannot_be_instantiated_fails_alone_and_the_sets_share_one_local_search(pose, monkeypatch):
    calls = {"local_search": 0, "build": 0}
    real_search, real_build = ev_mod.local_search, pose.build

    def counting_search(*a, **k):
        calls["local_search"] += 1
        return real_search(*a, **k)

    def counting_build(*a, **k):
        calls["build"] += 1
        return real_build(*a, **k)

    monkeypatch.setattr(ev_mod, "local_search", counting_search)
    monkeypatch.setattr(pose, "build", counting_build)
    inst = pose.generate(PARAMS, 3)
    bad = ConstraintSet(_Learned(fail=True))
    out = evaluate_instance(pose, inst, {"paper": "paper", "bad": bad, "primary": "primary"})
    assert calls == {"local_search": 1, "build": 1}  # one model and one local search for the three sets
    assert list(out.results) == ["paper", "bad", "primary"]
    paper, failed, primary = (out.results[k] for k in ("paper", "bad", "primary"))
    assert isinstance(failed, NotInstantiated) and "no template fits" in failed.reason
    assert isinstance(paper, SolveResult) and isinstance(primary, SolveResult)
    assert paper.local is out.local and primary.local is out.local
    # the sets after the failed one are still solved, and judged on their own numbers: paper is rank 1 with
    # the SDP cost at the local optimum, primary is not
    assert paper.outcome == "tight" and paper.log_svr > Criteria().min_log_svr
    assert paper.sdp.primal_cost == pytest.approx(out.local.best.cost, rel=1e-5)
    assert primary.outcome != "tight" and primary.log_svr < Criteria().min_log_svr
    row = summary(failed)
    assert row["outcome"] == "not tight" and row["status"] == "not instantiated" and row["calls"] == 0
    assert row["n_constraints"] == 0 and math.isnan(row["log_svr"]) and row["reason"].startswith("cannot instantiate")
    with pytest.raises(AutotightError, match="no template fits"):  # the report's rule: the whole trial fails
        evaluate_instance(pose, inst, {"bad": bad}, catch_instantiate=False)


def test_evaluate_follows_the_seed_scheme_of_solve_instance(pose):
    """``evaluate(params, s)`` is ``solve_instance`` on ``generate(params, s)`` with ``seeds(s)``: the same numbers."""
    out = evaluate(pose, PARAMS, 11, {"paper": "paper"}).results["paper"]
    ref = solve_instance(pose, pose.generate(PARAMS, 11), "paper")
    assert isinstance(out, SolveResult)
    assert out.local.from_random[0].cost == ref.local.from_random[0].cost
    assert (out.log_svr, out.upper, out.sdp.primal_cost) == (ref.log_svr, ref.upper, ref.sdp.primal_cost)
    row = summary(out)
    assert row["calls"] == max(1, len(out.attempts)) and row["n_constraints"] == out.n_constraints
    assert row["log_svr"] == out.log_svr and row["outcome"] == out.outcome


def test_learned_sets_draw_fresh_generators_unless_one_is_given(pose):
    """Without ``rng_constraints`` every learned set draws from a fresh ``seeds(s).constraints()`` (check,
    held-out); with one, the sets share it in their order (a report trial's ``rng_disc``)."""
    inst = pose.generate(PARAMS, 5)
    first = seeds(5).constraints().random()
    always = lambda *a: _Proof()  # noqa: E731  # no SDP: the test is about the generators
    a, b = _Learned(), _Learned()
    evaluate_instance(pose, inst, {"a": ConstraintSet(a), "b": ConstraintSet(b)}, shortcut=always)
    assert a.draws == [first] and b.draws == [first]
    a, b = _Learned(), _Learned()
    shared = np.random.default_rng(99)
    expected = np.random.default_rng(99).random(2)
    evaluate_instance(pose, inst, {"a": ConstraintSet(a), "b": ConstraintSet(b)}, shortcut=always,
                      rng_constraints=shared)
    assert [*a.draws, *b.draws] == list(expected)


def test_the_shortcut_certifies_at_the_local_solution_and_solves_what_it_cannot(pose):
    inst = pose.generate(PARAMS, 7)
    seen = []

    def recording(model, constraints, theta, criteria, gap):
        seen.append((len(constraints), theta))
        return certified_tight(model, constraints, theta, criteria, gap)

    out = evaluate_instance(pose, inst, {"paper": "paper", "primary": "primary"}, shortcut=recording,
                            raise_unbounded=False)
    paper, primary = out.results["paper"], out.results["primary"]
    assert isinstance(paper, Certified) and paper.proof.rel_bound <= Criteria().gap_tol
    assert paper.n_constraints == seen[0][0] == len(out.model.primary() + out.model.paper_constraints())
    np.testing.assert_array_equal(seen[0][1], pose.lift(inst, out.local.best.state))  # Θ̂ of the best local solution
    assert isinstance(primary, SolveResult) and primary.outcome != "tight"  # not certified: the full SDP judged it
    row = summary(paper)
    assert (row["outcome"], row["status"], row["calls"]) == ("tight", "certified", 0)
    assert row["rel_gap"] == paper.proof.rel_bound and math.isnan(row["log_svr"])
