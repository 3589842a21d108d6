"""``check_problem``: does a problem module keep its contract (docs/problem_contract.md)?

Checks, each with a named one-line message (``ProblemCheck.lines``):

- ``cost``: cost(x) = ⟨Q, ΘᵀΘ⟩ + cost_offset at Θ = lift(x), on the truth and fresh samples;
- ``local-cost``: the local solver's reported cost equals the lifted cost of its own result;
- ``sample-feasible``: every primary constraint vanishes on lift(sample(…)) (and on lift(truth));
- ``local-feasible``: … and on lift of the local solver's result started from the truth;
- ``recover``: recover(lift(x)) returns x (every entry of x; a transposed rotation fails);
  entries that lift ignores (shifting them leaves lift(x) unchanged, e.g. marginalised variables) are
  not compared, and the ``cost`` check evaluates cost(x) with the values recover reads for them;
- ``local-descent``: the local solver started from the truth does not increase the cost;
- ``identities``: two factors of one type learn the same identities (``discovery.learn``), so that a
  learned set carries over between factors and instances.  Factors of one type with different
  ``roles`` (e.g. roles left out) give a warning, not a failure;
- ``data``: finite measurements, Q and constraints, and cost weights the solver resolves
  (``autotight.validate.check_data``);
- ``sample-spread``, ``random-state``, ``local-descent-perturbed``, ``errors``, ``marginal_log_svr`` and
  the fields of ``META``: see
  ``autotight.checks_parts``.  Every part a module defines is called; a check that fails, or raises,
  is one FAIL line and the other checks still run.

Relative measures: a quadratic form's value ⟨A, ΘᵀΘ⟩ − b is divided by Σ|A_ij|‖θ_i‖‖θ_j‖ + |b|
(``discovery.samples.residuals``: 0 when it holds exactly, ≤ 1 always); a state entry's
difference by max(1, max |entry|).  An error raised by a module part (``ProblemModuleError`` or any
``AutotightError``), or an exception raised while our code uses its result, fails the check that
called it.  Bad input (``n_samples`` < 1, unknown parameters given) is a ``ParameterError``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .errors import AutotightError, ParameterError, ProblemDefinitionError
from .limits import ONE_RUN_SECONDS, check_count, check_size, sample_seconds
from .model import Constraint, Model
from .problem import SAMPLE_TOL, Instance, Problem, State, load
from .svec import as_theta
from .threads import single_blas_thread

#: relative tolerance of the cost checks (see module docstring)
COST_RTOL = 1e-8
#: relative tolerance of the primary constraints on sampled and locally solved states
FEAS_TOL = SAMPLE_TOL
#: relative tolerance of recover(lift(x)) against x
RECOVER_TOL = 1e-6
#: the local solver from the truth may end this much (relative to |cost(truth)|, floor 1e-12) above it
DESCENT_RTOL = 1e-9


@dataclass
class ProblemCheck:
    """Outcome of ``check_problem``: ``ok`` when nothing failed (warnings are allowed)."""

    problem: str
    path: str | None
    params: dict[str, Any]
    seed: int
    failures: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    passed: list[str] = field(default_factory=list)
    measurements: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failures

    def lines(self) -> list[str]:
        """One readable line per finding: PASS, WARN and FAIL lines, then the verdict."""
        head = f"check {self.problem}" + (f" ({self.path})" if self.path else "") + \
            f"  params {self.params}  seed {self.seed}"
        verdict = "OK" if self.ok else f"FAILED ({len(self.failures)} check(s))"
        return ([head] + [f"PASS {m}" for m in self.passed] + [f"WARN {m}" for m in self.warnings]
                + [f"FAIL {m}" for m in self.failures] + [f"{verdict}, {len(self.warnings)} warning(s)"])

    def record(self) -> dict[str, Any]:
        return {"problem": self.problem, "path": self.path, "params": self.params, "seed": self.seed, "ok": self.ok,
                "failures": self.failures, "warnings": self.warnings, "passed": self.passed,
                "measurements": self.measurements}


def _relative(A: Any, b: float, Theta: np.ndarray) -> float:
    """|⟨A, ΘᵀΘ⟩ − b| / (Σ|A_ij|‖θ_i‖‖θ_j‖ + |b|) for one lifted point."""
    from .discovery.samples import residuals

    val, mag = residuals([Constraint(A, b)], Theta[None])
    return float(abs(val[0, 0]) / max(mag[0, 0], 1e-300))


def _worst_violation(model: Model, thetas: np.ndarray) -> tuple[float, str]:
    from .discovery.samples import relative_violation

    cons = model.primary()
    v = relative_violation(cons, thetas)
    if not v.size:
        return 0.0, ""
    k = int(np.argmax(v))
    return float(v[k]), cons[k].name


def _state_difference(x: State, y: State) -> tuple[float, str]:
    """Largest relative difference over x's numeric entries, and the entry (a missing one counts as ∞)."""
    worst, where = 0.0, ""
    for k, v in x.items():
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            continue
        if k not in y:
            return float("inf"), f"{k} (missing)"
        b = np.asarray(y[k], dtype=float)
        if b.shape != a.shape:
            return float("inf"), f"{k} (shape {b.shape}, expected {a.shape})"
        e = float(np.max(np.abs(a - b), initial=0.0) / max(1.0, float(np.max(np.abs(a), initial=0.0))))
        if not e <= worst:
            worst, where = e, k
    return worst, where


