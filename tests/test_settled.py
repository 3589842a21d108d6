"""Work that cannot change a verdict is not done: no retry of a solve whose bracket is already open, and no face
or recession-frame certificate where weak duality rules one out.

The bracket's "not tight" (U − P above the tolerance plus the solve's accuracy) bounds every dual bound of the
relaxation, so neither a second solve nor a certificate on a face can close it (``pipeline.gap_settled``,
``dual_polish.gap_stays_open``).
"""

from pathlib import Path

import numpy as np
import pytest

from autotight import pipeline, sdp
from autotight.certificate import stack
from autotight.face import forced_face
from autotight.pipeline import gap_settled, solve_instance
from autotight.problem import load
from autotight.sdp import clarabel_direct
from autotight.tightness import NOT_TIGHT, Criteria, accuracy, bracket
from autotight.unbounded import UnboundedRelaxation, is_unbounded, unbounded_blocks

MODULE = str(Path(__file__).parent / "stereo_translation_module.py")
PARAMS = {"prior_sigma": 2.0}
COST = Criteria(accept="cost")


def _almost_solved(monkeypatch) -> list:
    """Clarabel's dense path, each result marked AlmostSolved (X kept): the status a retry is made for."""
    real, calls = clarabel_direct.solve_dense, []

    def almost(Q, As, b, d, opts):
        calls.append(opts.clarabel.regularization)
        res = real(Q, As, b, d, opts)
        res.status = "AlmostSolved"
        return res

    monkeypatch.setattr(clarabel_direct, "solve_dense", almost)
    return calls


def test_a_settled_result_is_not_retried_and_the_rule_sees_the_frame_solved(monkeypatch):
    """An AlmostSolved solve of ≤ 100 columns is retried with the default regularisation, unless the caller's rule
    calls it settled.  The rule gets the data of the frame that was solved (scaled here): the solver's X satisfies
    those constraints to its accuracy, and the message says that no retry was made."""
    p = load("rotation_averaging")
    inst = p.generate({"M": 5, "sigma": 0.1}, 0)
    model = p.build(inst)
    cons = model.primary()
    D = np.linspace(0.5, 2.0, model.variables.N)
    calls = _almost_solved(monkeypatch)
    sdp.solve_model(model, cons, scale=D)
    assert calls == ["small", "default"]  # retried without a rule
    calls.clear()
    seen = []

    def rule(res, Q, As, b):  # X as the solver returned it (the layer unscales it afterwards)
        X = np.array(res.X)
        seen.append((X, res.primal_cost, Q.toarray(), [A.toarray() for A in As], b))
        return True

    out = sdp.solve_model(model, cons, scale=D, settled=rule)
    assert calls == ["small"] and out.n_calls == 1 and len(seen) == 1
    assert "not retried with default regularisation: its verdict is settled" in out.message
    X, P, Q, As, b = seen[0]
    residual = np.array([np.sum(A * X) for A in As]) - b
    assert np.abs(residual).max() <= 1e-6 * max(1.0, np.abs(b).max())
    assert abs(float(np.sum(Q * X)) - P) <= 1e-6 * abs(P)
    plain = [np.sum(c.A.toarray() * X) for c in cons]  # the unscaled data do not fit the scaled X
    assert np.abs(np.array(plain) - b).max() > 1e-3


def test_gap_settled_is_the_brackets_not_tight():
    """On a relaxation that is not tight (primary constraints of a lifting with free columns) the rule says
    settled, and the bracket of the same result says not tight; on a tight one (rotation averaging at σ = 0.01)
    neither."""
    for name, params, crit, expect in [(MODULE, PARAMS, COST, True),
                                       ("rotation_averaging", {"M": 5, "sigma": 0.01}, Criteria(), False)]:
        p = load(name)
        inst = p.generate(params, 0)
        model = p.build(inst)
        cons = model.primary()
        U = p.local_solve(inst, inst.truth).cost
        res = sdp.solve_model(model, cons)
        As, b = stack(cons)
        assert gap_settled(U, crit)(res, model.Q, As, b) is expect
        assert (bracket(res, U, crit, accuracy(res, model.Q, cons))[0] == NOT_TIGHT) is expect


