"""The discovery engine: learn → tighten and reduce on training instances → validate on held-out
instances → close the loop → one set with its evidence.

``discover(problem, params, seed, over=…)`` (``autotight.discover``, ``autotight discover``) runs every
case the same way: one point is a range of one point, ``n_train`` is the number of training instances
per point, and a set that must carry to other sizes (``carry_to``, e.g. ``{"K": 200}``) is validated at
those sizes as well.

1. **Points** are the product of ``over`` on top of ``params`` (``autotight.points.points_of``); each
   has ``n_train`` training instances (seeds: ``trainers``).  With ``carry_to`` every point also gets a
   validation point at the same values with the ``carry_to`` parameters.
2. **Learn** the candidates per factor type on each training instance (with ``carry_to``: once, at the
   first point, with their templates, which carry every candidate to instances of any size).
3. **Tighten and reduce** on the training instances (``select``), every solve through
   ``autotight.pipeline.solve_instance``: the function ``solve`` and ``check`` use.  A training instance
   that no candidate makes tight for a reason of its own (its bound stays below its optimum with every
   candidate, or its verdict stays undecided) is set aside and replaced by a fresh one, up to
   ``MAX_SET_ASIDE`` per point: an instance whose relaxation is not tight with every valid relation the
   groups can learn is a fact about that instance, which held-out validation then counts as ``check`` does.
   Reasons every instance shares (``Trainer.structural``: rank 1 out of reach under ``accept="rank"``, an
   unbounded block no candidate bounds) end the discovery at once.  The set is reduced over the instances
   it is tight on.
4. **Validate**: ``n_heldout`` fresh held-out instances at every point (and validation point), solved with
   the set in parallel (``heldout``: ``jobs``/``scheduler``).  A point passes as in ``check``: tight /
   (instances − undecided) ≥ ``min_fraction``.  At a validation point of ``carry_to`` (large, costly
   instances) the batch stops at the instance after which the point cannot pass any more
   (``heldout.hopeless``; the rest of its seeds are not solved).  At the points the set is learned at every
   instance of the batch is solved, so that every failing one is taken in: a set tightened on fewer of them
   passed a fresh batch and then failed ``check`` (pose averaging M = 5 over σ ∈ {0.01, 0.1, 1}, seed 1).
   An instance first tries the certificate of its local solution (``shortcut``) instead of the full SDP, until a
   batch of its point has tight instances and the shortcut decided none of them; once the set grows, every point
   tries it again (``shortcut_pays``).
5. **Close the loop**: every held-out instance the set fails becomes a training instance (the set's own pairs
   with the very constraints its check solved, ``trainers.make_trainer``'s ``given``); the set is
   tightened from where it is on them, one at a time (``select.tighten_each``; its pairs stay: dropping
   them to fit the new instances would lose what the earlier batches showed; the added pairs are reduced
   over all training instances), and the points with a failing instance get a fresh batch (the set only
   grows and tightness is monotone in the set, so a batch without failures stays tight).
   **Confirm**: a point is done once it holds ``confirm_count(min_fraction, n_heldout)`` decided held-out
   instances since the last failing one the set was grown to fix, tight at ``min_fraction`` or more (``done``;
   solved with the set or a smaller one: by monotonicity those tight then are tight with the set): whole
   batches, at least ``MIN_CONFIRM_BATCHES``, enough that a set tight on a share of just ``min_fraction`` of
   the instances is confirmed with probability at most ``CONFIRM_RISK``.  So a point whose first fresh batch is
   clean gets more.  At 0.9 that is 30 instances (0.9³⁰ = 0.04): with 20, a set failing one instance in 10
   passed with probability 0.12 and then failed ``check``'s 10 instances one time in four.  A failing instance
   that no candidate makes tight (taken in, not reached: the lifting cannot make it tight) leaves the set as
   it was: it counts against the fraction and does not restart the count, so a problem with such instances
   below 1 − ``min_fraction`` is confirmed instead of spending its budget.  It stops when every point is done
   (validated), or when ``max_rounds`` rounds or ``max_solves`` SDP solver calls are spent: validated then
   when every point's latest batch passes at ``min_fraction`` (a passing batch's failing instances are still
   taken in), else the result records that validation failed.  Validated with a point short of its
   confirmation (the budget spent), the message says so.  A held-out instance whose check before any verdict
   rejects the set (``validity``: a constraint off at one of its feasible points, e.g. a template fitted at the
   learning size and off where it was carried) ends validation as failed, with that constraint named.
6. The set (``DiscoveredSet``) is saved with the evidence of every round (``DiscoveryResult.record``).

Seeds (``trainers``): training ``seed`` for the first instance at the first point, else
SeedSequence((seed, i, t, 1)); held-out SeedSequence((seed, i, t, 2)) with t
counting on over the rounds, so every batch is fresh and none is one of ``check``'s instances.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from ..points import parse_over, points_of
import autotight.module_parts as module_parts
from ..check import PointResult
from ..constraint_set import ConstraintSet
from ..errors import ParameterError
from ..problem import Problem, load
from ..sdp.config import SolverConfig
from ..threads import single_blas_thread
from ..tightness import Criteria
from ..unbounded import UnboundedRelaxation
from ..validity import InvalidConstraintError
from .compare import paper_in_span, resemblance
from .discovered import DiscoveredSet
from .heldout import auto_jobs, jobs_after, solve_batch
from .learn import LearnOptions
from .result import DiscoveryResult, PointRecord, round_record
from .select import reduce, tighten, tighten_each
from .trainers import Solves, Trainer, candidates, heldout_seed, learned_source, make_trainer, training_seed

#: the probability at most that a set tight on a share of just ``min_fraction`` of the instances is confirmed
#: (module docstring, step 5)
CONFIRM_RISK = 0.05
#: held-out batches a point needs at least since its last failing one, whatever ``min_fraction``
MIN_CONFIRM_BATCHES = 2
#: training instances a point may set aside and replace by fresh ones (module docstring, step 3)
MAX_SET_ASIDE = 3


def default_groups(problem: Problem, groups: Any) -> Any:
    """``groups``, or when None the problem module's ``META.default_groups`` (else "factors")."""
    return module_parts.default_groups(problem) if groups is None else groups


