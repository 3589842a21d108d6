"""What ``discover`` hands back: ``DiscoveryResult``, one type and one JSON layout for every case.

``DiscoveryResult.record()`` is the JSON of ``autotight discover --json`` and the ``summary`` saved in the
set file; docs/discovery.md lists its fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..check import PointResult
from ..constraint_set import ConstraintSet
from ..io import versions
from ..model import Constraint, Model
from ..problem import Instance, Problem
from .catalog import Catalog, Pair
from .discovered import DiscoveredSet
from .trainers import Trainer


def _label(varied: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in varied.items()) or "params"


def _evidence(pr: PointResult | None) -> dict[str, Any] | None:
    """Per point: instances, tight, undecided, not tight, fraction, passed, and the failing/undecided seeds."""
    if pr is None:
        return None
    return {"instances": len(pr.seeds), "tight": pr.count("tight"), "undecided": pr.count("undecided"),
            "not_tight": pr.count("not tight"), "fraction": pr.fraction, "passed": pr.passed,
            "failing_seeds": [s for s, _, _ in pr.with_outcome("not tight")],
            "undecided_seeds": [s for s, _, _ in pr.with_outcome("undecided")],
            "failing": [{"seed": s, "reason": r, "log_svr": v} for s, r, v in pr.with_outcome("not tight")],
            "n_constraints": sorted(set(pr.n_constraints))}


def round_record(index: int, points: list[PointResult], n_pairs: int, passed: bool,
                 planned: list[int]) -> dict[str, Any]:
    """One held-out round: the set's size and every point's evidence; ``planned``: per point the seeds of its
    batch (its ``instances`` are fewer when the batch stopped once the point could not pass)."""
    return {"round": index + 1, "n_pairs": n_pairs, "passed": passed,
            "points": [{"varied": p.varied, "planned": k} | (_evidence(p) or {}) for p, k in zip(points, planned)],
            "taken_in": 0, "n_pairs_after": n_pairs}


@dataclass
class PointRecord:
    """One point: its parameters, its training instances (reached or not) and the last held-out batch."""

    index: int
    varied: dict[str, Any]
    params: dict[str, Any]
    train_seeds: list[int]
    reached: list[bool]
    messages: list[str]
    origins: list[str]
    heldout: PointResult | None = None
    paper: PointResult | None = None
    carried: bool = False  # a validation point at a size the set must carry to

    def record(self) -> dict[str, Any]:
        return {"varied": self.varied, "params": self.params, "carried": self.carried,
                "train_seeds": self.train_seeds, "train_origins": self.origins, "reached": self.reached,
                "messages": self.messages, "heldout": _evidence(self.heldout), "paper": _evidence(self.paper)}


@dataclass
class DiscoveryResult:
    """One discovered set and its evidence; ``constraint_set`` is what ``solve``/``check`` take."""

    problem_obj: Problem
    params: dict[str, Any]
    over: dict[str, list[Any]]
    carry_to: dict[str, Any]
    seed: int
    n_train: int
    points: list[PointRecord]
    candidates: list[Pair]
    greedy: list[Pair]
    pairs: list[Pair]
    tight: bool
    dropped_in_verification: list[Pair]
    discovered: DiscoveredSet
    validation: dict[str, Any]
    n_solves: int
    solves_by_stage: dict[str, int]
    times: dict[str, float]
    log: list[dict[str, Any]]
    trainers: list[Trainer]
    paper_span: dict[str, dict] = field(default_factory=dict)
    resembles: dict[str, str] = field(default_factory=dict)
    accept: str = "rank"

    @property
    def problem(self) -> str:
        return self.problem_obj.name

    @property
    def validated(self) -> bool | None:
        """True: every point confirmed (``engine``, step 5), or the budget ran out with every point's latest fresh
        held-out batch passing; False: the budget ran out first; None: no validation (no held-out instances, or
        the set is not tight on its training instances)."""
        return self.validation["passed"]

    @property
    def constraint_set(self) -> ConstraintSet:
        return ConstraintSet(self.discovered)

    @property
    def example(self) -> Trainer:
        """The first training instance the set is tight on (the first one when none is)."""
        return next((tr for tr in self.trainers if tr.reached), self.trainers[0])

    @property
    def instance(self) -> Instance:
        """The instance of ``example`` (``model``, ``constraints`` and ``catalog`` are its own)."""
        return self.example.inst

    @property
    def model(self) -> Model:
        return self.example.model

    @property
    def catalog(self) -> Catalog | None:
        return self.example.catalog

    @property
    def constraints(self) -> list[Constraint]:
        """The set's constraints on ``example``."""
        return [c for p in self.pairs for c in self.example.pairs.get(p, [])]

    @property
    def heldout_fraction(self) -> float | None:
        """The smallest held-out fraction over the points of the last batch (None without one)."""
        fr = [p.heldout.fraction for p in self.points if p.heldout is not None and p.heldout.n_decided]
        return min(fr) if fr else None

    def save(self, path: str | Path, replace: bool = False) -> Path:
        """The set as JSON (``ConstraintSet.load`` reads it), with this record as ``summary``; an existing file
        is kept unless ``replace`` (the set is then saved beside it, ``DiscoveredSet.save``).  Returns the
        path written."""
        return self.discovered.save(path, self.model, self.constraints, {"summary": self.record()},
                                    problem=self.problem_obj, replace=replace)

    def record(self) -> dict[str, Any]:
        """The JSON layout (docs/discovery.md)."""
        n_primary = len(self.model.primary())
        return {"problem": self.problem, "params": self.params, "over": self.over, "carry_to": self.carry_to,
                "seed": self.seed, "accept": self.accept, "tight": self.tight, "validated": self.validated,
                "validation": self.validation, "n_train": self.n_train,
                "n_pairs": len(self.pairs), "pairs": [f"{t}:{i}" for t, i in self.pairs],
                "n_constraints": len(self.constraints), "n_primary": n_primary,
                "n_paper": len(self.model.paper_constraints()),
                "n_candidate_pairs": len(self.candidates), "n_greedy_pairs": len(self.greedy),
                "irreducible": self.tight,
                "dropped_in_verification": [f"{t}:{i}" for t, i in self.dropped_in_verification],
                "points": [p.record() for p in self.points],
                "paper_in_span": self.paper_span, "resembles": self.resembles,
                "n_solves": self.n_solves, "solves_by_stage": self.solves_by_stage, "times": self.times,
                "versions": versions()}

    def table(self) -> str:
        """Per point: training instances reached, held-out evidence of the set and of the paper's families."""
        v = self.validation
        lines = [f"problem {self.problem}  params {self.params}" + (f"  over {self.over}" if self.over else "")
                 + (f"  carry to {self.carry_to}" if self.carry_to else "") + f"  seed {self.seed}",
                 f"{len(self.candidates)} candidate pairs; greedy {len(self.greedy)} → {len(self.pairs)} pairs "
                 f"({len(self.constraints)} constraints on the first training instance it is tight on; paper "
                 f"{len(self.model.paper_constraints())}), "
                 f"{'irreducible over the training instances' if self.tight else 'NOT TIGHT on training'}; "
                 f"{sum(len(p.train_seeds) for p in self.points)} training instances "
                 f"({sum(r.get('taken_in', 0) for r in v['rounds'])} taken in from held-out failures); "
                 f"{self.n_solves} SDP solver calls; {self.times.get('total_s', float('nan')):.1f} s", "",
                 f"{'point':<24}{'trained':>9}{'set: tight (held-out)':>30}{'paper: tight (held-out)':>30}"]
        for p in self.points:
            tr = f"{sum(p.reached)}/{len(p.reached)}" if p.reached else "—"
            lines.append(f"{_label(p.varied):<24}{tr:>9}{_frac(p.heldout):>30}{_frac(p.paper):>30}")
        lines.append("")
        for p in self.points:
            for s, ok, msg, origin in zip(p.train_seeds, p.reached, p.messages, p.origins):
                if not ok:
                    how = ("taken in from held-out, not reached" if origin == "held-out" else
                           "set aside" if any(p.reached) else "not reached")
                    lines.append(f"{how} at {_label(p.varied)} (training seed {s}): {msg}")
        lines.append("pairs: " + (", ".join(f"{t}:{i}" for t, i in self.pairs)
                                  or ("none (the primary constraints suffice)" if self.tight else "none")))
        lines.append(v["message"])
        lines.append("the held-out evidence covers the points above only: at other parameters (another σ or size) "
                     "`autotight check --set FILE` tests the set")
        return "\n".join(lines)


def _frac(h: PointResult | None) -> str:
    if h is None or not h.seeds:
        return "—"
    und = h.count("undecided")
    return (f"{h.count('tight')} of {h.n_decided}" + (f" (+{und} undecided)" if und else "")
            + ("" if h.passed else " FAIL"))
