"""Does a constraint set suffice?  N fresh instances per point of a range, solved through the pipeline.

``check_sufficient`` is what ``autotight check`` and ``autotight.testing.assert_sufficient`` run.

Points: the product of the ``over`` values (``sigmas`` is short for ``over={"sigma": sigmas}``),
each on top of the fixed ``params``; without either, the one point ``params`` (or, for a saved
range set, the range it was learned over, ``info["range"]["over"]``).  Values are sorted.

Seeds: instance t (t = 0 … N − 1) at point index i has the seed SeedSequence((seed, i, t)), the
report sweep's trial seeds (``autotight.report.spec.trial_seeds``), so ``check --seed S`` solves
the instances of ``report --seed S`` over the same σ list; its local starts and the
re-instantiation of a learned set use the generators of ``autotight.pipeline.seeds``.

Counting: each instance's outcome is "tight", "undecided" or "not tight" (a learned set that cannot be
instantiated on the instance is "not tight"; a solve that returned no usable solution is "undecided").
Undecided instances are left out of the fraction: fraction = tight / (instances − undecided), and a point passes when
fraction ≥ min_fraction.  A point where every instance is undecided has no evidence and does not
pass.  Undecided instances are listed separately and never count as failures.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .constraint_set import ConstraintSet, ConstraintsLike, set_name
from .errors import ParameterError
from .evaluate import NotInstantiated, evaluate, summary
from .io import versions
from .limits import check_count, check_size, count_arg
from .pipeline import SolveResult
from .points import parse_over, points_of
from .problem import Problem, load
from .tightness import Criteria, Outcome

OUTCOMES = (Outcome.TIGHT, Outcome.UNDECIDED, Outcome.NOT_TIGHT)


def instance_seed(seed: int, point: int, trial: int) -> int:
    """The seed of instance ``trial`` at point index ``point`` (see the module docstring)."""
    return int(np.random.SeedSequence([seed, point, trial]).generate_state(1, np.uint32)[0])


@dataclass
class PointResult:
    """One point of the range: per instance its seed, outcome, log SVR and the verdict's reason."""

    params: dict[str, Any]
    varied: dict[str, Any]
    min_fraction: float
    seeds: list[int] = field(default_factory=list)
    outcomes: list[str] = field(default_factory=list)
    log_svr: list[float] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    n_constraints: list[int] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    rel_gap: list[float] = field(default_factory=list)
    set_label: str = ""

    def add(self, seed: int, row: Mapping[str, Any]) -> None:
        """Append one instance: its seed and its row of ``evaluate.summary`` (outcome, log SVR, reason, …)."""
        self.seeds.append(int(seed)); self.outcomes.append(row["outcome"]); self.log_svr.append(row["log_svr"])
        self.reasons.append(row["reason"]); self.n_constraints.append(row["n_constraints"])
        self.statuses.append(row["status"]); self.rel_gap.append(row["rel_gap"])

    def count(self, outcome: str) -> int:
        return sum(o == outcome for o in self.outcomes)

    @property
    def n_decided(self) -> int:
        return len(self.outcomes) - self.count("undecided")

    @property
    def fraction(self) -> float:
        """tight / (instances − undecided); NaN when no instance was decided."""
        return self.count("tight") / self.n_decided if self.n_decided else float("nan")

    @property
    def passed(self) -> bool:
        return self.n_decided > 0 and self.fraction >= self.min_fraction - 1e-12

    def with_outcome(self, outcome: str) -> list[tuple[int, str, float]]:
        """(seed, reason, log SVR) of the instances with this outcome."""
        return [(s, r, v) for s, o, r, v in zip(self.seeds, self.outcomes, self.reasons, self.log_svr) if o == outcome]

    def record(self) -> dict[str, Any]:
        return {"params": self.params, "varied": self.varied, "instances": len(self.seeds),
                "tight": self.count("tight"), "undecided": self.count("undecided"),
                "not_tight": self.count("not tight"), "fraction": self.fraction, "passed": self.passed,
                "n_constraints": sorted(set(self.n_constraints)), "statuses": self.statuses,
                "rel_gap": self.rel_gap,
                "failing": [{"seed": s, "reason": r, "log_svr": v} for s, r, v in self.with_outcome("not tight")],
                "undecided_seeds": [{"seed": s, "reason": r, "log_svr": v}
                                    for s, r, v in self.with_outcome("undecided")],
                "seeds": self.seeds, "outcomes": self.outcomes, "log_svr": self.log_svr}