def test_an_open_gap_tries_no_face_and_no_face_could_close_it(monkeypatch):
    """The primary constraints of the free-column module: the verdict is not tight, the face's own dual is not
    solved, and the bracket's reason says why.  Solved all the same, the face's dual bound stays below P plus the
    solve's accuracy, and so below U by more than the tolerance: it could not have certified."""
    import autotight.face as face

    p = load(MODULE)
    inst = p.generate(PARAMS, 0)
    called = []
    real = face.face_dual
    monkeypatch.setattr(face, "face_dual", lambda *a, **k: called.append(1) or real(*a, **k))
    r = solve_instance(p, inst, "primary", criteria=COST)
    assert not r.tight and r.verdict.cost_outcome == NOT_TIGHT and not r.certificate.certified
    assert called == [] and "exceeds the tolerance" in r.verdict.reason
    model = p.build(inst)
    cons = pipeline.prepare(p, inst, "primary").constraints
    As, b = stack(cons)
    res = sdp.solve_model(model, cons)
    x = np.atleast_2d(p.lift(inst, r.local.best.state))
    got = forced_face(model.Q, As, res.y, x)
    assert got is not None
    dual = real(model.Q, cons, got[1])
    acc = accuracy(res, model.Q, cons)
    assert dual is not None
    assert float(b @ dual[0]) <= res.primal_cost + acc.acc + 1e-9 * abs(res.primal_cost)
    assert r.upper - (res.primal_cost + acc.acc) > COST.gap_tol * abs(r.upper)


def test_a_ray_of_the_scaled_solve_is_not_solved_again_on_the_plain_data():
    """Robust Wahba's primary relaxation is unbounded: the scaled solve returns a ray, which proves it in either
    frame, so the plain data are not solved again.  The ray names the blocks nothing bounds, and raising on it
    names them too."""
    p = load("robust_wahba")
    inst = p.generate({}, 0)
    r = solve_instance(p, inst, "primary", criteria=COST, raise_unbounded=False)
    assert len(r.attempts) == 1 and is_unbounded(r.sdp) and not r.tight
    blocks = unbounded_blocks(p.build(inst), r.sdp)
    assert blocks
    with pytest.raises(UnboundedRelaxation) as e:
        solve_instance(p, inst, "primary", criteria=COST)
    assert e.value.blocks == blocks


def test_the_reduction_gets_its_verdict_of_an_unbounded_set_in_one_solver_call():
    """Greedy ranking needs a ray of an unbounded set, the reduction only its verdict: ``Solves.solve`` with
    ``with_ray=False`` makes one solver call for robust Wahba's primary relaxation, with the ray two, and both
    judge it not tight."""
    from autotight.discovery.trainers import Solves, Trainer
    from autotight.pipeline import local_search, seeds
    from autotight.sdp.config import SolverConfig

    p = load("robust_wahba")
    inst = p.generate({}, 0)
    tr = Trainer(0, 0, inst, p.build(inst), local_search(p, inst, seeds(0).local(), 1), {})
    calls = []
    for with_ray in (False, True):
        run = Solves(p, SolverConfig(), COST)
        assert run.solve(tr, [], "reduce", with_ray=with_ray) is False
        calls.append(run.n_solves)
    assert calls == [1, 2]
    assert is_unbounded(tr.last.sdp)


def _stalled_ipm(monkeypatch) -> tuple[list, list]:
    """Our IPM's results marked InsufficientProgress (its iterate kept), and a count of Clarabel's solves: the
    status after which the SDP layer hands an IPM result to its fallback."""
    from autotight.sdp import schur_ipm
    from autotight.sdp.registry import BACKENDS

    real_ipm, ipm_calls, clarabel_calls = schur_ipm.solve_ipm, [], []
    clarabel = BACKENDS["clarabel"]
    real_clarabel = clarabel.solve

    def stalled(*a, **k):
        res = real_ipm(*a, **k)
        res.status = "InsufficientProgress"
        ipm_calls.append(res)
        return res

    monkeypatch.setattr(schur_ipm, "solve_ipm", stalled)
    monkeypatch.setattr(clarabel, "solve", lambda *a, **k: clarabel_calls.append(1) or real_clarabel(*a, **k))
    return ipm_calls, clarabel_calls