def carry_hint(problem: Problem) -> tuple[dict[str, Any], str | None]:
    """The module's optional ``META.carry_to`` hint as (parameters a set must also pass at, suggested backend)."""
    return module_parts.carry_to(problem)


def _parsed(prob: Problem, values: dict[str, Any]) -> dict[str, Any]:
    """Only the given parameters, each validated and parsed (``Problem.parse_params`` checks the names)."""
    prob.parse_params(values)
    return {k: prob.params[k].parse(k, v) for k, v in values.items()}


def confirm_count(min_fraction: float, n_heldout: int) -> int:
    """Decided held-out instances a point needs since its last failing one (module docstring, step 5).

    Whole batches of ``n_heldout``, at least ``MIN_CONFIRM_BATCHES``, holding n ≥ log(CONFIRM_RISK) /
    log(min_fraction) instances: a set tight on each instance independently with probability ``min_fraction``
    is tight on all n with probability min_fraction^n ≤ CONFIRM_RISK.  With min_fraction = 1 (every instance must
    pass) or 0, the minimum: no count of clean instances bounds that risk, and any failure restarts the count.
    """
    batches = MIN_CONFIRM_BATCHES
    if 0.0 < min_fraction < 1.0 and n_heldout > 0:
        n = math.log(CONFIRM_RISK) / math.log(min_fraction)
        batches = max(batches, math.ceil(n / n_heldout - 1e-9))
    return batches * n_heldout


