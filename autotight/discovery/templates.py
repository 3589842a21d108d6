"""Templates: learned constraints whose coefficients are polynomials in a factor's measurement entries.

A learned ``(factor type, identity)`` pair is a basic solution of the nullspace of the factor's
monomial data, normalised to coefficient 1 on its free monomial.  Its coefficient vector p(δ) is a
deterministic function of the factor's measurement entries δ = ``Factor.data``.  When p is a polynomial
of low degree in δ, one least-squares fit

    p(δ) = W ᵀ φ_g(δ),   φ_g(δ) = [1, δ_i, δ_i δ_j (i ≤ j)]  (all monomials of δ up to degree g)

over factors of many instances (fresh seeds: fresh measurements and fresh states) gives a template.
Applying it to an instance is one matrix product Φ W for all factors of the type: no sampling and no
nullspace.  Every template is checked before it is kept on instances that took no part in the fit:
(a) its coefficients equal those re-learned there to ``FIT_RTOL`` (relative to each factor's largest
coefficient) and (b) its constraints hold on fresh feasible states of those instances to
``LearnOptions.heldout_tol`` (relative violation, as for learning).  The degree is the smallest of
(0, 1, 2) that passes.  A factor type that passes none gets a transport template when its problem module
declares ``TRANSPORTS`` for it (``transport``: exact congruences of one learned factor's relations, checked
the same way); otherwise it is reported and learned per factor instead (``fallback``).

Coefficient layout: for a factor with local columns c_0 … c_{n−1} (its blocks in order, h first), the
monomials are θ_{c_i}ᵀθ_{c_j}, i ≤ j, in svec order (column-major upper triangle, no √2; see
``autotight.svec``).  A type's k identities are stacked into one vector of length k·m
(m = n(n+1)/2); ``support`` lists the positions that are not zero for every factor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import AutotightError
from ..model import Constraint, Model, canonical_coos
from ..problem import Instance, Problem
from ..svec import triu_indices
from ..validity import VALID_RTOL
from .learn import LearnOptions
from .transport import Layout, TransportTemplate, reference_template

#: a template's coefficients must equal re-learned ones to this relative accuracy (max-norm, relative
#: to each factor's largest coefficient) on the instances used for fitting and checking
FIT_RTOL = 1e-9
#: polynomial degrees tried, lowest first
DEGREES = (0, 1, 2)
#: fresh instances (never used in the fit) on which every template is checked before it is saved
CHECK_INSTANCES = 2
#: most instances generated to collect samples of one factor type
MAX_INSTANCES = 60
#: samples kept aside (from the fitting instances) to validate a fit before collecting more
VALIDATE = 8


def features(D: np.ndarray, degree: int) -> np.ndarray:
    """φ_g of each row of D (n, p): 1, then δ_i, then δ_i δ_j (i ≤ j, svec order) → (n, F)."""
    D = np.atleast_2d(np.asarray(D, dtype=float))
    cols = [np.ones((D.shape[0], 1))]
    if degree >= 1:
        cols.append(D)
    if degree >= 2:
        i, j = triu_indices(D.shape[1])
        cols.append(D[:, i] * D[:, j])
    return np.concatenate(cols, axis=1)


def n_features(p: int, degree: int) -> int:
    return 1 + (p if degree >= 1 else 0) + (p * (p + 1) // 2 if degree >= 2 else 0)


def relative_error(pred: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per row: max |pred − Y| / max |Y|."""
    return np.max(np.abs(pred - Y), axis=1) / np.maximum(np.max(np.abs(Y), axis=1), 1e-300)