def test_a_stalled_iterate_whose_gap_is_open_is_not_solved_again_by_the_fallback(monkeypatch):
    """The free-column module's primary relaxation with our IPM, each of its solves stopped InsufficientProgress:
    the best iterate's bracket says not tight, so neither Clarabel (the fallback) nor the plain data solve it again.
    The verdict is the one Clarabel's finished solve gives (not tight; its P below U by more than the tolerance and
    its accuracy), the result says it was settled, and the reason names the status it ended with."""
    from autotight.sdp.config import SolverConfig

    p = load(MODULE)
    inst = p.generate(PARAMS, 0)
    ipm_calls, clarabel_calls = _stalled_ipm(monkeypatch)
    r = solve_instance(p, inst, "primary", config=SolverConfig(backend="ipm"), criteria=COST)
    assert clarabel_calls == [] and len(ipm_calls) == r.sdp.n_calls >= 1
    assert r.outcome == NOT_TIGHT and r.sdp.settled and not r.sdp.usable and len(r.attempts) == 1
    assert "not solved again by clarabel" in r.sdp.message and "InsufficientProgress" in r.verdict.reason
    done = solve_instance(p, inst, "primary", config=SolverConfig(backend="clarabel"), criteria=COST)
    assert done.sdp.usable and done.outcome == NOT_TIGHT
    assert done.upper - done.sdp.primal_cost > done.verdict.tolerance + done.verdict.accuracy


def test_a_stalled_iterate_of_a_tight_relaxation_still_goes_to_the_fallback(monkeypatch):
    """Rotation averaging at σ = 0.01 is tight: its stalled IPM iterate settles nothing (a bracket of an unfinished
    solve says "not tight" or nothing, never "tight"), so Clarabel solves it again and decides it tight."""
    from autotight.sdp.config import SolverConfig

    p = load("rotation_averaging")
    inst = p.generate({"M": 5, "sigma": 0.01}, 0)
    ipm_calls, clarabel_calls = _stalled_ipm(monkeypatch)
    r = solve_instance(p, inst, "primary", config=SolverConfig(backend="ipm"))
    assert ipm_calls and clarabel_calls and r.tight and not r.sdp.settled
    model = p.build(inst)
    cons = pipeline.prepare(p, inst, "primary").constraints
    ipm_calls.clear()
    res = sdp.solve_model(model, cons, SolverConfig(backend="ipm"), settled=gap_settled(r.upper, Criteria()))
    assert res.usable and not res.settled and clarabel_calls
    stalled = ipm_calls[0]  # unscaled data: the frame it was solved in
    acc = accuracy(stalled, model.Q, cons)
    assert bracket(stalled, r.upper, Criteria(), acc, partial=True)[0] == "undecided"
    stalled.status = "Solved"  # the same iterate, finished: tight
    assert bracket(stalled, r.upper, Criteria(), acc)[0] == "tight"