def _count(name: str, v: Any, low: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
        raise ParameterError(f"{name} must be an int ≥ {low}, got {v!r}")
    return int(v)


@single_blas_thread
def discover(problem: Problem | str, params: Mapping[str, Any] | None = None, seed: int = 0, *,
             over: Mapping[str, Sequence[Any]] | None = None, n_train: int = 1, n_heldout: int = 10,
             min_fraction: float = 0.9, max_rounds: int = 5, max_solves: int | None = None,
             carry_to: Mapping[str, Any] | None = None, groups: Any = None,
             learn_options: LearnOptions = LearnOptions(), criteria: Criteria = Criteria(),
             solver: SolverConfig | None = None, n_random: int = 2, compare: bool = True, jobs: int | None = None,
             scheduler: Any = None, progress: Callable[[str, str], None] | None = None,
             shortcut: bool = True) -> DiscoveryResult:
    """Discover one set for ``problem`` at ``params`` (over every point of ``over``) that passes validation.

    n_train: training instances per point.  n_heldout: held-out instances per point and round (0: no
    validation).  min_fraction: the pass rule of ``check``.  max_rounds: held-out batches at most;
    max_solves: SDP solver calls at most (None: no limit); either spent, validation has failed.
    carry_to: parameters (e.g. ``{"K": 200}``) at which the set must pass too (None: the module's
    ``META.carry_to`` hint, if any; ``{}``: none).  groups: learning groups (None: the module's
    ``META.default_groups``, else "factors").  criteria: what counts as tight (``criteria.accept``).  solver: the
    ``SolverConfig`` of every SDP solve.  compare: also solve the paper's families on each point's latest held-out
    batch (once validation ends).  jobs/scheduler: where held-out instances run (``heldout``; jobs None: every CPU
    when the largest held-out point has an SDP of ``heldout.AUTO_JOBS_MIN_N`` columns or more, else this process,
    ``heldout.auto_jobs``, and every CPU for the later batches once a batch in this process took
    ``heldout.AUTO_JOBS_MIN_S`` or more per instance, ``heldout.jobs_after``; the result does not depend on it).
    shortcut: a held-out instance whose local solution's certificate proves the set tight needs no full SDP
    (``shortcut``; the others are solved in full), tried at a point as long as it pays (``shortcut_pays``).
    progress(stage, text) is called as work proceeds.
    Raises ``UnboundedRelaxation`` when no learned candidate bounds an unbounded relaxation.
    """
    prob = load(problem) if isinstance(problem, str) else problem
    seed = _count("seed", seed, 0)
    n_train, n_heldout, max_rounds = _count("n_train", n_train, 1), _count("n_heldout", n_heldout, 0), \
        _count("max_rounds", max_rounds, 1)
    if max_solves is not None:
        max_solves = _count("max_solves", max_solves, 1)
    if not 0.0 <= float(min_fraction) <= 1.0:
        raise ParameterError(f"min_fraction must be in [0, 1], got {min_fraction!r}")
    jobs = None if jobs is None else _count("jobs", jobs, 1)
    groups = default_groups(prob, groups)
    say = progress or (lambda stage, text: None)
    over_ = parse_over(prob, over)
    hint, backend = carry_hint(prob)
    carry = hint if carry_to is None else _parsed(prob, dict(carry_to))
    config = solver if solver is not None else (SolverConfig(backend=backend) if carry_to is None and hint
                                                and backend else SolverConfig())
    clash = sorted(set(carry) & set(over_))
    if clash:
        raise ParameterError(f"parameter {clash[0]} is both varied and a size the set must carry to")
    points = points_of(prob, params, over_)
    carry = {k: v for k, v in carry.items() if any(full[k] != v for full, _ in points)}
    fixed = {k: v for k, v in points[0][0].items() if k not in over_}
    check_points = points + [(full | carry, varied | carry) for full, varied in points] if carry else list(points)
    chosen_jobs = jobs is None and scheduler is None  # the engine picks the held-out workers (``heldout``)
    if jobs is None:
        jobs = 1 if scheduler is not None or not n_heldout else auto_jobs(prob, [full for full, _ in check_points])
    t0 = time.perf_counter()
    tm = {"learn_s": 0.0, "tighten_s": 0.0, "reduce_s": 0.0, "templates_s": 0.0, "heldout_s": 0.0}

    def timed(key: str, f: Callable, *a: Any, **k: Any) -> Any:
        t = time.perf_counter()
        out = f(*a, **k)
        tm[key] += time.perf_counter() - t
        return out

    source = None
    if carry:  # learned once, carried to every instance by its templates
        source = timed("learn_s", learned_source, prob, points[0][0], seed, groups, learn_options,
                       {k: v for k, v in over_.items()}, say)
    trainers: list[Trainer] = []
    for i, (full, varied) in enumerate(points):
        for t in range(n_train):
            trainers.append(timed("learn_s", make_trainer, prob, full, i, training_seed(seed, i, t), groups,
                                  learn_options, n_random, source))
            say("learn", f"{varied} #{t}")
    run = Solves(prob, config, criteria)
    cands = candidates(trainers, source is not None)
    greedy = timed("tighten_s", tighten, run, trainers, cands, say)
    unreached = [tr for tr in trainers if not tr.reached]
    if unreached and all("unbounded" in tr.message for tr in unreached) and len(unreached) == len(trainers):
        from ..unbounded import unbounded_blocks

        tr = unreached[0]
        raise UnboundedRelaxation(tr.message, unbounded_blocks(tr.model, tr.last.sdp) if tr.last else [])
    drawn = [n_train] * len(points)  # training instances drawn per point, replacements included
    while True:  # replace the training instances that no candidate makes tight, where another one can be
        new = [timed("learn_s", make_trainer, prob, points[i][0], i, training_seed(seed, i, drawn[i]), groups,
                     learn_options, n_random, source, "replacement") for i in _short(trainers, drawn, n_train)]
        if not new:
            break
        for tr in new:
            drawn[tr.point] += 1
        trainers += new
        say("learn", f"{len(new)} replacement training instance(s)")
        cands = candidates(trainers, source is not None)
        start = greedy if any(tr.reached for tr in trainers if tr not in new) else []
        greedy = timed("tighten_s", tighten, run, new, cands, say, start, "tighten")
    tight_on = [tr for tr in trainers if tr.reached]
    unreached = [tr for tr in trainers if not tr.reached
                 and not any(k.point == tr.point for k in tight_on)]  # at a point no training instance reached
    pairs, dropped = (timed("reduce_s", reduce, run, tight_on, greedy, say) if greedy and not unreached
                      else (list(greedy), []))
    info = {"range": {"over": over_, "n_train": n_train, "carry_to": carry,
                      "training_seeds": "SeedSequence((seed, point, t, 1))",
                      "heldout_seeds": "SeedSequence((seed, point, t, 2))"},
            "criteria": asdict(criteria)}

    fits: dict = {}  # template fits of this discovery: instances and their learning, kept as the set grows

    def make_set(chosen: list) -> DiscoveredSet:
        ds = DiscoveredSet(prob.name, dict(points[0][0]), seed, list(chosen), asdict(learn_options), dict(info),
                           groups if isinstance(groups, str) else [list(g) for g in groups])
        if source is not None:
            ds.templates = source.template_set(prob).restricted(chosen)
        elif chosen:
            ds.template_set(prob, cache=fits)
        return ds

    rounds: list[dict[str, Any]] = []
    last: list[Any] = [None] * len(check_points)  # per point its latest batch (a PointResult)
    ds = timed("templates_s", make_set, pairs)
    next_t = [0] * len(check_points)
    validated: bool | None = None
    stop = ""
    # the paper's families are solved once the loop ends, on each point's latest batch (the one kept): a batch
    # that fails is replaced by a fresh one, so solving them on every batch (the carry's held-out SDPs) was
    # wasted; their solver calls are not part of max_solves
    with_paper = bool(compare and trainers[0].model.paper)
    paper: list[Any] = [None] * len(check_points)
    kept: list[list[int]] = [[] for _ in check_points]  # the seeds of each point's latest batch
    need = confirm_count(float(min_fraction), n_heldout)
    # per point, the decided held-out instances since the last failing one the set was grown to fix (``clean``),
    # and how many of them no candidate makes tight (``loose``: taken in, not reached)
    clean = [0] * len(check_points)
    loose = [0] * len(check_points)
    # per point, whether its held-out instances try the shortcut (``shortcut_pays``; every point again once the set
    # grows)
    quick = [bool(shortcut)] * len(check_points)

    def done(i: int) -> bool:
        """``need`` decided instances since the last failure the set was grown to fix, tight at min_fraction."""
        return clean[i] >= need and clean[i] - loose[i] >= float(min_fraction) * clean[i] - 1e-12

    while n_heldout and not unreached:
        # a point is done once ``done``: the set only grows from here on, and tightness is monotone in the set
        todo = [i for i in range(len(check_points)) if not done(i)]
        batch = [[heldout_seed(seed, i, next_t[i] + t) for t in range(n_heldout)] if i in todo else []
                 for i in range(len(check_points))]
        next_t = [n + len(b) for n, b in zip(next_t, batch)]
        t_batch = time.perf_counter()
        try:
            held, n = timed("heldout_s", solve_batch, prob, {"set": ConstraintSet(ds)}, check_points, batch,
                            min_fraction=float(min_fraction), criteria=criteria, config=config, n_random=1,
                            jobs=jobs, scheduler=scheduler, shortcut=quick,
                            stop_hopeless=[i >= len(points) for i in range(len(check_points))])
        except InvalidConstraintError as e:  # a template off where it was carried: no verdict can stand on it
            validated, stop = False, f"a held-out instance rejects the set before any verdict: {e}"
            break
        run.count("heldout", n["set"])
        for i in todo:
            last[i] = held["set"][i]
            kept[i] = batch[i]
        solved = sum(len(held["set"][i].seeds) for i in todo)
        if chosen_jobs and jobs == 1 and solved:  # instances slower than their columns said: workers from here on
            jobs = jobs_after(prob, (time.perf_counter() - t_batch) / solved)
        failing = [(i, s) for i in todo for s, _, _ in last[i].with_outcome("not tight")]
        passed = all(pr.passed for pr in last)
        rounds.append(round_record(len(rounds), [last[i] for i in todo], len(pairs), passed,
                                   [len(batch[i]) for i in todo]))
        say("validate", f"round {len(rounds)}: {'passed' if passed else 'not passed'}, {len(failing)} not tight")
        spent = ""
        if len(rounds) >= max_rounds:
            spent = f"{max_rounds} held-out rounds spent (max_rounds)"
        elif max_solves is not None and run.n_solves >= max_solves:
            spent = f"{run.n_solves} SDP solver calls spent (max_solves {max_solves})"
        grown: set[int] = set()  # points with a failing instance the set was grown to fix
        changed = False  # the set grew this round
        if failing and not (spent and not passed):
            new = [timed("learn_s", make_trainer, prob, check_points[i][0], i, s, groups, learn_options, n_random,
                         source, "held-out", ds) for i, s in failing]
            trainers += new
            cands = candidates(trainers, source is not None)
            more = timed("tighten_s", tighten_each, run, new, cands, say, pairs, "validate")
            reached = [tr for tr in trainers if tr.reached]
            grown = {tr.point for tr in new if tr.reached}
            rounds[-1]["taken_in"] = len(new)
            rounds[-1]["not_reached"] = len(trainers) - len(reached)
            if len(more) > len(pairs):  # the pairs added for the new instances, reduced; the set's own pairs stay
                pairs, d2 = timed("reduce_s", reduce, run, reached, more, say, keep=pairs)
                dropped += d2
                rounds[-1]["n_pairs_after"] = len(pairs)
                ds = timed("templates_s", make_set, pairs)
                changed = True
        for i in todo:
            quick[i] = bool(shortcut) and (changed or shortcut_pays(last[i], quick[i]))
            if i in grown:
                clean[i] = loose[i] = 0
            else:
                clean[i] += last[i].n_decided
                loose[i] += last[i].count("not tight")
        rounds[-1]["tight_since_last_failure"] = [c - k for c, k in zip(clean, loose)]
        rounds[-1]["loose_since_last_failure"] = list(loose)
        if all(done(i) for i in range(len(check_points))):
            validated = True
            break
        if not failing and not passed:  # only undecided instances keep a batch from passing
            validated, stop = False, "held-out instances undecided by the solver's accuracy; none failed"
            break
        if spent:  # a passing last batch's failing instances were taken in (the set only grew)
            validated, stop = passed, spent
            break
    if with_paper and validated is not None:
        held, n = timed("heldout_s", solve_batch, prob, {"paper": "paper"}, check_points, kept,
                        min_fraction=float(min_fraction), criteria=criteria, config=config, n_random=1, jobs=jobs,
                        scheduler=scheduler, shortcut=shortcut)
        paper = held["paper"]
        run.count("paper", n["paper"])
    validation = {"passed": validated, "min_fraction": float(min_fraction), "n_heldout": n_heldout,
                  "max_rounds": max_rounds, "max_solves": max_solves, "confirm": need,
                  "tight_since_last_failure": [c - k for c, k in zip(clean, loose)],
                  "loose_since_last_failure": list(loose), "rounds": rounds,
                  "message": _validation_message(validated, stop, rounds, n_heldout, unreached, clean, loose, need,
                                                 [tr.seed for tr in trainers if not tr.reached
                                                  and tr.origin != "held-out" and tr not in unreached],
                                                 all(done(i) for i in range(len(check_points))))}
    ds.info["validation"] = validation
    precs = []
    for i, (full, varied) in enumerate(check_points):
        mine = [tr for tr in trainers if tr.point == i]
        precs.append(PointRecord(i, varied, full, [tr.seed for tr in mine], [tr.reached for tr in mine],
                                 [tr.message for tr in mine], [tr.origin for tr in mine],
                                 last[i], paper[i],
                                 carried=i >= len(points)))
    first = next((tr for tr in trainers if tr.catalog is not None), None)
    span, like = {}, {}
    if compare and first is not None and first.catalog is not None and first.model.paper:
        spans: dict = {}  # the primary constraints' coefficients per group, shared by both
        span = paper_in_span(first.catalog, spans)
        like = {c.name: resemblance(c, first.catalog, cache=spans) for p in pairs for c in first.pairs.get(p, [])}
    tm["sdp_training_s"] = run.sdp_s
    tm["total_s"] = time.perf_counter() - t0
    say("done", "")
    return DiscoveryResult(prob, fixed, over_, carry, seed, n_train, precs, cands, greedy, list(pairs),
                           not unreached, dropped, ds, validation, run.n_solves, dict(run.by_stage), tm, run.log,
                           trainers, span, like, criteria.accept)


def shortcut_pays(batch: PointResult, tried: bool) -> bool:
    """Whether a point's next batch tries the shortcut, after ``batch`` with the same set, solved with it
    (``tried``) or not: yes unless it was tried and decided none of the batch's tight instances (their status is
    "certified" when it did).  Where the certificate of the local solution does not find the set's multipliers,
    each try is time lost before the SDP that then decides (discrete trajectory K = 200, a 5-pair set: 1.1–1.7 s
    of Douglas–Rachford before a 3.2 s SDP).  The rule reads only finished batches, so the choice, and with it
    every row, does not depend on where the instances ran."""
    if not tried:
        return False
    tight = [st for o, st in zip(batch.outcomes, batch.statuses) if o == "tight"]
    return not tight or "certified" in tight


def _short(trainers: list[Trainer], drawn: list[int], n_train: int) -> list[int]:
    """The points that get a replacement training instance: fewer than ``n_train`` of their instances reached,
    one not reached for a reason of its own (not ``Trainer.structural``), and fewer than ``MAX_SET_ASIDE``
    replacements drawn."""
    return [i for i in range(len(drawn)) if drawn[i] < n_train + MAX_SET_ASIDE
            and any(not tr.reached and not tr.structural for tr in trainers if tr.point == i)
            and sum(tr.reached for tr in trainers if tr.point == i) < n_train]


def _validation_message(validated: bool | None, stop: str, rounds: list[dict], n_heldout: int,
                        unreached: list[Trainer], clean: list[int], loose: list[int], need: int,
                        set_aside: list[int], confirmed: bool) -> str:
    if unreached:
        drawn = max(sum(1 for t in unreached if t.point == tr.point) for tr in unreached)
        why = f" (no candidate makes any of the {drawn} drawn at a point tight)" if drawn > 1 else ""
        return f"not validated: the set is not tight on every training instance{why}"
    aside = (f"; training seed(s) {', '.join(map(str, set_aside))} set aside and replaced: no candidate makes them "
             "tight" if set_aside else "")
    if not n_heldout:
        return f"not validated (no held-out instances){aside}"
    if validated:
        rounds_taken = f"({len(rounds)} round(s), {sum(r.get('taken_in', 0) for r in rounds)} failing held-out " \
                       "instance(s) taken in)"
        if confirmed:
            n_loose = sum(loose)
            with_loose = f", {n_loose} of them not tight with any candidate" if n_loose else ""
            return (f"validated: every point holds at least {need} decided held-out instances since the last failure "
                    f"the set was grown to fix, tight at the required fraction{with_loose} {rounds_taken}{aside}")
        short = min(clean, default=need)
        return (f"validated: every point's latest fresh held-out batch passed, but a point holds only {short} decided "
                f"held-out instances since the last failure the set was grown to fix, short of the {need} that "
                f"confirm it (the budget was spent) {rounds_taken}{aside}")
    worst = min(((p["fraction"], p) for p in (rounds[-1]["points"] if rounds else []) if not p["passed"]),
                key=lambda x: float("inf") if x[0] != x[0] else x[0], default=(None, None))[1]
    where = f" (worst {worst['varied'] or 'point'}: {worst['tight']} tight of {worst['instances']})" if worst else ""
    return f"validation FAILED: {stop}{where}{aside}"