@dataclass
class TypeTemplate(Layout):
    """The templates of one factor type: coefficients = features(data, degree) @ W on ``support``."""

    factor_type: str
    identities: list[str]
    roles: list[str]
    block_sizes: list[int]
    n_data: int
    degree: int
    support: np.ndarray
    W: np.ndarray
    check: dict[str, Any] = field(default_factory=dict)
    kind: str = "polynomial"

    def coefficients(self, D: np.ndarray, problem: Problem | None = None) -> np.ndarray:
        """Coefficients on ``support`` for factors with data D (n_f, n_data) → (n_f, |support|) (``problem``:
        unused, as ``TransportTemplate.coefficients``)."""
        return features(D, self.degree) @ self.W

    def dense(self, D: np.ndarray, problem: Problem | None = None) -> np.ndarray:
        """Full coefficient vectors (n_f, k, m), as learning returns them (``LearnedGroup.coeffs``ᵀ)."""
        out = np.zeros((D.shape[0], len(self.identities) * self.n_monomials))
        out[:, self.support] = self.coefficients(D)
        return out.reshape(D.shape[0], len(self.identities), self.n_monomials)

    def restricted(self, identities: Sequence[str]) -> "TypeTemplate":
        """The template of ``identities`` only (a subset of its own, in that order)."""
        idx = [self.identities.index(i) for i in identities]
        m = self.n_monomials
        q, mono = self.support // m, self.support % m
        new_q = {old: new for new, old in enumerate(idx)}
        keep = np.flatnonzero(np.isin(q, idx))
        support = np.array([new_q[int(q[j])] * m + int(mono[j]) for j in keep], dtype=np.int64)
        return replace(self, identities=list(identities), support=support, W=self.W[:, keep])

    def record(self) -> dict[str, Any]:
        return {"kind": self.kind, "factor_type": self.factor_type, "identities": self.identities, "roles": self.roles,
                "block_sizes": self.block_sizes, "n_data": self.n_data, "degree": self.degree,
                "support": self.support.tolist(), "W": self.W.tolist(), "check": self.check}

    @classmethod
    def from_record(cls, r: dict[str, Any]) -> "TypeTemplate | TransportTemplate":
        if r.get("kind", "polynomial") == "transport":
            return TransportTemplate.from_record(r)
        return cls(r["factor_type"], list(r["identities"]), list(r["roles"]), [int(s) for s in r["block_sizes"]],
                   int(r["n_data"]), int(r["degree"]), np.asarray(r["support"], dtype=np.int64),
                   np.asarray(r["W"], dtype=float).reshape(n_features(int(r["n_data"]), int(r["degree"])), -1),
                   dict(r.get("check", {})))


@dataclass
class TemplateSet:
    """Templates per factor type, and the types that fall back to per-factor learning (with the reason)."""

    templates: dict[str, "TypeTemplate | TransportTemplate"]
    fallback: dict[str, str]
    times: dict[str, float] = field(default_factory=dict)

    def restricted(self, pairs: Sequence[tuple[str, str]]) -> "TemplateSet":
        """The templates and fallbacks of ``pairs`` only (identities sorted per type, as ``learn_templates``)."""
        wanted: dict[str, list[str]] = {}
        for t, i in pairs:
            wanted.setdefault(t, [])
            if i not in wanted[t]:
                wanted[t].append(i)
        return TemplateSet({t: tpl.restricted(sorted(wanted[t])) for t, tpl in self.templates.items() if t in wanted},
                           {t: why for t, why in self.fallback.items() if t in wanted}, dict(self.times))

    def record(self) -> dict[str, Any]:
        return {"templates": [t.record() for t in self.templates.values()], "fallback": self.fallback,
                "template_times": self.times}

    @classmethod
    def from_record(cls, obj: dict[str, Any]) -> "TemplateSet":
        ts = [TypeTemplate.from_record(r) for r in obj.get("templates", [])]
        return cls({t.factor_type: t for t in ts}, dict(obj.get("fallback", {})), dict(obj.get("template_times", {})))


# ----------------------------------------------------------------------------- learning


def _instance(problem: Problem, point: dict[str, Any], seed: int, cache: dict | None) -> tuple[Instance, Model]:
    """The instance at ``point`` with generator seed ``seed`` and its model (kept in ``cache`` when given)."""
    key = ("instance", problem.name, repr(sorted(point.items())), seed)
    if cache is not None and key in cache:
        return cache[key]
    inst = problem.generate(point, np.random.default_rng(seed))
    out = (inst, problem.build(inst))
    if cache is not None:
        cache[key] = out
    return out