def _unlifted(prob: Problem, inst: Instance, x: State, T: np.ndarray) -> set[str]:
    """Entries of x that lift ignores (shifting them leaves lift(x) unchanged), e.g. marginalised variables."""
    out = set()
    for k, v in x.items():
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            continue
        if not a.size:
            continue
        try:
            T2 = as_theta(prob.lift(inst, dict(x) | {k: a + 1e-3 * (1.0 + np.abs(a))}))
        except AutotightError:  # the shifted entry is not a valid state: lift reads it
            continue
        if T2.shape == T.shape and np.array_equal(T2, T):
            out.add(k)
    return out


class _Checker:
    def __init__(self, prob: Problem, inst: Instance, model: Model, rng: np.random.Generator, out: ProblemCheck):
        self.prob, self.inst, self.model, self.rng, self.out = prob, inst, model, rng, out

    def run(self, name: str, fn: Callable[[], None]) -> None:
        t0 = time.perf_counter()
        try:
            fn()
        except AutotightError as e:
            self.out.failures.append(f"{name}: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
        except Exception as e:  # a module result our own code could not use: reported, the other checks still run
            msg = str(e).splitlines()[0] if str(e) else ""
            self.out.failures.append(f"{name}: {type(e).__name__}" + (f": {msg}" if msg else "")
                                     + " (raised while checking this part)")
        self.out.measurements[f"{name}_s"] = time.perf_counter() - t0

    def verdict(self, name: str, ok: bool, good: str, bad: str) -> None:
        (self.out.passed if ok else self.out.failures).append(f"{name}: {good if ok else bad}")


@single_blas_thread
def check_problem(problem: Problem | str, params: dict[str, Any] | None = None, seed: int = 0, n_samples: int = 5,
                  rng: np.random.Generator | None = None) -> ProblemCheck:
    """Run every check on one instance (``params``: default the module's ``META.check_params``, else PARAMS'
    defaults)."""
    from . import checks_parts as more
    from .module_parts import check_params

    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 1:
        raise ParameterError(f"samples must be an int ≥ 1, got {n_samples!r}")
    prob = load(problem)
    bad_check_params = ""
    if params is None:
        try:
            given = check_params(prob)
        except ProblemDefinitionError as e:  # reported as a failure; the other checks run at the defaults
            given, bad_check_params = {}, str(e).splitlines()[0]
    else:
        given = dict(params)
    full = prob.parse_params(given)
    check_size(prob, full)
    check_count(prob, full, f"samples {n_samples}", n_samples, what="samples", budget=ONE_RUN_SECONDS,
                seconds=sample_seconds)
    out = ProblemCheck(prob.name, prob.path, full, int(seed))
    if bad_check_params:
        out.failures.append(f"META.check_params: {bad_check_params} (checked at the defaults of PARAMS instead)")
    rng = rng if rng is not None else np.random.default_rng([int(seed), 1])
    t0 = time.perf_counter()
    try:
        inst = prob.generate(full, seed)
        model = prob.build(inst)
    except ProblemDefinitionError as e:  # a broken generate or build fails the check; bad parameters raise
        out.failures.append(f"setup: {str(e).splitlines()[0]}")
        return out
    c = _Checker(prob, inst, model, rng, out)
    states: list[State] = [inst.truth]
    thetas: list[np.ndarray] = []
    unlifted: list[set[str]] = []

    def draw() -> None:
        for _ in range(n_samples):
            states.append(prob.sample(inst, rng))
        for i, s in enumerate(states):
            try:
                thetas.append(as_theta(prob.lift(inst, s)))
            except AutotightError as e:
                why = "lift(truth) failed" if i == 0 else \
                    f"lift(sample {i}) failed, so sample() may return states off the constraints"
                raise type(e)(f"{why}: {e}") from e
        unlifted.extend(_unlifted(prob, inst, s, T) for s, T in zip(states, thetas))
        v, name = _worst_violation(model, np.stack(thetas))
        out.measurements["sample_violation"] = v
        c.verdict("sample-feasible", v <= FEAS_TOL,
                  f"the primary constraints hold on lift(truth) and {n_samples} samples (worst relative "
                  f"violation {v:.1e}; tolerance {FEAS_TOL:g})",
                  f"primary constraint {name!r} is violated by {v:.1e} on lift(sample) (relative; tolerance "
                  f"{FEAS_TOL:g}): sample() returns infeasible states or lift() puts entries in the wrong blocks")

    def cost() -> None:
        if "cost" in prob.derived:
            out.passed.append("cost: not defined by the module; derived as ⟨Q, ΘᵀΘ⟩ + cost_offset "
                              "(only local-cost compares it with an independent value)")
            return
        worst, at = 0.0, 0
        for i, (s, T, skip) in enumerate(zip(states, thetas, unlifted)):
            if skip:  # entries lift ignores take the values recover reads from Θ
                rec = prob.recover(inst, T)
                s = dict(s) | {k: rec[k] for k in skip if k in rec}
            e = _relative(model.Q, prob.cost(inst, s) - model.cost_offset, T)
            if not e <= worst:
                worst, at = e, i
        out.measurements["cost_rel_diff"] = worst
        c.verdict("cost", worst <= COST_RTOL,
                  f"cost(x) = ⟨Q, lift(x)lift(x)ᵀ⟩ + offset on {len(states)} states (worst relative difference "
                  f"{worst:.1e}; tolerance {COST_RTOL:g})",
                  f"cost(x) differs from ⟨Q, lift(x)lift(x)ᵀ⟩ + offset by {worst:.1e} (relative; tolerance "
                  f"{COST_RTOL:g}) at {'the truth' if at == 0 else f'sample {at}'}: cost(), lift() or the model's Q "
                  f"is wrong")

    def recover() -> None:
        worst, where, at = 0.0, "", 0
        for i, (s, T, skip) in enumerate(zip(states, thetas, unlifted)):
            e, k = _state_difference({k: v for k, v in s.items() if k not in skip}, prob.recover(inst, T))
            if not e <= worst:
                worst, where, at = e, k, i
        out.measurements["recover_rel_diff"] = worst
        skipped = sorted(set().union(*unlifted))
        note = f"; entries lift ignores, not compared: {', '.join(skipped)}" if skipped else ""
        c.verdict("recover", worst <= RECOVER_TOL,
                  f"recover(lift(x)) = x on {len(states)} states (worst relative difference {worst:.1e}; "
                  f"tolerance {RECOVER_TOL:g}{note})",
                  f"recover(lift(x)) differs from x in entry {where!r} by {worst:.1e} (relative; tolerance "
                  f"{RECOVER_TOL:g}) at {'the truth' if at == 0 else f'sample {at}'}")

    def local() -> None:
        res = prob.local_solve(inst, inst.truth)
        local_cost.append(res.cost)
        c_truth = prob.cost(inst, inst.truth)
        rise = res.cost - c_truth
        out.measurements |= {"cost_truth": c_truth, "cost_local": res.cost, "local_iterations": float(res.iterations)}
        c.verdict("local-descent", rise <= DESCENT_RTOL * max(abs(c_truth), 1e-12 / DESCENT_RTOL),
                  f"the local solver from the truth lowers the cost {c_truth:.6g} → {res.cost:.6g}",
                  f"the local solver started from the truth raises the cost {c_truth:.10g} → {res.cost:.10g}")
        T = as_theta(prob.lift(inst, res.state))
        v, name = _worst_violation(model, T[None])
        out.measurements["local_violation"] = v
        c.verdict("local-feasible", v <= FEAS_TOL,
                  f"the primary constraints hold on lift(local solution) (relative violation {v:.1e})",
                  f"primary constraint {name!r} is violated by {v:.1e} on lift(local solution) (relative; "
                  f"tolerance {FEAS_TOL:g})")
        e = _relative(model.Q, res.cost - model.cost_offset, T)
        out.measurements["local_cost_rel_diff"] = e
        c.verdict("local-cost", e <= COST_RTOL,
                  f"the local solver's cost = ⟨Q, lift lift ᵀ⟩ + offset at its result (relative difference {e:.1e})",
                  f"the local solver reports cost {res.cost:.10g} but ⟨Q, lift lift ᵀ⟩ + offset at its result "
                  f"differs by {e:.1e} (relative; tolerance {COST_RTOL:g})")

    def perturbed() -> None:
        start = more.check_random_state(prob, inst, model, rng, out, FEAS_TOL)
        if local_cost:
            more.check_perturbed_descent(prob, inst, model, start, local_cost[0], out, FEAS_TOL)

    def data() -> None:
        from .validate import check_data, cost_condition

        check_data(prob, inst, model)
        kappa = cost_condition(model)[0]
        out.measurements["cost_condition"] = kappa
        out.passed.append(f"data: finite measurements, Q and constraints; the cost's weights have condition "
                          f"number {kappa:.2g} (autotight.validate)")

    local_cost: list[float] = []
    c.run("data", data)
    c.run("sample-feasible", draw)
    if len(unlifted) == len(states) > 1:  # the samples exist
        c.run("sample-spread", lambda: more.check_spread(model, thetas, out))
        c.run("cost", cost)
        c.run("recover", recover)
        c.run("errors", lambda: more.check_errors(prob, inst, states[1], out))
    c.run("local", local)
    c.run("random-state", perturbed)
    if thetas:
        c.run("marginal_log_svr", lambda: more.check_marginal(prob, inst, thetas[0], out))
    c.run("declared", lambda: more.check_declared(prob, out))
    c.run("identities", lambda: _identities(prob, inst, model, rng, out))
    c.run("carry", lambda: _carry(prob, given, out))
    out.measurements["time_s"] = time.perf_counter() - t0
    return out


def _carry(prob: Problem, given: dict[str, Any], out: ProblemCheck) -> None:
    """A declared ``META.carry_to`` hint names parameters of the problem with valid values."""
    from .discovery.engine import carry_hint

    params, backend = carry_hint(prob)
    if not params:
        out.passed.append("carry: no META.carry_to hint; discover validates at the given parameters only")
        return
    out.passed.append(f"carry: discover also validates at {params}" + (f" (with {backend})" if backend else ""))


def _identities(prob: Problem, inst: Instance, model: Model, rng: np.random.Generator, out: ProblemCheck) -> None:
    """Learn two factors of every type that has two, and compare the identity names they produce."""
    from .discovery.learn import Group, LearnOptions, learn_group, monomials_needed
    from .discovery.samples import draw

    pairs: list[tuple[Group, Group]] = []
    for t, fs in model.factor_types().items():
        if len(fs) >= 2:
            pairs.append((Group.of(fs[0]), Group.of(fs[1])))
    if not pairs:
        out.passed.append("identities: no factor type has two factors; nothing to compare")
        return
    opts = LearnOptions()
    groups = [g for p in pairs for g in p]
    bank = draw(prob, inst, monomials_needed(model, groups, opts), rng, None)
    heldout = draw(prob, inst, opts.heldout, rng, None)
    shared_any = False
    for a, b in pairs:
        la, lb = (learn_group(model, g, bank, heldout, opts) for g in (a, b))
        ia, ib = set(la.identities), set(lb.identities)
        shared_any |= bool(ia & ib)
        if a.type in prob.transport_types():
            _transport(prob, model, la, lb, out)
        where = f"factors {a.name!r} and {b.name!r} of type {a.type!r}"
        if a.roles != b.roles:
            diff = [f"{x}→{y}" for x, y in zip(a.roles, b.roles) if x != y][:3]
            out.warnings.append(f"identities: {where} have different roles ({', '.join(diff)}; {len(ia & ib)} of "
                                f"{len(ia | ib)} identities shared): give the factors the same roles "
                                f"(Factor(..., roles=...)), or a learned set will not carry over to other factors "
                                f"or sizes")
        elif ia != ib:
            only = sorted(ia ^ ib)[:3]
            out.failures.append(f"identities: {where} learn different identities ({len(ia ^ ib)} differ, e.g. "
                                f"{', '.join(only)}): their blocks or constraints do not correspond")
        else:
            out.passed.append(f"identities: {where} learn the same {len(ia)} identities")
    if not shared_any:
        out.warnings.append("identities: no two factors of one type share an identity; a learned set will not "
                            "carry over")


#: a declared transport must carry one factor's learned relations onto another's to this relative accuracy
TRANSPORT_RTOL = 1e-8


def _transport(prob: Problem, model: Model, la: Any, lb: Any, out: ProblemCheck) -> None:
    """``TRANSPORTS[type]`` carries the relations learned on factor a onto those learned on factor b."""
    from .discovery.templates import relative_error
    from .discovery.transport import basic, carry

    t = la.group.type
    where = f"TRANSPORTS[{t!r}] on factors {la.group.name!r} → {lb.group.name!r}"
    fa, fb = model.factor(la.group.name), model.factor(lb.group.name)
    if lb.free is None or la.coeffs.shape != lb.coeffs.shape:
        out.failures.append(f"transport: {where}: the factors learn relation spaces of different sizes "
                            f"({la.coeffs.shape[1]} and {lb.coeffs.shape[1]}), so no change of variables maps one "
                            "onto the other")
        return
    n = len(la.columns)
    da, db = (np.zeros(0) if f.data is None else f.data for f in (fa, fb))
    R = np.linalg.solve(prob.transport(t, da, n), prob.transport(t, db, n))
    V, _ = basic(carry(la.coeffs, R[None]), lb.free)
    err = float(np.nan_to_num(relative_error(V[0], lb.coeffs.T), nan=np.inf).max())
    out.measurements[f"transport_{t}_rel_error"] = err
    ok = err <= TRANSPORT_RTOL
    (out.passed if ok else out.failures).append(
        f"transport: {where} carries the {lb.coeffs.shape[1]} learned relations onto the other factor's (relative "
        f"error {err:.1e}; tolerance {TRANSPORT_RTOL:g})" if ok else
        f"transport: {where} does not carry the learned relations onto the other factor's (relative error "
        f"{err:.1e}; tolerance {TRANSPORT_RTOL:g}): M(data) is not the change of variables to the reference "
        "measurement")
