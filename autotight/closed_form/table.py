"""Closed forms of a discovered set's families beside the paper's, and how they relate.

``family_table(problem, ds)`` gives one row per discovered ``(factor type, identity)``: its closed form
(``family``), the paper family it equals modulo the primary constraints and the relation, e.g.
``= R2`` or ``= R1[1] − 1/2 R1[3]``, or "new".  The relation is an exact identity between closed forms
(both in normal form modulo the primary constraints, so equal means equal modulo them), checked on
``N_FRESH`` factors of fresh instances that took no part in any fit; its ``residual`` is the largest
relative difference there.  Every closed form is also checked on feasible states of those instances:
``violation`` is the largest relative violation |Σ u_μ m_μ| / Σ |u_μ| |m_μ| (m_μ the monomials).

Where the relations come from: a polynomial or transport template of the set; for a type without one
(re-learned per factor) whose module declares ``TRANSPORTS``, a transport from one learned factor
(``autotight.discovery.transport``); otherwise the family has no closed form and the row says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any, Callable

import numpy as np

from ..errors import AutotightError
from ..problem import Problem
from ..svec import monomials as lifted_monomials
from . import polynomials as poly
from .family import ClosedForm, closed_form
from .formula import data_names, formula
from .samples import FactorSamples, collect, factor_cols

#: factors (of fresh instances) on which relations and closed forms are checked
N_FRESH = 100
#: factors collected to fit the closed forms (degree ≤ 2 in 12 data entries needs ≥ 177)
N_FIT = 240
#: a relation between closed forms holds when they differ by at most this, relative, on every fresh factor
RELATION_RTOL = 1e-9
#: feasible states drawn per fresh instance for the validity check
STATES = 2


@dataclass
class FamilyRow:
    """One family: its closed form (text and LaTeX), the paper family it equals and the relation."""

    factor_type: str
    identity: str
    closed_form: str
    latex: str
    paper: str
    relation: str
    residual: float
    violation: float
    exact: bool
    degree: int | None
    source: str

    def record(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class FamilyTable:
    """The discovered families' rows and the paper's families in the same notation (per factor type)."""

    problem: str
    rows: list[FamilyRow]
    paper: dict[str, list[tuple[str, str, str]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @classmethod
    def from_record(cls, r: dict[str, Any]) -> "FamilyTable":
        return cls(r["problem"], [FamilyRow(**x) for x in r["rows"]],
                   {t: [(x["row"], x["closed_form"], x["latex"]) for x in v] for t, v in r["paper"].items()},
                   list(r.get("notes", [])))

    def record(self) -> dict[str, Any]:
        return {"problem": self.problem, "rows": [r.record() for r in self.rows],
                "paper": {t: [{"row": n, "closed_form": c, "latex": x} for n, c, x in v]
                          for t, v in self.paper.items()},
                "notes": self.notes, "relation_rtol": RELATION_RTOL}


def learned_transport(problem: Problem, ds, t: str, idents: list[str]):
    """A transport template of type ``t`` for ``idents`` from the first factor of the set's learning instance
    (seed + 1000, as ``learn_templates``) that has them all (``autotight.discovery.transport``)."""
    from ..discovery.catalog import learn
    from ..discovery.transport import reference_template

    if t not in problem.transport_types():
        raise AutotightError(f"factor type {t!r} has no TRANSPORTS entry in its problem module")
    inst = problem.generate(ds.params, np.random.default_rng(int(ds.seed or 0) + 1000))
    model = problem.build(inst)
    cat = learn(problem, inst, model, np.random.default_rng([int(ds.seed or 0), 1000]), "factors", ds.options(),
                types=[t])
    g = next((g for g in cat.groups if g.free is not None and all(i in g.identities for i in idents)), None)
    if g is None:
        raise AutotightError(f"no factor of type {t!r} has the identities {idents} on the learning instance")
    f = model.factor(g.group.name)
    sizes = [model.variables.sizes[b] for b in f.blocks]
    return reference_template(problem, t, idents, list(f.roles or f.blocks), sizes,
                              np.zeros(0) if f.data is None else f.data, g.coeffs, np.asarray(g.free), g.identities)


def _evaluator(problem: Problem, ds, t: str, idents: list[str]) -> tuple[Callable[[np.ndarray], np.ndarray], str]:
    """A function D (S, p) → relations (S, k, m) of ``idents``, and where it comes from."""
    ts = ds.template_set(problem)
    if t in ts.templates:
        tpl = ts.templates[t].restricted(idents)
        how = "transport template" if tpl.kind == "transport" else f"polynomial template (degree {tpl.degree})"
        return (lambda D: tpl.dense(D, problem)), how
    if t not in problem.transport_types():
        raise AutotightError(f"no template ({ts.fallback.get(t, 'learned per factor')}) and no TRANSPORTS entry")
    ref = learned_transport(problem, ds, t, idents)
    return (lambda D: ref.dense(D, problem)), "transport from one learned factor (the set has no template)"


def _fresh_violation(cf: ClosedForm, fresh: FactorSamples, problem: Problem, rng: np.random.Generator) -> float:
    """Largest relative violation of the closed form on feasible states of the fresh instances."""
    from ..discovery.samples import draw

    worst = 0.0
    m = fresh.n_monomials
    for inst, model, fs in fresh.instances:
        thetas = draw(problem, inst, STATES, rng, None).thetas
        D = np.array([np.zeros(0) if f.data is None else f.data for f in fs]).reshape(len(fs), -1)
        U = cf.values(D, m)
        for f, u in zip(fs, U):
            mono = lifted_monomials(thetas[:, :, factor_cols(model, f)])
            den = np.abs(mono) @ np.abs(u)
            worst = max(worst, float(np.max(np.abs(mono @ u) / np.maximum(den, 1e-300))))
    return worst


def _combination(alpha: np.ndarray, names: list[str]) -> str:
    parts: list[str] = []
    for a, n in zip(alpha, names):
        if a == 0:
            continue
        mag = "" if abs(a) == 1 else (f"{abs(a)} " if isinstance(a, Fraction) else f"{abs(a):.6g} ")
        sign = "−" if a < 0 else "+"
        parts.append(f"{'−' if a < 0 else ''}{mag}{n}" if not parts else f" {sign} {mag}{n}")
    return "".join(parts) or "0"


def relation(u: np.ndarray, P: np.ndarray, names: list[str]) -> tuple[str | None, float]:
    """u (S, m) against rows P (S, k, m): "= Σ α_i name_i" with constant exact α when every u_s is that
    combination to ``RELATION_RTOL``; "in the span of …" when the combination's coefficients vary with the
    data; None when u is not in the span.  Returns (text, residual of the best combination)."""
    S = u.shape[0]
    alphas = np.array([np.linalg.lstsq(P[s].T, u[s], rcond=None)[0] for s in range(S)])
    fit = np.einsum("sk,skm->sm", alphas, P)
    res = poly.relative_residual(fit, u)
    if not res <= RELATION_RTOL:
        return None, res
    F = [Fraction(float(a)).limit_denominator(poly.MAX_DENOMINATOR) for a in np.median(alphas, axis=0)]
    exact = np.einsum("k,skm->sm", np.array([float(x) for x in F]), P)
    res_exact = poly.relative_residual(exact, u)
    if res_exact <= RELATION_RTOL:
        return "= " + _combination(np.array(F, dtype=object), names), res_exact
    return f"in the span of {', '.join(names)} (coefficients depend on the data)", res


def _identify(u: np.ndarray, fams: dict[str, tuple[np.ndarray, list[str]]]) -> tuple[str, str, float]:
    """(paper family, relation, residual) of relations u (S, m) against each family's rows (S, k, m), one
    family at a time, then all together ("combination"); "new" when u is in no span (the residual is then
    that of the best combination of all the rows)."""
    for fam, (P, names) in fams.items():
        text, res = relation(u, P, names)
        if text is not None:
            return fam, text, res
    if not fams:
        return "new", "the problem has no paper family on this factor type", float("nan")
    text, res = relation(u, np.concatenate([P for P, _ in fams.values()], axis=1),
                         [n for _, names in fams.values() for n in names])
    if text is not None:
        return "combination", text, res
    return "new", "not in the span of the paper's families modulo the primary constraints", res


def _paper_types(problem: Problem, params: dict[str, Any]) -> list[str]:
    """The factor types that carry a paper family (on the instance with seed 0)."""
    model = problem.build(problem.generate(params, 0))
    have = {c.factor for cons in model.paper.values() for c in cons}
    return sorted({f.type for f in model.factors if f.name in have})


def family_table(problem: Problem, ds, seed: int = 0, progress: Callable[[str], None] | None = None) -> FamilyTable:
    """The closed forms of the set ``ds`` (a ``DiscoveredSet``) beside the paper's families (see the module)."""
    rows: list[FamilyRow] = []
    paper_out: dict[str, list[tuple[str, str, str]]] = {}
    notes: list[str] = []
    by_type: dict[str, list[str]] = {}
    for t, i in ds.pairs:
        by_type.setdefault(t, [])
        if i not in by_type[t]:
            by_type[t].append(i)
    rng = np.random.default_rng([seed, 8000])
    for t, idents in sorted(by_type.items()):
        if progress is not None:
            progress(f"closed forms of {t}")
        try:
            evaluate, source = _evaluator(problem, ds, t, idents)
            # a polynomial template holds where it was fitted and checked: data at the set's parameters
            wide = not source.startswith("polynomial")
            fs = collect(problem, ds.params, t, N_FIT, seed, wide=wide)
            fresh = collect(problem, ds.params, t, N_FRESH, seed + 1, keep_instances=10**6, wide=wide)
        except AutotightError as e:
            rows += [FamilyRow(t, i, f"no closed form: {e}", "", "—", "—", float("nan"), float("nan"), False, None,
                               "none") for i in idents]
            continue
        names = data_names(problem, t, fs.D.shape[1])
        m = fs.n_monomials

        def show(cf: ClosedForm, latex: bool) -> str:
            return formula(cf, fs.roles, fs.block_sizes, names, latex=latex, d=fs.d)

        paper_cf: dict[str, list[tuple[str, ClosedForm]]] = {}
        for fam, P in fs.paper.items():
            paper_cf[fam] = [(r, closed_form(r, fs, P[:, k, :])) for k, r in enumerate(fs.paper_rows[fam])]
            paper_out.setdefault(t, [])
            paper_out[t] += [(r, show(cf, False), show(cf, True)) for r, cf in paper_cf[fam]]
        V = evaluate(fs.D)
        V_fresh = fresh.normal_form(evaluate(fresh.D))
        paper_fresh = {fam: fresh.normal_form(P) for fam, P in fresh.paper.items()}
        for j, ident in enumerate(idents):
            cf = closed_form(ident, fs, V[:, j, :])
            if cf.found:
                u = cf.values(fresh.D, m)
                fams = {fam: (np.stack([c.values(fresh.D, m) for _, c in rows_], axis=1), [r for r, _ in rows_])
                        for fam, rows_ in paper_cf.items() if all(c.found for _, c in rows_)}
            else:  # no closed form: the relation of its normal form with the paper's rows as the module writes them
                ok = np.all(np.isfinite(V_fresh[:, j, :]), axis=1)
                u = V_fresh[ok, j, :]
                fams = {fam: (P[ok], fs.paper_rows[fam]) for fam, P in paper_fresh.items()}
            fam_name, rel, res = _identify(u, fams)
            viol = _fresh_violation(cf, fresh, problem, rng) if cf.found else float("nan")
            rows.append(FamilyRow(t, ident, show(cf, False), show(cf, True) if cf.found else "", fam_name, rel, res,
                                  viol, cf.exact, cf.degree, source))
    for t in _paper_types(problem, ds.params):  # the paper's families on types without a discovered pair
        if t in by_type:
            continue
        try:
            fs = collect(problem, ds.params, t, N_FIT, seed)
        except AutotightError as e:
            notes.append(f"the paper's families on {t} were not written: {e}")
            continue
        names = data_names(problem, t, fs.D.shape[1])
        paper_out[t] = [(r, formula(cf, fs.roles, fs.block_sizes, names, d=fs.d),
                         formula(cf, fs.roles, fs.block_sizes, names, latex=True, d=fs.d))
                        for fam, P in fs.paper.items()
                        for cf, r in ((closed_form(r, fs, P[:, k, :]), r) for k, r in enumerate(fs.paper_rows[fam]))]
    if not ds.pairs:
        notes.append("the set has no learned pairs: the primary constraints alone are tight")
    return FamilyTable(ds.problem, rows, paper_out, notes)


def residual_note(r: FamilyRow) -> str:
    """" (residual … on N fresh factors)" of a relation; for a new family, how far the best combination of the
    paper's rows is; "" without a residual."""
    if np.isnan(r.residual):
        return ""
    if r.paper == "new":
        return f" (the best combination is off by {r.residual:.1e} relative)"
    return f" (residual {r.residual:.1e} on {N_FRESH} fresh factors)"


def text(tab: FamilyTable) -> str:
    """The table as text: per family its closed form, the paper family and the relation."""
    lines = ["discovered family | closed form | paper family | relation"]
    for r in tab.rows:
        lines.append(f"{r.factor_type}:{r.identity} | {r.closed_form} | {r.paper} | {r.relation}{residual_note(r)}")
    for t, rows in tab.paper.items():
        lines.append(f"paper families on {t}:")
        lines += [f"  {n}: {c}" for n, c, _ in rows]
    lines += tab.notes
    return "\n".join(lines)