def _factor_samples(problem: Problem, inst: Instance, model: Model, wanted: dict[str, list[str]],
                    rng: np.random.Generator, opts: LearnOptions,
                    cache: dict | None = None) -> tuple[dict[str, list], list[str]]:
    """Per type: (data, stacked coefficient vector) of every factor of ``inst``; and issues.  ``cache``: the
    learning of each (instance, factor types) is kept, with the state of ``rng`` after it, so that a later fit
    with other identities of the same types (a set that grew) reuses it and continues the same random stream."""
    from .catalog import learn

    key = ("samples", id(inst), tuple(sorted(wanted)), repr(opts))
    if cache is not None and key in cache:
        cat, state = cache[key]
        rng.bit_generator.state = state
    else:
        # only the basic solutions: the fit is checked separately (fresh instances, fresh states)
        cat = learn(problem, inst, model, rng, "factors", replace(opts, heldout=min(opts.heldout, 6)),
                    types=sorted(wanted), checked=False)
        if cache is not None:
            cache[key] = (cat, rng.bit_generator.state)
    out: dict[str, list] = {t: [] for t in wanted}
    issues: list[str] = []
    for g in cat.groups:
        t = g.group.type
        have = {ident: j for j, ident in enumerate(g.identities)}
        miss = [i for i in wanted[t] if i not in have]
        if miss:
            issues.append(f"identity {t}:{miss[0]} not found on factor {g.group.name}")
            continue
        f = model.factor(g.group.name)
        data = np.zeros(0) if f.data is None else f.data
        out[t].append((data, g.coeffs[:, [have[i] for i in wanted[t]]].T.ravel()))
    return out, issues


def _fit(D: np.ndarray, Y: np.ndarray, degree: int) -> np.ndarray:
    Phi = features(D, degree)
    W, *_ = np.linalg.lstsq(Phi, Y, rcond=None)
    return W


