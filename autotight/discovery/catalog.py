"""Learning on every group of an instance: the candidate constraints, keyed by (factor type, identity)."""

from __future__ import annotations

import time
from ..threads import single_blas_thread
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from ..errors import LearningError
from ..model import Constraint, Model
from ..problem import Instance, Problem
from .learn import (Group, LearnedGroup, LearnOptions, SpanningIndex, groups_of, learn_group, monomials_needed,
                    spanning_matrices)
from .samples import SampleBank, check_feasible, draw

Pair = tuple[str, str]  # (factor type, identity within the type)


def by_pair(constraints: Iterable[Constraint]) -> dict[Pair, list[Constraint]]:
    """Learned constraints grouped by their pair: a learned constraint's identity is "type:identity"."""
    out: dict[Pair, list[Constraint]] = {}
    for c in constraints:
        t, _, ident = str(c.identity).partition(":")
        out.setdefault((t, ident), []).append(c)
    return out


@dataclass
class Catalog:
    """Learned groups of one instance; candidates are new relations that passed the held-out check."""

    model: Model
    groups: list[LearnedGroup]
    n_samples: int
    times: dict[str, float] = field(default_factory=dict)

    def candidates(self) -> list[Constraint]:
        N = self.model.variables.N
        return [g.constraint(j, N) for g in self.groups for j in g.candidate_index()]

    def by_pair(self) -> dict[Pair, list[Constraint]]:
        return by_pair(self.candidates())

    def basic(self, group: str) -> list[Constraint]:
        """Every basic solution of a group (spanned or not) that passed the held-out check."""
        g = next(x for x in self.groups if x.group.name == group)
        return [g.constraint(int(j), self.model.variables.N) for j in np.flatnonzero(g.passed())]

    def rejected(self) -> list[tuple[str, str, float]]:
        return [(g.group.name, ident, v) for g in self.groups for ident, v in g.rejected()]


def _sorted_groups(model: Model, groups: Sequence[Group]) -> list[Group]:
    """Smaller groups first, so that relations of shared blocks are learned once."""
    return sorted(groups, key=lambda g: len(model.variables.index(g.blocks)))


def sample_banks(problem: Problem, inst: Instance, model: Model, groups: Sequence[Group], opts: LearnOptions,
                 rng: np.random.Generator) -> tuple[SampleBank, SampleBank, float]:
    t0 = time.perf_counter()
    bank = draw(problem, inst, monomials_needed(model, groups, opts), rng, opts.spread)
    heldout = draw(problem, inst, opts.heldout, rng, opts.spread)
    check_feasible(model, bank, tol=1e-8)
    return bank, heldout, time.perf_counter() - t0


@single_blas_thread
def learn(problem: Problem, inst: Instance, model: Model, rng: np.random.Generator,
          groups: str | Sequence[Sequence[str]] = "factors", opts: LearnOptions = LearnOptions(),
          types: Iterable[str] | None = None, progress=None, whole_nullspace: bool = False,
          names: Iterable[str] | None = None, checked: bool = True) -> Catalog:
    """Learn every group (or only the factors of ``types``, or only the groups ``names``) of one instance
    (``whole_nullspace``, ``checked``: see ``learn.learn_group``)."""
    gs = groups_of(model, groups)
    if types is not None:
        wanted = set(types)
        gs = [g for g in gs if g.type in wanted]
    if names is not None:
        only = set(names)
        gs = [g for g in gs if g.name in only]
    if not gs:
        raise LearningError("no groups to learn on")
    gs = _sorted_groups(model, gs)
    bank, heldout, t_sample = sample_banks(problem, inst, model, gs, opts, rng)
    t0 = time.perf_counter()
    learned: list[LearnedGroup] = []
    spanning = SpanningIndex(spanning_matrices(model) if checked else [])  # grows with each group's new relations
    N = model.variables.N
    for g in gs:
        lg = learn_group(model, g, bank, heldout, opts, spanning=spanning, whole_nullspace=whole_nullspace,
                         checked=checked)
        learned.append(lg)
        for j in lg.candidate_index():
            spanning.add(lg.constraint(j, N).A)
        if progress is not None:
            progress(g.name)
    return Catalog(model, learned, bank.size, {"sampling_s": t_sample, "nullspace_s": time.perf_counter() - t0})


@dataclass
class CarryOver:
    """What instantiating a set of pairs on one instance gave.

    counts[type] = (expected, instantiated): expected = (pairs of that factor type) × (groups of that
    type on the instance), instantiated = the constraints found there that passed the held-out check.
    issues: one line per identity missing or rejected on some group, and per type with a shortfall.
    whole: one line per near-degenerate group (``learn.learn_group``'s ``whole_nullspace``) whose
    identities could not be written accurately (no accurate basic solutions, a wanted identity failed
    the held-out check, or a wanted identity is missing on a ``near_degenerate`` group, whose free
    monomials differ from a generic instance's): every new relation of its orthonormal nullspace basis
    that passed the held-out check is used instead (a superset of the identities' span, so no
    shortfall), counted in ``n_whole``.
    """

    constraints: list[Constraint]
    counts: dict[str, tuple[int, int]]
    issues: list[str]
    whole: list[str] = field(default_factory=list)
    n_whole: int = 0

    def shortfall(self) -> dict[str, tuple[int, int]]:
        return {t: (e, n) for t, (e, n) in self.counts.items() if n < e}

    def message(self) -> str:
        """One line naming every factor type with a shortfall, its counts and the first issue."""
        short = self.shortfall()
        parts = [f"factor type {t!r}: {n} of {e} expected constraints instantiated" for t, (e, n) in short.items()]
        lost = [i for i in self.issues if not i.startswith("factor type")]
        return "; ".join(parts) + (f" (e.g. {lost[0]}; {len(lost)} issue(s))" if lost else "")