@dataclass
class SufficiencyReport:
    """The result of ``check_sufficient``: one ``PointResult`` per point; ``passed`` when every point passed."""

    problem: str
    constraint_set: str
    params: dict[str, Any]
    over: dict[str, list[Any]]
    instances: int
    min_fraction: float
    seed: int
    points: list[PointResult]
    n_solves: int
    time_s: float
    solver: str = "clarabel"
    accept: str = "rank"

    @property
    def passed(self) -> bool:
        return all(p.passed for p in self.points)

    @property
    def failing_seeds(self) -> list[int]:
        return [s for p in self.points for s, _, _ in p.with_outcome("not tight")]

    def record(self) -> dict[str, Any]:
        """The JSON form (``autotight check --json``)."""
        return {"problem": self.problem, "constraint_set": self.constraint_set, "params": self.params,
                "over": self.over, "instances": self.instances, "min_fraction": self.min_fraction,
                "seed": self.seed, "solver": self.solver, "accept": self.accept,
                "seed_scheme": "instance t at point i: SeedSequence((seed, i, t))",
                "fraction_rule": "tight / (instances - undecided) >= min_fraction",
                "passed": self.passed, "points": [p.record() for p in self.points],
                "n_solves": self.n_solves, "time_s": self.time_s, "versions": versions()}

    def table(self) -> str:
        """A text table: per point tight, undecided, not tight, the fraction and the failing seeds."""
        lines = [f"problem {self.problem}  set {self.constraint_set}  params {self.params}  "
                 f"{self.instances} instances per point  seed {self.seed}",
                 f"pass: tight / (instances − undecided) ≥ {self.min_fraction:g} at every point", "",
                 f"{'point':<22}{'constraints':>12}{'tight':>7}{'undecided':>11}{'not tight':>11}"
                 f"{'fraction':>10}  {'':<5} failing seeds"]
        for p in self.points:
            label = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                              for k, v in p.varied.items()) or "(params above)"
            ncons = "/".join(str(n) for n in sorted(set(p.n_constraints))) or "—"
            bad = " ".join(str(s) for s, _, _ in p.with_outcome("not tight"))
            und = " ".join(str(s) for s, _, _ in p.with_outcome("undecided"))
            lines.append(f"{label:<22}{ncons:>12}{p.count('tight'):>7}{p.count('undecided'):>11}"
                         f"{p.count('not tight'):>11}{p.fraction:>10.2f}  {'ok' if p.passed else 'FAIL':<5} {bad}"
                         + (f"  (undecided: {und})" if und else ""))
        lines += ["", f"{'PASSED' if self.passed else 'FAILED'}: {sum(p.passed for p in self.points)} of "
                      f"{len(self.points)} points reach {self.min_fraction:g}; {self.n_solves} SDP solves, "
                      f"{self.time_s:.1f} s"]
        failing = next((p for p in self.points if p.with_outcome("not tight")), None)
        if failing is not None:
            ps = " ".join(f"-p {k}={v}" for k, v in failing.params.items())
            cs = self.constraint_set if self.constraint_set in ("paper", "primary") else "FILE"
            seed = failing.with_outcome('not tight')[0][0]
            lines.append(f"re-run one: autotight solve {self.problem} {ps} --seed {seed} "
                         f"--set {cs}")
        return "\n".join(lines)

    def failure_message(self) -> str:
        """Which points failed, with every failing seed and its verdict."""
        out = [f"{self.constraint_set} constraints do not suffice for {self.problem} at {self.params}:"]
        for p in self.points:
            if p.passed:
                continue
            out.append(f"  {p.varied or p.params}: {p.count('tight')} tight, {p.count('undecided')} undecided, "
                       f"{p.count('not tight')} not tight of {len(p.seeds)} (fraction {p.fraction:.2f} < "
                       f"{p.min_fraction:g})")
            out += [f"    seed {s}: not tight, log SVR {v:.2f} ({r})" for s, r, v in p.with_outcome("not tight")]
            out += [f"    seed {s}: undecided, log SVR {v:.2f} ({r})" for s, r, v in p.with_outcome("undecided")]
        return "\n".join(out)


def range_of(constraints: ConstraintsLike) -> dict[str, list[Any]] | None:
    """The range a saved range set was learned over (``info["range"]["over"]``), else None."""
    if isinstance(constraints, ConstraintSet):
        rng = (getattr(constraints.discovered, "info", None) or {}).get("range")
        if isinstance(rng, dict) and rng.get("over"):
            return {k: list(v) for k, v in rng["over"].items()}
    return None