def learn_templates(problem: Problem, params: dict[str, Any] | Sequence[dict[str, Any]],
                    pairs: Sequence[tuple[str, str]], seed: int, opts: LearnOptions = LearnOptions(),
                    progress=None, cache: dict | None = None) -> TemplateSet:
    """Fit a template per factor type of ``pairs`` from instances with seeds ``seed + 1000 + i``.

    ``params``: one parameter point, or several (a set discovered over a range): instance i is drawn at
    point i mod P, and no fit is accepted before every point has given its factors.  A polynomial fitted
    where the measurements vary little (σ = 0.001) can match a function that is no polynomial to
    ``FIT_RTOL`` there and miss it at σ = 0.01 (discrete trajectory, odometry r'[2]·ρ[2]: 2.4e-8); over
    the range's points it fails its fit instead, and the type gets its transport template.
    Instances are generated until, for every type, some degree fits the collected factors and predicts
    ``VALIDATE`` further ones to ``FIT_RTOL``, or the most features (degree 2) are exhausted.  Every kept
    template is then checked on ``CHECK_INSTANCES`` fresh instances, and at least one per point
    (``check_template``).  ``cache``: a dict kept between fits of one discovery (instances and their learning:
    the same templates, without learning an instance twice)."""
    points = [dict(params)] if isinstance(params, dict) else [dict(p) for p in params]
    params = points[0]
    t0 = time.perf_counter()
    wanted: dict[str, list[str]] = {}
    for t, i in pairs:
        wanted.setdefault(t, [])
        if i not in wanted[t]:
            wanted[t].append(i)
    for t in wanted:
        wanted[t].sort()
    samples: dict[str, list] = {t: [] for t in wanted}
    fitted: dict[str, tuple[int, np.ndarray, np.ndarray]] = {}
    fallback: dict[str, str] = {}
    layout: dict[str, tuple[list[str], list[int]]] = {}
    open_types = dict.fromkeys(wanted)  # an ordered set: types in the pairs' order, whatever the hash seed
    k = 0
    while open_types and k < MAX_INSTANCES:
        rng = np.random.default_rng([seed, 1000 + k])
        point = points[k % len(points)]
        inst, model = _instance(problem, point, seed + 1000 + k, cache)
        k += 1
        for t in list(open_types):
            fs = [f for f in model.factors if f.type == t]
            if not fs:
                fallback[t] = f"factor type {t!r} has no factor on an instance with params {point}"
                open_types.pop(t)
            else:
                layout[t] = (list(fs[0].roles or fs[0].blocks), [model.variables.sizes[b] for b in fs[0].blocks])
        got, issues = _factor_samples(problem, inst, model, {t: wanted[t] for t in open_types}, rng, opts, cache)
        for t in list(open_types):
            samples[t] += got[t]
            bad = [s for s in issues if s.startswith(f"identity {t}:")]
            if bad:
                fallback[t] = f"{bad[0]}: the identity is not a basic solution on every factor, so it has no template"
                open_types.pop(t)
                continue
            n_data = {d.size for d, _ in samples[t]}
            if len(n_data) != 1:
                fallback[t] = f"factors of type {t!r} have measurement data of different lengths {sorted(n_data)}"
                open_types.pop(t)
                continue
            D = np.array([d for d, _ in samples[t]]).reshape(len(samples[t]), -1)
            Y = np.array([y for _, y in samples[t]])
            p = D.shape[1]
            n_fit = len(Y) - VALIDATE
            for g in DEGREES:
                if (g > 0 and p == 0) or n_fit < 3 or k < len(points):  # every point's factors first
                    break
                W = _fit(D[:n_fit], Y[:n_fit], g)
                if relative_error(features(D, g) @ W, Y).max() <= FIT_RTOL:  # the last VALIDATE factors decide
                    fitted[t] = (g, _fit(D, Y, g), np.flatnonzero(np.any(Y != 0, axis=0)))
                    open_types.pop(t)
                    break
            if t in open_types and len(Y) - VALIDATE >= n_features(p, max(DEGREES)) + VALIDATE:
                errs = [relative_error(features(D, g) @ _fit(D[:-VALIDATE], Y[:-VALIDATE], g), Y).max()
                        for g in DEGREES if g == 0 or p > 0]
                fallback[t] = (f"the coefficients of factor type {t!r} are not a polynomial of degree ≤ "
                               f"{max(DEGREES)} in its {p} measurement entries (smallest relative error on "
                               f"validation factors {min(errs):.1e} > {FIT_RTOL:g}); learned per factor instead")
                open_types.pop(t)
        if progress is not None:
            progress(f"template instance {k}: {sorted(open_types)} open")
    for t in open_types:
        fallback[t] = (f"factor type {t!r}: no template of degree ≤ {max(DEGREES)} fitted within {MAX_INSTANCES} "
                       "instances; learned per factor instead")
    templates: dict[str, TypeTemplate | TransportTemplate] = {}
    for t, (g, W, support) in fitted.items():
        D0 = samples[t][0][0]
        templates[t] = TypeTemplate(t, wanted[t], *layout[t], int(D0.size), g, support, W[:, support],
                                    {"n_fit_factors": len(samples[t]), "fit_instances": k})
    transports = _transports(problem, params, sorted(set(wanted) - set(fitted)), wanted, layout, seed, opts,
                             fallback)
    t1 = time.perf_counter()
    templates |= transports
    failed = _check_templates(problem, points, templates, wanted, seed, opts, fallback, cache)
    # a polynomial that fitted but failed its check (it matched a non-polynomial where it was fitted): transport
    retry = _transports(problem, params, [t for t in failed if not isinstance(failed[t], TransportTemplate)],
                        wanted, layout, seed, opts, fallback)
    _check_templates(problem, points, retry, wanted, seed, opts, fallback, cache)
    templates |= retry
    for tpl in templates.values():
        tpl.check |= {"check_instances": max(CHECK_INSTANCES, len(points)), "fit_rtol": FIT_RTOL,
                      "heldout_tol": opts.heldout_tol} | ({"points": len(points)} if len(points) > 1 else {})
    return TemplateSet(templates, fallback, {"fit_s": t1 - t0, "check_s": time.perf_counter() - t1})


def _transports(problem: Problem, params: dict[str, Any], types: Sequence[str], wanted: dict[str, list[str]],
                layout: dict[str, tuple[list[str], list[int]]], seed: int, opts: LearnOptions,
                fallback: dict[str, str]) -> dict[str, TransportTemplate]:
    """Transport templates of ``types`` that the problem declares one for; each found leaves ``fallback``
    (its reason kept as the template's ``check["polynomial"]``), each that fails says why there."""
    out: dict[str, TransportTemplate] = {}
    for t in types:
        if t in layout and t in problem.transport_types():
            try:
                out[t] = _transport_template(problem, params, t, wanted[t], layout[t], seed, opts)
            except AutotightError as e:
                fallback[t] += f"; no transport template either: {e}"
                continue
            out[t].check["polynomial"] = fallback.pop(t).replace("; learned per factor instead", "")
    return out


