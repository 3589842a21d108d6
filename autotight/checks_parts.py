"""``check_problem``'s checks of how a module behaves beyond one point, and of its optional parts.

- ``sample-spread``: the samples move.  The rank of the lifted samples' differences from the lifted
  truth, rank[vec(Θ_i) − vec(Θ_0)] (singular values above ``SPREAD_RTOL``·max(1, ‖Θ_0‖)), must reach
  min(n, dim), n the samples and dim the variety's local dimension at the truth as the primary
  constraints give it: the free entries of Θ (all but the h block) minus the rank of their Jacobian
  there (rows normalised, relative rank tolerance ``JACOBIAN_RTOL``; an upper bound on the true
  dimension when some of the set is implied by the rest only to second order, as for matrix liftings
  whose rows are tied by the h block).  When Θ has more than ``MAX_TANGENT`` free entries
  dim is not computed and min(n, 2) is required (samples that are not all equal).  A sampler that
  returns its nominal state, or one fixed state, fails; discovery would learn constraints valid at
  that point only.
- ``random-state``: ``random_state`` (the module's, or the default from ``sample``) lifts onto the
  primary constraints (relative violation ≤ ``checks.FEAS_TOL``).
- ``local-descent-perturbed``: the local solver started at a random state ends at a cost below the
  start's by more than ``DESCENT_MARGIN`` relative (a solver that returns its start fails) and on the
  primary constraints; whether it ends above the local minimum from the truth (a trapped start, normal
  from a random start) is recorded as a measurement.
- ``errors``: ``errors`` (the module's or the default) returns finite floats at the truth and a sample.
- ``marginal_log_svr`` (when defined): a float at the rank-1 X = lift(truth)ᵀlift(truth), above
  ``tightness.Criteria().min_log_svr`` (a rank-1 X must read as rank 1); skipped above ``MAX_DENSE_X`` columns.
- the fields of ``META`` (``sigmas``, ``paper_claim``, ``default_groups``, ``carry_to``, ``check_params``): as
  ``autotight.module_parts`` reads them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from .errors import AutotightError
from .model import Model
from .problem import Instance, Problem, State
from .svec import as_theta

#: a sample counts as moved when a singular value of the differences exceeds this × max(1, ‖Θ_0‖)
SPREAD_RTOL = 1e-6
#: relative rank tolerance of the normalised Jacobian of the primary constraints
JACOBIAN_RTOL = 1e-8
#: largest number of free entries of Θ for which the variety's dimension is computed (a dense SVD)
MAX_TANGENT = 1500
#: the local solver from a random state must lower the cost by more than this, relative to |cost(start)|
DESCENT_MARGIN = 1e-6
#: a local solve from a random state counts as trapped above the truth's local minimum by this, relative
TRAP_RTOL = 1e-4
#: marginal_log_svr is called on the dense rank-1 X only up to this many columns
MAX_DENSE_X = 2000


def variety_dimension(model: Model, Theta: np.ndarray) -> int | None:
    """The local dimension of the primary constraints' variety at Θ (module docstring), or None when too large."""
    T = np.atleast_2d(np.asarray(Theta, dtype=float))
    V = model.variables
    d, N = V.d, V.N
    h = V.sizes["h"]
    free = d * (N - h)
    if free > MAX_TANGENT:
        return None
    rows = []
    for c in model.primary():
        if c.family == "homogenisation":
            continue
        G = 2.0 * (sp.csr_array(c.A) @ T.T).T  # ∂ tr(Θ A Θᵀ) / ∂Θ = 2ΘA (A symmetric), (d, N)
        g = G[:, h:].ravel()
        n = np.linalg.norm(g)
        if n > 0:
            rows.append(g / n)
    if not rows:
        return free
    s = np.linalg.svd(np.array(rows), compute_uv=False)
    return free - int(np.sum(s > JACOBIAN_RTOL * s[0]))


def spread_rank(thetas: list[np.ndarray]) -> int:
    """rank[vec(Θ_i) − vec(Θ_0)] with the tolerance of the module docstring."""
    base = np.ravel(thetas[0])
    D = np.array([np.ravel(t) - base for t in thetas[1:]])
    if not D.size:
        return 0
    s = np.linalg.svd(D, compute_uv=False)
    return int(np.sum(s > SPREAD_RTOL * max(1.0, float(np.linalg.norm(base)))))


def check_spread(model: Model, thetas: list[np.ndarray], out: Any) -> None:
    """``sample-spread`` (module docstring); ``thetas[0]`` is the lifted truth."""
    n = len(thetas) - 1
    dim = variety_dimension(model, thetas[0])
    need = min(n, dim) if dim is not None else min(n, 2)
    rank = spread_rank(thetas)
    out.measurements["sample_spread_rank"] = float(rank)
    if dim is not None:
        out.measurements["variety_dimension"] = float(dim)
    where = f"the variety's dimension at the truth is {dim}" if dim is not None else \
        f"Θ has more than {MAX_TANGENT} free entries: its dimension is not computed"
    ok = rank >= need
    (out.passed if ok else out.failures).append(
        f"sample-spread: {n} samples span {rank} directions around lift(truth) (need {need}; {where})" if ok else
        f"sample-spread: {n} samples span only {rank} direction(s) around lift(truth), need {need} ({where}): "
        "sample() does not spread its states (it returns the nominal state or a fixed one?), so discovery would "
        "learn constraints valid only there")


