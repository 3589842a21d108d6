"""Checks on one instance before its SDP is trusted: finite data, and a cost that matches its lifting.

``check_instance`` is called once per instance by ``autotight.pipeline.solve_instance`` (so by
``solve``, every report trial and discovery's held-out check) and at the start of discovery.  Each
failure is an ``InstanceError`` (an ``AutotightError``) that names what is wrong: the CLI prints
it as one line, and a report records it as the trial's error row.

The cost check: a local solve's cost c must equal the lifted cost
ĉ = ⟨Q, ΘᵀΘ⟩ + cost_offset at its own state (Θ = lift(state)) to ``COST_RTOL`` relative to
the magnitude of the terms summed, S = Σ|Q_ij| |(ΘᵀΘ)_ij| + |cost_offset| (and at least ``COST_ATOL``):
|c − ĉ| ≤ COST_RTOL · max(S, |c|, COST_ATOL).  A wrong lift, cost or Q (or an inconsistent
``cost_offset``) breaks it; rounding and the local solver's stopping tolerance do not.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np
import scipy.sparse as sp

from .errors import AutotightError

#: relative tolerance of the cost check (see the module docstring)
COST_RTOL = 1e-6
#: absolute floor of the scale in the cost check (a zero-cost instance)
COST_ATOL = 1e-12


class InstanceError(AutotightError):
    """An instance whose data or costs cannot give a meaningful SDP (NaN/inf, or a cost mismatch)."""


def _nonfinite(values: np.ndarray) -> str:
    v = np.asarray(values, dtype=float)
    n_nan, n_inf = int(np.isnan(v).sum()), int(np.isinf(v).sum())
    return ", ".join(s for s in (f"{n_nan} NaN" if n_nan else "", f"{n_inf} inf" if n_inf else "") if s)


def check_data(problem: Any, inst: Any, model: Any) -> None:
    """The measurements (weights included), Q and the primary constraints hold only finite numbers."""
    for key, value in (inst.measurements or {}).items():
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            continue  # not numeric data (names, options): nothing to check
        bad = _nonfinite(arr)
        if bad:
            raise InstanceError(f"{problem.name}: measurement {key!r} has non-finite entries ({bad})")
    bad = _nonfinite(model.Q.data)
    if bad:
        raise InstanceError(f"{problem.name}: the cost matrix Q has non-finite entries ({bad})")
    cons = model.primary()
    if np.all(np.isfinite(np.concatenate([c.A.data for c in cons] + [[c.b for c in cons]]))):
        return  # one pass over the stored entries (no per-constraint copies)
    for c in cons:
        bad = _nonfinite(np.append(c.A.data, c.b))
        if bad:
            raise InstanceError(f"{problem.name}: constraint {c.name or c.family!r} has non-finite entries ({bad})")


def lifted_cost(model: Any, Theta: np.ndarray) -> tuple[float, float]:
    """(⟨Q, ΘᵀΘ⟩ + cost_offset, Σ|Q_ij||(ΘᵀΘ)_ij| + |cost_offset|) for Θ of shape (N,) or (d, N)."""
    T = np.atleast_2d(np.asarray(Theta, dtype=float))
    Q = sp.csr_array(model.Q)
    QT = Q @ T.T  # (N, d)
    value = float(np.sum(T.T * QT)) + float(model.cost_offset)
    absQ = abs(Q)
    G = np.abs(T.T)
    scale = float(np.sum(G * (absQ @ G))) + abs(float(model.cost_offset))  # ≥ Σ|Q_ij||X_ij| by Cauchy-Schwarz
    return value, scale


def check_costs(problem: Any, inst: Any, model: Any, results: Iterable[Any], rtol: float = COST_RTOL) -> None:
    """Every local result's cost is finite and the first one's equals its lifted cost (module docstring)."""
    results = list(results)
    for r in results:
        if not np.isfinite(r.cost):
            raise InstanceError(f"{problem.name}: a local solve ended with cost {r.cost} "
                                "(non-finite data, or a local solver that diverged)")
    if not results:
        return
    r = results[0]
    Theta = problem.lift(inst, r.state)
    T = np.atleast_2d(np.asarray(Theta, dtype=float))
    N = model.variables.N
    if T.shape[-1] != N:
        raise InstanceError(f"{problem.name}: lift returned {T.shape[-1]} columns, the model has N = {N}")
    if not np.all(np.isfinite(T)):
        raise InstanceError(f"{problem.name}: lift of the local solution has non-finite entries ({_nonfinite(T)})")
    value, scale = lifted_cost(model, T)
    err = abs(float(r.cost) - value)
    if err > rtol * max(scale, abs(float(r.cost)), COST_ATOL):
        raise InstanceError(f"{problem.name}: the local cost {r.cost:.10g} differs from ⟨Q, lift(x)lift(x)ᵀ⟩ + "
                            f"cost_offset = {value:.10g} at the same state (relative {err / max(scale, COST_ATOL):.1e} "
                            f"> {rtol:g}); lift, cost and build disagree")


def check_instance(problem: Any, inst: Any, model: Any, local: Any) -> None:
    """``check_data`` and ``check_costs`` on the local search ``local`` (from the truth first)."""
    check_data(problem, inst, model)
    check_costs(problem, inst, model, [local.from_truth, *local.from_random])