def _check_templates(problem: Problem, points: list[dict[str, Any]], templates: dict, wanted: dict[str, list[str]],
                     seed: int, opts: LearnOptions, fallback: dict[str, str], cache: dict | None = None) -> dict:
    """Check ``templates`` on fresh instances (seeds seed + 2000 + c, at least one per point) against
    re-learning (``FIT_RTOL``) and on fresh states (``heldout_tol``); a failing one moves from ``templates`` to
    ``fallback`` with its figures.  Returns the failed templates by type."""
    failed = {}
    for c in range(max(CHECK_INSTANCES, len(points))):
        if not templates:
            break
        inst, model = _instance(problem, points[c % len(points)], seed + 2000 + c, cache)
        rng = np.random.default_rng([seed, 2000 + c])
        got, _ = _factor_samples(problem, inst, model, {t: wanted[t] for t in templates}, rng, opts, cache)
        for t in list(templates):
            tpl = templates[t]
            err = 0.0
            if got[t]:
                D = np.array([d for d, _ in got[t]]).reshape(len(got[t]), -1)
                Y = np.array([y for _, y in got[t]])
                err = float(relative_error(tpl.dense(D, problem).reshape(len(Y), -1), Y).max())
            viol = check_template(problem, inst, model, tpl, rng, opts)
            worst = max(viol.values()) if viol else 0.0
            tpl.check["relearn_rel_error"] = max(tpl.check.get("relearn_rel_error", 0.0), err)
            tpl.check["heldout_violation"] = max(tpl.check.get("heldout_violation", 0.0), worst)
            if not (err <= FIT_RTOL and worst <= opts.heldout_tol):  # NaN (no solution on a factor) fails
                fallback[t] = (f"the template of factor type {t!r} failed its check on a fresh instance "
                               f"(coefficients off by {err:.1e} relative, violation {worst:.1e}); learned per "
                               "factor instead")
                failed[t] = templates.pop(t)
    return failed


def _transport_template(problem: Problem, params: dict[str, Any], t: str, wanted: list[str],
                        layout: tuple[list[str], list[int]], seed: int, opts: LearnOptions) -> TransportTemplate:
    """A transport template of type ``t`` from the first factor of the first fitting instance (seed + 1000),
    its coefficients checked against re-learning on the instance's other factors (``FIT_RTOL``).
    AutotightError when it does not hold."""
    from .catalog import learn

    inst = problem.generate(params, np.random.default_rng(seed + 1000))
    model = problem.build(inst)
    cat = learn(problem, inst, model, np.random.default_rng([seed, 1000]), "factors",
                replace(opts, heldout=min(opts.heldout, 6)), types=[t])
    gs = [g for g in cat.groups if g.free is not None and all(i in g.identities for i in wanted)]
    if len(gs) < 2:
        raise AutotightError(f"fewer than 2 factors of type {t!r} have the identities {wanted} on an instance "
                             f"with params {params}")
    data = [np.zeros(0) if (x := model.factor(g.group.name).data) is None else x for g in gs]
    free = gs[0].free
    assert free is not None  # gs keeps the groups with free monomials
    tpl = reference_template(problem, t, wanted, *layout, data[0], gs[0].coeffs, free, gs[0].identities)
    Y = np.array([g.coeffs[:, [g.identities.index(i) for i in wanted]].T.ravel() for g in gs[1:]])
    pred = tpl.solutions(np.array(data[1:]), problem).reshape(len(Y), -1)
    err = float(np.nan_to_num(relative_error(pred, Y), nan=np.inf).max())
    tpl.check |= {"reference_factor": gs[0].group.name, "n_fit_factors": len(gs) - 1, "relearn_rel_error": err}
    if not err <= FIT_RTOL:
        raise AutotightError(f"carried coefficients off by {err:.1e} relative on the learning instance's other factors")
    return tpl


# ----------------------------------------------------------------------------- applying