def check_random_state(prob: Problem, inst: Instance, model: Model, rng: np.random.Generator, out: Any,
                       feas_tol: float) -> State:
    """``random-state`` (module docstring); returns the state."""
    from .discovery.samples import relative_violation

    start = prob.random_state(inst, rng)
    T = as_theta(prob.lift(inst, start))
    cons = model.primary()
    v = relative_violation(cons, T[None])
    worst = float(v.max()) if v.size else 0.0
    out.measurements["random_state_violation"] = worst
    what = "the module's" if "random_state" not in prob.derived else "the default (sample at META.random_spread)"
    ok = worst <= feas_tol
    name = cons[int(np.argmax(v))].name if v.size else ""
    (out.passed if ok else out.failures).append(
        f"random-state: {what} random state lifts onto the primary constraints (relative violation {worst:.1e})"
        if ok else f"random-state: {what} random state violates primary constraint {name!r} by {worst:.1e} "
                   f"(relative; tolerance {feas_tol:g})")
    return start


def check_perturbed_descent(prob: Problem, inst: Instance, model: Model, start: State, truth_cost: float,
                            out: Any, feas_tol: float) -> None:
    """``local-descent-perturbed`` (module docstring)."""
    from .discovery.samples import relative_violation

    c0 = prob.cost(inst, start)
    res = prob.local_solve(inst, start)
    out.measurements |= {"cost_random_start": c0, "cost_from_random_start": res.cost}
    drop = c0 - res.cost
    ok = np.isfinite(res.cost) and drop > DESCENT_MARGIN * max(abs(c0), 1e-12)
    (out.passed if ok else out.failures).append(
        f"local-descent-perturbed: from a random state the local solver lowers the cost {c0:.6g} → {res.cost:.6g}"
        if ok else f"local-descent-perturbed: from a random state the local solver does not descend (cost "
                   f"{c0:.10g} → {res.cost:.10g}; needs a drop above {DESCENT_MARGIN:g} relative): it returns its "
                   "start or stops at once")
    v = relative_violation(model.primary(), as_theta(prob.lift(inst, res.state))[None])
    worst = float(v.max()) if v.size else 0.0
    if worst > feas_tol:
        out.failures.append(f"local-descent-perturbed: the local solution from a random state violates the primary "
                            f"constraints by {worst:.1e} (relative; tolerance {feas_tol:g})")
    out.measurements["trapped_from_random_start"] = float(res.cost - truth_cost > TRAP_RTOL * max(abs(truth_cost),
                                                                                                1e-12))


def check_errors(prob: Problem, inst: Instance, sample: State, out: Any) -> None:
    """``errors`` (module docstring)."""
    at_truth = prob.errors(inst, inst.truth)
    at_sample = prob.errors(inst, sample)
    bad = sorted(k for k, v in (at_truth | at_sample).items() if not np.isfinite(v))
    what = "the module's" if "errors" not in prob.derived else "the default"
    if bad:
        out.failures.append(f"errors: {what} errors are not finite for {', '.join(bad)}")
        return
    shown = ", ".join(f"{k} {v:.2g}" for k, v in at_sample.items()) or "none"
    out.passed.append(f"errors: {what} errors are finite floats (at a sample: {shown})")


def check_marginal(prob: Problem, inst: Instance, theta: np.ndarray, out: Any) -> None:
    """``marginal_log_svr`` (module docstring), when the module defines it."""
    from .tightness import Criteria

    if not hasattr(prob.module, "marginal_log_svr"):
        return
    T = np.atleast_2d(theta)
    if T.shape[1] > MAX_DENSE_X:
        out.warnings.append(f"marginal_log_svr: not checked (N = {T.shape[1]} > {MAX_DENSE_X}; give smaller "
                            "META.check_params)")
        return
    v = prob.marginal_log_svr(inst, T.T @ T, None)
    need = Criteria().min_log_svr
    out.measurements["marginal_log_svr_truth"] = v
    ok = v > need
    (out.passed if ok else out.failures).append(
        f"marginal_log_svr: {v:.3g} on the rank-1 X of the lifted truth" if ok else
        f"marginal_log_svr: {v:.3g} ≤ {need:g} on the rank-1 X of the lifted truth: it does not read rank 1")


def check_declared(prob: Problem, out: Any) -> None:
    """Every field of the module's ``META`` that it gives (``module_parts.READERS``) reads without error."""
    from .meta import Meta
    from .module_parts import READERS

    for part, read in READERS.items():
        name = part.split(".", 1)[1]
        if getattr(prob.meta, name) == getattr(Meta(), name) or any(f.startswith(f"{part}:") for f in out.failures):
            continue  # not given, or reported already (META.check_params, read first)
        try:
            read(prob)
        except AutotightError as e:
            out.failures.append(f"{part}: {str(e).splitlines()[0]}")
        else:
            out.passed.append(f"{part}: valid")
