"""Learning on every group of an instance: the candidate constraints, keyed by (factor type, identity)."""

from __future__ import annotations

import time
from ..threads import single_blas_thread
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import LearningError
from ..model import Constraint, Model
from ..problem import Instance, Problem
from .learn import Group, LearnedGroup, LearnOptions, groups_of, learn_group, monomials_needed, spanning_matrices
from .samples import SampleBank, check_feasible, draw

Pair = tuple[str, str]  # (factor type, identity within the type)


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
        out: dict[Pair, list[Constraint]] = {}
        for c in self.candidates():
            t, ident = c.identity.split(":", 1)
            out.setdefault((t, ident), []).append(c)
        return out

    def basic(self, group: str) -> list[Constraint]:
        """Every basic solution of a group (spanned or not) that passed the held-out check."""
        g = next(x for x in self.groups if x.group.name == group)
        return [g.constraint(j, self.model.variables.N) for j in np.flatnonzero(g.passed())]

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
          types: Iterable[str] | None = None, progress=None) -> Catalog:
    """Learn every group (or only the factors of ``types``) of one instance."""
    gs = groups_of(model, groups)
    if types is not None:
        wanted = set(types)
        gs = [g for g in gs if g.type in wanted]
    if not gs:
        raise LearningError("no groups to learn on")
    gs = _sorted_groups(model, gs)
    bank, heldout, t_sample = sample_banks(problem, inst, model, gs, opts, rng)
    t0 = time.perf_counter()
    learned: list[LearnedGroup] = []
    spanning = spanning_matrices(model)  # grows with each group's new relations
    N = model.variables.N
    for g in gs:
        lg = learn_group(model, g, bank, heldout, opts, spanning=spanning)
        learned.append(lg)
        spanning += [sp.coo_array(lg.constraint(j, N).A) for j in lg.candidate_index()]
        if progress is not None:
            progress(g.name)
    return Catalog(model, learned, bank.size, {"sampling_s": t_sample, "nullspace_s": time.perf_counter() - t0})


@single_blas_thread
def instantiate(problem: Problem, inst: Instance, pairs: Sequence[Pair], rng: np.random.Generator,
                opts: LearnOptions = LearnOptions(), model: Model | None = None,
                groups: str | Sequence[Sequence[str]] = "factors") -> tuple[list[Constraint], list[str]]:
    """Re-learn the factors of the needed types on ``inst`` and keep the given identities.

    Returns the constraints and a list of problems (identities not found or failing the
    held-out check on this instance); the constraints returned all passed that check.
    """
    if not pairs:
        return [], []
    model = model or problem.build(inst)
    types = sorted({t for t, _ in pairs})
    cat = learn(problem, inst, model, rng, groups, opts=opts, types=types)
    want = set(pairs)
    found: dict[Pair, int] = {p: 0 for p in pairs}
    out, issues = [], []
    N = model.variables.N
    for g in cat.groups:
        if g.group.type not in types:
            continue
        for j, ident in enumerate(g.identities):
            key = (g.group.type, ident)
            if key in want:
                if g.passed()[j]:
                    out.append(g.constraint(j, N))
                    found[key] += 1
                else:
                    issues.append(f"{g.group.name}:{ident} failed the held-out check ({g.heldout_violation[j]:.1e})")
    for p, n in found.items():
        if n == 0:
            issues.append(f"identity {p[0]}:{p[1]} not found on this instance")
    return out, issues