def factor_columns(model: Model, tpl: TypeTemplate | TransportTemplate) -> tuple[list, np.ndarray, np.ndarray]:
    """(factors of the type, their local columns (n_f, n), their data (n_f, n_data)); AutotightError when
    the block layout or the data length does not fit the template."""
    fs = [f for f in model.factors if f.type == tpl.factor_type]
    V = model.variables
    for f in fs:
        sizes = [V.sizes[b] for b in f.blocks]
        if sizes != tpl.block_sizes:
            raise AutotightError(f"factor {f.name} of type {tpl.factor_type!r} has block sizes {sizes}; the "
                                 f"constraint set's template expects {tpl.block_sizes}")
        n = 0 if f.data is None else f.data.size
        if n != tpl.n_data:
            raise AutotightError(f"factor {f.name} has {n} measurement entries; the template of type "
                                 f"{tpl.factor_type!r} expects {tpl.n_data}")
    if not fs:
        return fs, np.zeros((0, tpl.n_cols), np.int64), np.zeros((0, tpl.n_data))
    cols = np.array([np.concatenate([np.arange(V.offsets[b], V.offsets[b] + V.sizes[b]) for b in f.blocks])
                     for f in fs], dtype=np.int64)
    D = np.array([np.zeros(0) if f.data is None else f.data for f in fs]).reshape(len(fs), tpl.n_data)
    return fs, cols, D


def violations(tpl: TypeTemplate | TransportTemplate, cols: np.ndarray, coeffs: np.ndarray,
               thetas: np.ndarray) -> np.ndarray:
    """Largest relative violation |Σ p θ_iᵀθ_j| / Σ |p| ‖θ_i‖‖θ_j‖ over the samples, per (factor, identity)
    → (n_f, k).  thetas: (S, d, N).  The products θ_iᵀθ_j are formed once per factor and monomial of the
    support (a transport template's support repeats every monomial once per identity)."""
    m = tpl.n_monomials
    q, mono = tpl.support // m, tpl.support % m
    ii, jj = triu_indices(tpl.n_cols)
    used, at = np.unique(mono, return_inverse=True)
    gi, gj = cols[:, ii[used]], cols[:, jj[used]]  # (n_f, u): the monomials the support uses
    k = len(tpl.identities)
    entries = [np.flatnonzero(q == a) for a in range(k)]  # the support entries of each identity
    out = np.zeros((cols.shape[0], k))
    norms = np.linalg.norm(thetas, axis=1)  # (S, N)
    for T, nr in zip(thetas, norms):
        prod = np.einsum("dfs,dfs->fs", T[:, gi], T[:, gj])
        mag = nr[gi] * nr[gj]
        for a, e in enumerate(entries):
            c = coeffs[:, e]
            val = np.einsum("fs,fs->f", c, prod[:, at[e]])
            den = np.einsum("fs,fs->f", np.abs(c), mag[:, at[e]])
            out[:, a] = np.maximum(out[:, a], np.abs(val) / np.maximum(den, 1e-300))
    return out


