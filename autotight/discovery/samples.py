"""Feasible samples of an instance, lifted once and shared by every learning group."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import LearningError
from ..model import Constraint, Model
from ..problem import Instance, Problem
from ..svec import as_theta


@dataclass
class SampleBank:
    """Θ of S feasible states near a nominal state: ``thetas`` is (S, d, N)."""

    thetas: np.ndarray

    @property
    def size(self) -> int:
        return self.thetas.shape[0]


def draw(problem: Problem, inst: Instance, n: int, rng: np.random.Generator, spread: float | None,
         max_growth: float = 1e3) -> SampleBank:
    """n samples from the problem's sampler around the ground truth, lifted.

    A sample whose lifting is not finite or exceeds ``max_growth`` times the largest entry of the
    nominal lifting is drawn again: near a Cayley singularity (angle π) the residual variables blow
    up and would wreck the conditioning of the data.
    """
    spread = problem.spread if spread is None else spread
    scale = max_growth * max(1.0, float(np.abs(as_theta(problem.lift(inst, inst.truth))).max()))
    thetas: list[np.ndarray] = []
    tries = 0
    while len(thetas) < n:
        tries += 1
        if tries > 10 * n + 100:
            raise LearningError(f"the sampler keeps returning liftings that are not finite or exceed {scale:.3g}; "
                                f"reduce the spread ({spread:g})")
        T = as_theta(problem.lift(inst, problem.sample(inst, rng, inst.truth, spread)))
        if np.all(np.isfinite(T)) and np.abs(T).max() <= scale:
            thetas.append(T)
    return SampleBank(np.stack(thetas))


def residuals(constraints: Sequence[Constraint], thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(⟨A,ΘᵀΘ⟩ − b, Σ|A_ij|‖θ_i‖‖θ_j‖ + |b|) for every sample and constraint, each (S, n_c).

    θ_i is column i of Θ.  Their ratio is the relative violation: 0 for a valid constraint,
    up to 1 for none at all.  Works on the sparse entries only; never forms ΘᵀΘ.
    """
    S = thetas.shape[0]
    norms = np.linalg.norm(thetas, axis=1)  # (S, N)
    val = np.zeros((S, len(constraints)))
    mag = np.zeros((S, len(constraints)))
    for k, c in enumerate(constraints):
        U = sp.coo_array(c.A)
        prod = np.einsum("sdk,sdk->sk", thetas[:, :, U.row], thetas[:, :, U.col]) * U.data
        val[:, k] = prod.sum(axis=1) - c.b
        mag[:, k] = (norms[:, U.row] * norms[:, U.col]) @ np.abs(U.data) + abs(c.b)
    return val, mag


#: the denominator's floor, relative to ‖Θ‖_F² of the sample: a constraint whose terms all (nearly) vanish
#: on a sample (an exact motion prior at the ground truth) is judged by its residual against the sample's
#: scale, not against roundoff-sized terms (which gave "violations" of 0.7 at residuals of 5e-18); with a
#: tolerance of 1e-8 such a constraint must then hold to 1e-16·‖Θ‖_F², i.e. to roundoff
MAG_FLOOR_REL = 1e-8


def relative_violation(constraints: Sequence[Constraint], thetas: np.ndarray) -> np.ndarray:
    """max over samples of |⟨A,ΘᵀΘ⟩ − b| / max(Σ|A_ij θ_iᵀθ_j| + |b|, MAG_FLOOR_REL·‖Θ‖_F²), per constraint."""
    if not constraints:
        return np.zeros(0)
    val, mag = residuals(constraints, thetas)
    floor = MAG_FLOOR_REL * np.sum(np.asarray(thetas, dtype=float) ** 2, axis=tuple(range(1, np.ndim(thetas))))
    return np.max(np.abs(val) / np.maximum(mag, np.maximum(floor, 1e-300)[:, None]), axis=0)


def check_feasible(model: Model, bank: SampleBank, tol: float) -> None:
    """Raise LearningError naming the worst primary constraint if the samples violate it."""
    cons = model.primary()
    viol = relative_violation(cons, bank.thetas)
    if viol.size and viol.max() > tol:
        k = int(np.argmax(viol))
        raise LearningError(
            f"the sampler returned infeasible points: primary constraint {cons[k].name!r} is violated by "
            f"{viol[k]:.1e} (relative; tolerance {tol:g}); fix the problem's sample() or lift()")