def test_an_ipm_solve_asked_to_settle_early_ends_at_an_iterate_that_proves_not_tight():
    """The free-column module's primary relaxation (not tight) with our IPM: asked to settle early, the solve ends
    at an iterate whose own bracket says not tight, in fewer iterations than the finished solve, and neither the
    fallback nor the plain data solve it again.  ``solve_instance`` with ``settle_early`` judges it as the finished
    solve does.  Rotation averaging at σ = 0.01 (tight) never meets the rule's cheap test: its solve is the same."""
    from autotight.sdp.config import SolverConfig

    ipm = SolverConfig(backend="ipm")
    p = load(MODULE)
    inst = p.generate(PARAMS, 0)
    model = p.build(inst)
    cons = pipeline.prepare(p, inst, "primary").constraints
    U = solve_instance(p, inst, "primary", config=ipm, criteria=COST).upper
    full = sdp.solve_model(model, cons, ipm, settled=gap_settled(U, COST))
    early = sdp.solve_model(model, cons, ipm, settled=gap_settled(U, COST, early=True))
    assert early.settled and early.n_calls == 1 and early.iterations < full.iterations
    assert "settles the verdict" in early.message
    acc = accuracy(early, model.Q, cons)
    assert bracket(early, U, COST, acc, partial=True)[0] == NOT_TIGHT
    assert U - early.primal_cost > COST.gap_tol * abs(U) + acc.acc
    done = solve_instance(p, inst, "primary", config=ipm, criteria=COST)
    fast = solve_instance(p, inst, "primary", config=ipm, criteria=COST, settle_early=True)
    assert done.outcome == fast.outcome == NOT_TIGHT and fast.sdp.settled and len(fast.attempts) == 1

    p = load("rotation_averaging")
    inst = p.generate({"M": 5, "sigma": 0.01}, 0)
    model = p.build(inst)
    cons = pipeline.prepare(p, inst, "primary").constraints
    U = solve_instance(p, inst, "primary", config=ipm).upper
    a = sdp.solve_model(model, cons, ipm, settled=gap_settled(U, Criteria()))
    b = sdp.solve_model(model, cons, ipm, settled=gap_settled(U, Criteria(), early=True))
    assert not b.settled and a.iterations == b.iterations and a.status == b.status
    assert np.array_equal(a.y, b.y)


def test_the_ipm_asks_a_settle_rule_a_bounded_number_of_times():
    """A rule whose cheap test always passes and whose full test never does is asked ``SETTLE_TRIES`` times, and the
    solve is the one made without it (the same iterations and multipliers): a relaxation whose iterates keep
    looking loose to the cheap test but never settle costs at most that many tests.  The cheap test's scale
    max|Q_ij|·tr X, read off the clique blocks of the decomposed solve (discrete trajectory, K = 5: one block per
    pose pair), is the trace of the X that the same iterate completes to."""
    from autotight.sdp import schur_ipm
    from autotight.sdp.config import SolverConfig

    class Never:
        def __init__(self):
            self.scales, self.traces = [], []

        def __call__(self, res, Q, As, b):
            self.traces.append(float(abs(Q).max()) * float(res.X.diagonal().sum()))
            return False

        def may_settle(self, primal, dual, scale):
            self.scales.append(scale)
            return True

    p = load("discrete_trajectory")
    inst = p.generate({"K": 5}, 0)
    model = p.build(inst)
    cons = model.primary()
    ipm = SolverConfig(backend="ipm")
    rule = Never()
    with_rule = sdp.solve_model(model, cons, ipm, settled=rule)
    plain = sdp.solve_model(model, cons, ipm)
    assert len(rule.traces) == schur_ipm.SETTLE_TRIES and len(rule.scales) == schur_ipm.SETTLE_TRIES
    assert len(sdp.model_cover(model, cons, "ipm")) > 1
    np.testing.assert_allclose(rule.scales, rule.traces, rtol=1e-6)
    assert not with_rule.settled and with_rule.iterations == plain.iterations and np.array_equal(with_rule.y, plain.y)


def test_the_cheap_test_reads_the_brackets_absolute_tolerance():
    """``EarlyGapSettled.may_settle`` is implied by the bracket's "not tight": with U − P above gap_tol·|U| + |P − D|
    but below the absolute tolerance cost_atol·max|Q|·tr X, it says no (the bracket could not say not tight)."""
    rule = gap_settled(1.0, Criteria(), early=True)
    c = Criteria()
    P, D = 0.9, 0.9
    assert rule.may_settle(P, D, 0.0)
    assert not rule.may_settle(P, D, 2 * (1.0 - P) / c.cost_atol * 1.01)
    assert not rule.may_settle(P, D - 0.2, 0.0)
