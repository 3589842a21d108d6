"""Every constraint of an SDP holds at the feasible points the tool holds, or no verdict is given.

A redundant constraint is a claim: ⟨A, ΘᵀΘ⟩ = b at *every* feasible Θ.  A set that breaks it (an edited
set file, a list of constraints from Python, a module whose sampler does not explore its variety) cuts
off feasible points, and the SDP's bound is then no bound on the QCQP: a TIGHT verdict from it would be
false.  Before any verdict, ``check_valid`` evaluates every constraint at the feasible points of the
instance that the tool holds (the ground truth, the local solutions, the state recovered from the SDP and
its refinement).

The measure is the relative violation of a constraint at a point Θ (d × N):

    v = |⟨A, ΘᵀΘ⟩ − b| / max(Σ_ij |A_ij|·‖θ_i‖·‖θ_j‖ + |b|,  MAG_FLOOR_REL·‖Θ‖_F²)

(θ_i: column i of Θ), the residual against the magnitude of the terms it sums: 0 for a valid constraint
up to roundoff, of order 1 for an arbitrary one.  ``VALID_RTOL`` is the tool's tolerance on it, a
constant no file or option can loosen.  A failure raises ``InvalidConstraintError`` naming the
constraint, its factor, the point and the violation.  A violated *primary* constraint means the point
itself is not feasible (a local solver or recovery that leaves the variety): a ``ProblemModuleError``.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from .errors import AutotightError, ProblemModuleError
from .model import Constraint
from .svec import stored_entries

#: largest relative violation (module docstring) of a constraint at a feasible point: far above the
#: roundoff of a lifting computed from a state on its manifold (≤ 1e-12 on the shipped problems), far
#: below the violation of a constraint that does not hold (≥ 1e-4 for a shifted b or a pinned block)
VALID_RTOL = 1e-6
#: floor of the denominator relative to ‖Θ‖_F²: a constraint whose terms all vanish at Θ is judged
#: against the point's own scale, not against roundoff-sized terms
MAG_FLOOR_REL = 1e-8


class InvalidConstraintError(AutotightError):
    """A constraint of the set does not hold at a feasible point: the set is not valid for the problem."""


def stacked_entries(constraints: Sequence[Constraint]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(row, col, value, owner) of every stored entry of every constraint's A, in one pass
    (``svec.stored_entries``)."""
    return stored_entries([c.A for c in constraints])


def relative_violations(constraints: Sequence[Constraint], thetas: Sequence[np.ndarray]) -> np.ndarray:
    """The relative violation of the module docstring, (n_points, n_constraints); Θ each (N,) or (d, N).
    Works on the stored entries only (never forms ΘᵀΘ); a non-finite point gives inf."""
    r, c, v, owner = stacked_entries(constraints)
    b = np.array([k.b for k in constraints], dtype=float)
    out = np.zeros((len(thetas), len(constraints)))
    for p, theta in enumerate(thetas):
        T = np.atleast_2d(np.asarray(theta, dtype=float))
        if not np.all(np.isfinite(T)):
            out[p] = np.inf
            continue
        norms = np.linalg.norm(T, axis=0)
        value = np.bincount(owner, weights=v * np.sum(T[:, r] * T[:, c], axis=0), minlength=len(constraints)) - b
        mag = np.bincount(owner, weights=np.abs(v) * norms[r] * norms[c], minlength=len(constraints)) + np.abs(b)
        floor = MAG_FLOOR_REL * float(np.sum(T * T))
        out[p] = np.abs(value) / np.maximum(mag, max(floor, 1e-300))
    return out


def describe(c: Constraint) -> str:
    """A constraint's name for a message: its name, family and factor."""
    name = c.name or c.identity or "unnamed"
    where = f", factor {c.factor}" if c.factor else ""
    return f"{name!r} ({c.family}{where})"


def check_valid(problem_name: str, constraints: Sequence[Constraint], points: Mapping[str, np.ndarray],
                rtol: float = VALID_RTOL) -> None:
    """Raise unless every constraint holds at every point (relative violation ≤ ``rtol``).

    points: label → lifted feasible point Θ ((N,) or (d, N)), e.g. {"the ground truth": Θ}.  The worst
    violation is named; a primary or homogenising constraint violated means the point is infeasible
    (``ProblemModuleError``), any other constraint is invalid (``InvalidConstraintError``)."""
    if not constraints or not points:
        return
    labels = list(points)
    viol = relative_violations(constraints, [points[k] for k in labels])
    if not np.any(viol > rtol):  # also False on NaN-free all-valid data
        return
    primary = np.array([c.family in ("primary", "homogenisation") for c in constraints])
    bad_primary = (viol > rtol) & primary[None, :]
    if bad_primary.any():
        p, k = (int(i) for i in np.unravel_index(np.argmax(np.where(bad_primary, viol, -1.0)), viol.shape))
        raise ProblemModuleError(f"{problem_name}: {labels[p]} is not feasible: it violates the primary constraint "
                                 f"{describe(constraints[k])} (relative violation {viol[p, k]:.2e} > {rtol:g})")
    bad = viol > rtol
    p, k = (int(i) for i in np.unravel_index(np.argmax(np.where(bad, viol, -1.0)), viol.shape))
    n_bad = int(bad.any(axis=0).sum())
    raise InvalidConstraintError(
        f"{problem_name}: constraint {describe(constraints[k])} does not hold at {labels[p]} (relative violation "
        f"{viol[p, k]:.2e} > {rtol:g}; {n_bad} of {len(constraints)} constraints fail): the set is not valid "
        "for this problem")