def check_template(problem: Problem, inst: Instance, model: Model, tpl: TypeTemplate, rng: np.random.Generator,
                   opts: LearnOptions, n_samples: int | None = None) -> dict[str, float]:
    """Largest relative violation of the template's constraints on fresh feasible states of ``inst``, per
    factor name."""
    fs, cols, D = factor_columns(model, tpl)
    if not fs:
        return {}
    from .samples import draw

    bank = draw(problem, inst, n_samples or max(4, opts.heldout // 10), rng, opts.spread)
    v = violations(tpl, cols, tpl.coefficients(D, problem), bank.thetas).max(axis=1)
    return {f.name: float(x) for f, x in zip(fs, v)}


def apply_template(model: Model, tpl: TypeTemplate | TransportTemplate, coeffs: np.ndarray,
                   columns: tuple[list, np.ndarray, np.ndarray] | None = None) -> list[Constraint]:
    """The template's constraints on every factor of its type in ``model``, from their coefficients
    (``tpl.coefficients`` of the factors' data, in ``factor_columns`` order), identity by identity; each
    matrix is ``canonical_coo`` of the factor's entries.  columns: ``factor_columns(model, tpl)`` when known."""
    fs, cols, _ = factor_columns(model, tpl) if columns is None else columns
    if not fs:
        return []
    m = tpl.n_monomials
    q, mono = tpl.support // m, tpl.support % m
    ii, jj = triu_indices(tpl.n_cols)
    N = model.variables.N
    out: list[Constraint] = []
    for a, ident in enumerate(tpl.identities):
        sel = np.flatnonzero(q == a)
        li, lj = ii[mono[sel]], jj[mono[sel]]
        p = coeffs[:, sel]
        keep = p != 0 if tpl.kind == "transport" else np.ones(p.shape, dtype=bool)  # transport: every position
        mats = _factor_matrices(cols[:, li], cols[:, lj], p, li != lj, keep, N)
        out += [Constraint(A, 0.0, name=f"{f.name}:{ident}", family="learned", factor=f.name,
                           identity=f"{tpl.factor_type}:{ident}") for f, A in zip(fs, mats)]
    return out


def _factor_matrices(gi: np.ndarray, gj: np.ndarray, p: np.ndarray, off: np.ndarray, keep: np.ndarray,
                     N: int) -> list[sp.coo_array]:
    """Per factor r (a row of the (n_f, s) arrays): ``canonical_coo`` of the symmetric entries p/2 at (gi, gj)
    and (gj, gi) (p at a diagonal monomial, ``off`` False) of its monomials where ``keep``
    (``model.canonical_coos``: every factor in one sort)."""
    mask = np.concatenate([keep, keep[:, off]], axis=1)
    rows = np.concatenate([gi, gj[:, off]], axis=1)[mask]
    cols = np.concatenate([gj, gi[:, off]], axis=1)[mask]
    vals = np.concatenate([np.where(off, p / 2, p), p[:, off] / 2], axis=1)[mask]
    owner = np.repeat(np.arange(p.shape[0]), mask.sum(axis=1))
    return canonical_coos(owner, rows, cols, vals, N, p.shape[0])


def check_tolerance(saved: float) -> float:
    """The tolerance of the check on fresh states: a set's own ``heldout_tol``, never looser than the
    tool's ``validity.VALID_RTOL`` (a saved file cannot switch the check off; NaN counts as absent)."""
    return float(saved) if 0 < saved <= VALID_RTOL else VALID_RTOL


def apply_templates(problem: Problem, inst: Instance, model: Model, ts: TemplateSet, rng: np.random.Generator,
                    opts: LearnOptions, skip_invalid: bool = False,
                    n_check: int = 2) -> tuple[list[Constraint], list[str], list[str]]:
    """Every template's constraints on ``inst``, each checked on ``n_check`` fresh feasible states of ``inst``
    → (constraints, skipped "factor:identity", factors to re-learn).

    A factor whose constraints violate the check (relative violation > ``check_tolerance(opts.heldout_tol)``)
    is a one-line AutotightError naming it, unless ``skip_invalid`` (its constraints are then left out and listed).  A
    factor where a transport template has no basic solutions (its free monomials are ill-conditioned there,
    e.g. a measured position at the origin) is not an error: its constraints are left out and the factor
    is listed to be re-learned (``DiscoveredSet.apply``), as learning names such a factor's relations
    otherwise."""
    out: list[Constraint] = []
    skipped: list[str] = []
    relearn: list[str] = []
    thetas = None
    tol = check_tolerance(opts.heldout_tol)
    for tpl in ts.templates.values():
        fs, cols, D = factor_columns(model, tpl)
        if not fs:
            continue
        if thetas is None:
            from .samples import draw

            thetas = draw(problem, inst, n_check, rng, opts.spread).thetas
        coeffs = tpl.coefficients(D, problem)
        viol = violations(tpl, cols, coeffs, thetas)
        none = np.isnan(viol).any(axis=1)  # no basic solutions on that factor
        bad = np.argwhere((viol > tol) & ~none[:, None])
        drop = {(fs[r].name, tpl.identities[a]) for r in np.flatnonzero(none) for a in range(len(tpl.identities))}
        relearn += [fs[r].name for r in np.flatnonzero(none)]
        if bad.size:
            r, a = bad[0]
            msg = (f"template {tpl.factor_type}:{tpl.identities[a]} fails its check on factor {fs[r].name} "
                   f"(relative violation {viol[r, a]:.1e} > {tol:g}; {len(bad)} factor identities fail)")
            if not skip_invalid:
                raise AutotightError(msg + "; pass --skip-invalid (skip_invalid=True) to leave them out")
            bad_pairs = {(fs[r].name, tpl.identities[a]) for r, a in bad}
            skipped += [f"{f}:{i}" for f, i in sorted(bad_pairs)]
            drop |= bad_pairs
        cons = apply_template(model, tpl, coeffs, (fs, cols, D))
        if drop:
            cons = [c for n, c in enumerate(cons) if (fs[n % len(fs)].name, tpl.identities[n // len(fs)]) not in drop]
        out += cons
    return out, skipped, relearn