@single_blas_thread
def carry_over(problem: Problem, inst: Instance, pairs: Sequence[Pair], rng: np.random.Generator,
               opts: LearnOptions = LearnOptions(), model: Model | None = None,
               groups: str | Sequence[Sequence[str]] = "factors", names: Iterable[str] | None = None) -> CarryOver:
    """Re-learn the groups of the needed types on ``inst`` (only the groups ``names``, if given) and keep
    the given identities, counting per factor type what was expected and what was instantiated (see
    ``CarryOver``)."""
    if not pairs:
        return CarryOver([], {}, [])
    model = model or problem.build(inst)
    types = sorted({t for t, _ in pairs})
    per_type = {t: sum(1 for q in set(pairs) if q[0] == t) for t in types}
    all_groups = groups_of(model, groups)
    if names is not None:
        only = set(names)
        all_groups = [g for g in all_groups if g.name in only]
    n_groups = {t: sum(1 for g in all_groups if g.type == t) for t in types}
    issues: list[str] = [f"factor type {t!r} has no group on this instance" for t in types if n_groups[t] == 0]
    present = [t for t in types if n_groups[t]]
    cat = (learn(problem, inst, model, rng, groups, opts=opts, types=present, whole_nullspace=True, names=names)
           if present else None)
    want = set(pairs)
    out: list[Constraint] = []
    got = {t: 0 for t in types}
    missing: dict[Pair, list[str]] = {}
    whole: list[str] = []
    n_whole = 0
    N = model.variables.N
    for g in cat.groups if cat is not None else []:
        t = g.group.type
        have = {ident: j for j, ident in enumerate(g.identities)}
        wanted_here = [have[key[1]] for key in want if key[0] == t and key[1] in have]
        inaccurate = [g.identities[j] for j in wanted_here if not g.passed()[j]]
        renamed = [key[1] for key in want if key[0] == t and key[1] not in have] if g.near_degenerate else []
        if per_type.get(t) and (g.degenerate is not None or ((inaccurate or renamed) and g.whole is not None)):
            src = g.whole if g.degenerate is None and g.whole is not None else g
            why = g.degenerate or "; ".join(
                ([f"identities {', '.join(inaccurate)} failed the held-out check"] if inaccurate else [])
                + ([f"near-degenerate (smallest singular value kept {g.spectrum_rel[g.rank - 1]:.1e}), identities "
                    f"{', '.join(renamed)} named otherwise here"] if renamed else []))
            new = [src.constraint(j, N) for j in src.candidate_index()]
            out += new
            n_whole += len(new)
            got[t] += per_type[t]
            whole.append(f"{g.group.name}: {why}; its nullspace's {len(new)} new relations used instead of the "
                         f"{per_type[t]} identities")
            continue
        for key in sorted(p for p in want if p[0] == g.group.type):
            j = have.get(key[1])
            if j is None:
                missing.setdefault(key, []).append(g.group.name)
            elif g.passed()[j]:
                out.append(g.constraint(j, N))
                got[key[0]] += 1
            else:
                issues.append(f"{g.group.name}:{key[1]} failed the held-out check ({g.heldout_violation[j]:.1e})")
    for (t, ident), where in missing.items():
        k = len(where)
        issues.append(f"identity {t}:{ident} not found on {k} of {n_groups[t]} groups ({', '.join(where[:3])}"
                      f"{', …' if k > 3 else ''})")
    counts = {t: (per_type[t] * n_groups[t], got[t]) for t in types}
    issues += [f"factor type {t!r}: {n} of {e} expected constraints instantiated"
               for t, (e, n) in counts.items() if n < e]
    return CarryOver(out, counts, issues, whole, n_whole)


def instantiate(problem: Problem, inst: Instance, pairs: Sequence[Pair], rng: np.random.Generator,
                opts: LearnOptions = LearnOptions(), model: Model | None = None,
                groups: str | Sequence[Sequence[str]] = "factors",
                strict: bool = True) -> tuple[list[Constraint], list[str]]:
    """The pairs' constraints on ``inst`` (each passed the held-out check there) and the issues.

    strict: a shortfall (fewer constraints than pairs × groups for some factor type) raises
    LearningError naming the factor types and their counts; with strict=False it is in the issues.
    """
    co = carry_over(problem, inst, pairs, rng, opts, model, groups)
    if strict and co.shortfall():
        raise LearningError(f"the set does not carry over to this instance: {co.message()}")
    return co.constraints, co.issues