def solve_points(problem: Problem, sets: Mapping[str, ConstraintsLike], points: Sequence[tuple[dict, dict]],
                 instances: int, seed: int, *, min_fraction: float = 1.0, solver: Any = None,
                 criteria: Criteria = Criteria(), n_random: int = 1,
                 on_result: Callable[[SolveResult], None] | None = None) -> tuple[dict[str, list[PointResult]], int]:
    """Solve ``instances`` fresh instances per point with each set (one model and local search per instance,
    shared by the sets).  Returns {set name: [PointResult per point]} and the number of SDP solves.
    ``on_result`` is called with every ``SolveResult`` (e.g. for a test's own assertions)."""
    for cons in sets.values():
        if isinstance(cons, ConstraintSet) and cons.problem != problem.name:
            raise ParameterError(f"the constraint set is for {cons.problem!r}, not {problem.name!r}")
    out = {name: [PointResult(full, varied, min_fraction) for full, varied in points] for name in sets}
    n_solves = 0
    for i, (full, _) in enumerate(points):
        for t in range(instances):
            s = instance_seed(seed, i, t)
            ev = evaluate(problem, full, s, sets, config=solver, criteria=criteria, n_random=n_random)
            for name, cons in sets.items():
                r = ev.results[name]
                row = summary(r)
                pr = out[name][i]
                if not isinstance(r, NotInstantiated):
                    pr.set_label = set_name(cons, ev.model)
                pr.add(s, row)
                n_solves += row["calls"]
                if on_result is not None and isinstance(r, SolveResult):
                    on_result(r)
    return out, n_solves


def check_sufficient(problem: str | Problem, constraints: ConstraintsLike = "paper",
                     sigmas: Sequence[float] | None = None, instances: int = 10, min_fraction: float = 1.0,
                     params: Mapping[str, Any] | None = None, seed: int = 0, solver: Any = None, *,
                     over: Mapping[str, Sequence[Any]] | None = None, criteria: Criteria = Criteria(),
                     n_random: int = 1, on_result: Callable[[SolveResult], None] | None = None) -> SufficiencyReport:
    """Solve ``instances`` fresh instances per point with ``constraints`` and count the outcomes.

    constraints: "paper", "primary" or a ``ConstraintSet``.  sigmas/over: the points (module
    docstring).  min_fraction F: a point passes when tight / (instances − undecided) ≥ F.
    n_random: random-start local solves per instance (0: from the ground truth only).
    on_result: called with each instance's ``SolveResult``.
    """
    prob = problem if isinstance(problem, Problem) else load(problem)
    if isinstance(instances, bool) or not isinstance(instances, (int, np.integer)) or instances < 1:
        raise ParameterError(f"instances must be an int ≥ 1, got {instances!r}")
    if not (0.0 <= float(min_fraction) <= 1.0):
        raise ParameterError(f"min_fraction must be in [0, 1], got {min_fraction!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f"seed must be a non-negative int, got {seed!r}")
    n_random = count_arg(n_random, "n_random")
    if constraints is None or isinstance(constraints, str):
        if constraints not in (None, "paper", "primary"):
            raise ParameterError(f"unknown constraint set {constraints!r}; use paper, primary or a saved set")
    elif not isinstance(constraints, ConstraintSet):
        raise ParameterError("constraints must be 'paper', 'primary' or a ConstraintSet (a list of constraints "
                             "belongs to one instance, not to a range)")
    varied = dict(over or {})
    if sigmas is not None:
        if "sigma" in varied:
            raise ParameterError("give the noise levels once: sigmas or over['sigma']")
        if "sigma" not in prob.params:
            raise ParameterError(f"problem {prob.name} has no 'sigma' parameter")
        varied["sigma"] = list(sigmas)
    if not varied:
        varied = {k: v for k, v in (range_of(constraints) or {}).items() if k not in (params or {})}
    over_ = parse_over(prob, varied)
    points = points_of(prob, params, over_)
    for full, _ in points:  # before any work: every point's SDP must fit, and the instances must finish
        check_size(prob, full, solver)
    check_count(prob, points[0][0], f"instances {instances}", int(instances) * len(points), per_item=2 + n_random,
                what=f"instances ({len(points)} points)")
    t0 = time.perf_counter()
    name = "set" if isinstance(constraints, ConstraintSet) else (constraints or "default")
    res, n = solve_points(prob, {name: constraints}, points, int(instances), int(seed),
                          min_fraction=float(min_fraction), solver=solver, criteria=criteria, n_random=n_random,
                          on_result=on_result)
    label = next((p.set_label for p in res[name] if p.set_label), "")
    if not label:  # no instance was solved (every one failed to instantiate the set)
        label = "discovered" if isinstance(constraints, ConstraintSet) else (constraints or "default")
    return SufficiencyReport(prob.name, label, {k: v for k, v in points[0][0].items() if k not in over_}, over_,
                             int(instances), float(min_fraction), int(seed), res[name], n,
                             time.perf_counter() - t0, getattr(solver, "backend", "clarabel"), criteria.accept)
