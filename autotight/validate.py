"""Checks on one instance before its SDP is trusted: finite data, and a cost that matches its lifting.

``check_instance`` is called once per instance by ``autotight.pipeline.solve_instance`` (so by
``solve``, every report trial and discovery's held-out check) and at the start of discovery.  Each
failure is an ``InstanceError`` (an ``AutotightError``) that names what is wrong: the CLI prints
it as one line, and a report records it as the trial's error row.

The conditioning check: the cost's weights (the eigenvalues of Q's diagonal blocks) may spread by at
most ``MAX_COST_CONDITION``; beyond it the solver's relative accuracy cannot resolve the lightest
terms, and its verdicts would rest on a tolerance larger than the cost.

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
#: the largest spread of the cost's weights (``cost_condition``) a solve is attempted with: measured on
#: rotation averaging, anisotropy a gives κ = a²; at κ = 1e8 (a = 1e4) 8 of 8 solves (M = 3, 10; seeds 0-3)
#: ended AlmostSolved, most judged on a cost tolerance above the cost itself; continuous time at σ = 1e-5
#: (κ = 2.5e8) ended AlmostSolved with P = 2177 against U = 0.12
MAX_COST_CONDITION = 1e8
#: an eigenvalue of a cost block counts as zero below this × the block's size × its largest
ZERO_RTOL = 1e-13


class InstanceError(AutotightError):
    """An instance whose data or costs cannot give a meaningful SDP (NaN/inf, or a cost mismatch)."""


def _nonfinite(values: np.ndarray) -> str:
    v = np.asarray(values, dtype=float)
    n_nan, n_inf = int(np.isnan(v).sum()), int(np.isinf(v).sum())
    return ", ".join(s for s in (f"{n_nan} NaN" if n_nan else "", f"{n_inf} inf" if n_inf else "") if s)


def check_measurements(problem: Any, inst: Any) -> None:
    """The measurements (weights included) hold only finite numbers."""
    for key, value in (inst.measurements or {}).items():
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            continue  # not numeric data (names, options): nothing to check
        bad = _nonfinite(arr)
        if bad:
            raise InstanceError(f"{problem.name}: measurement {key!r} has non-finite entries ({bad})")


def cost_condition(model: Any) -> tuple[float, str, str]:
    """(κ, block of the largest, block of the smallest): the spread of the cost's weights, κ = the largest
    |eigenvalue| of Q's diagonal blocks (every block but h) over the smallest one above roundoff
    (``ZERO_RTOL`` × its block's largest).  κ = 1 when Q has no such block."""
    V = model.variables
    Q = sp.coo_array(model.Q)
    names = [n for n in V.names if n != "h"]
    start = np.array([V.offsets[n] for n in names], dtype=np.int64)
    size = np.array([V.sizes[n] for n in names], dtype=np.int64)
    owner = np.full(V.N, -1, dtype=np.int64)
    for k, (o, m) in enumerate(zip(start, size)):
        owner[o:o + m] = k
    keep = (owner[Q.row] >= 0) & (owner[Q.row] == owner[Q.col]) & (Q.data != 0)
    blocks = np.unique(owner[Q.row[keep]])
    if not blocks.size:
        return 1.0, "", ""
    lmax, lmin, at_max, at_min = 0.0, np.inf, "", ""
    r, c, v, b = Q.row[keep], Q.col[keep], Q.data[keep], owner[Q.row[keep]]
    for m in np.unique(size[blocks]):  # blocks of one size: one batched eigvalsh
        ids = blocks[size[blocks] == m]
        slot = np.full(len(names), -1, dtype=np.int64)
        slot[ids] = np.arange(ids.size)
        sel = slot[b] >= 0
        B = np.zeros((ids.size, m, m))
        np.add.at(B, (slot[b[sel]], r[sel] - start[b[sel]], c[sel] - start[b[sel]]), v[sel])
        lam = np.abs(np.linalg.eigvalsh(0.5 * (B + B.transpose(0, 2, 1))))
        top = lam.max(axis=1)
        pos = np.where(lam > ZERO_RTOL * m * top[:, None], lam, np.inf)
        i, j = int(np.argmax(top)), int(np.argmin(pos.min(axis=1)))
        if top[i] > lmax:
            lmax, at_max = float(top[i]), names[ids[i]]
        if pos[j].min() < lmin:
            lmin, at_min = float(pos[j].min()), names[ids[j]]
    return (lmax / lmin if np.isfinite(lmin) and lmin > 0 else 1.0), at_max, at_min


def check_conditioning(problem: Any, model: Any) -> float:
    """Refuse a cost whose weights spread beyond ``MAX_COST_CONDITION`` (``cost_condition``); returns κ."""
    kappa, big, small = cost_condition(model)
    if kappa > MAX_COST_CONDITION:
        where = f"block {big}" if big == small else f"blocks {big} and {small}"
        raise InstanceError(f"{problem.name}: the cost's weights have condition number {kappa:.1e} ({where}) > "
                            f"{MAX_COST_CONDITION:.0e}: beyond what the SDP solver resolves (its cost tolerance "
                            "would exceed the cost); use weights closer together (e.g. a smaller anisotropy)")
    return kappa


def check_data(problem: Any, inst: Any, model: Any) -> None:
    """The measurements (weights included), Q and the primary constraints hold only finite numbers, and the
    cost's weights are within what the solver resolves (``check_conditioning``)."""
    check_measurements(problem, inst)
    bad = _nonfinite(model.Q.data)
    if bad:
        raise InstanceError(f"{problem.name}: the cost matrix Q has non-finite entries ({bad})")
    check_conditioning(problem, model)
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
