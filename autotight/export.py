"""``autotight export SET --to python|latex|json-sparse``: a saved constraint set as code, LaTeX or triplets.

- ``python``: a standalone module (NumPy only, no autotight) whose ``constraint_matrices(factors, N)`` returns
  the learned constraints of an instance as symmetric sparse triplets, from each factor's measurement
  entries and columns; it evaluates the set's polynomial templates exactly as ``solve --set`` does
  (``autotight.discovery.templates``: coefficients = features(data) @ W, monomial μ = θ_iᵀθ_j in svec
  order, A_ii = p, A_ij = A_ji = p/2).  Factor types with a transport template or none (re-learned per
  factor) need autotight's learning and are refused with a one-line error.
- ``latex``: the closed forms of the set's families beside the paper's (``autotight.closed_form``).
- ``json-sparse``: the templates as plain triplets, and with ``--seed`` the constraints of one instance
  (primary and learned) as upper-triangle triplets (i, j, A_ij), for another solver.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from .errors import AutotightError
from .io import jsonable, versions
from .outpaths import check_file, writing

FORMATS = ("python", "latex", "json-sparse")

PYTHON = '''"""Learned constraints of the set {source} (problem {problem}), exported by autotight {version}.

Needs NumPy only.  ``constraint_matrices(factors, N)``: ``factors`` maps each factor type to
(columns (n_f, n) int, data (n_f, p) float): per factor, the lifted columns of its blocks in order (h first;
for a matrix lifting, the d columns of each block) and its measurement entries (``Factor.data``).  Returns a
list of (name, rows, cols, values): the symmetric N × N matrix A of the constraint <A, X> = 0 as triplets
(both triangles).  Coefficients: p = features(data) @ W on the positions ``support`` of the stacked
k·m vector (identity q = pos // m, monomial pos % m in svec order: column-major upper triangle of the
factor's n columns, no sqrt 2); A_ii = p, A_ij = A_ji = p / 2.
"""

import numpy as np

TEMPLATES = {templates}


def features(D, degree):
    """[1, d_i, d_i d_j (i <= j, svec order)] up to degree, per row of D (n, p)."""
    D = np.atleast_2d(np.asarray(D, dtype=float))
    cols = [np.ones((D.shape[0], 1))]
    if degree >= 1:
        cols.append(D)
    if degree >= 2:
        jj, ii = np.tril_indices(D.shape[1])
        cols.append(D[:, ii] * D[:, jj])
    return np.concatenate(cols, axis=1)


def constraint_matrices(factors, N):
    out = []
    for ftype, tpl in TEMPLATES.items():
        if ftype not in factors:
            continue
        cols, D = factors[ftype]
        cols = np.asarray(cols, dtype=np.int64)
        D = np.asarray(D, dtype=float).reshape(len(cols), tpl["n_data"])
        n = tpl["n_cols"]
        m = n * (n + 1) // 2
        jj, ii = np.tril_indices(n)  # svec order: (i, j), i <= j, column-major upper triangle
        support = np.asarray(tpl["support"], dtype=np.int64)
        coeffs = features(D, tpl["degree"]) @ np.asarray(tpl["W"], dtype=float)
        q, mono = support // m, support % m
        for a, ident in enumerate(tpl["identities"]):
            sel = np.flatnonzero(q == a)
            li, lj = ii[mono[sel]], jj[mono[sel]]
            off = li != lj
            for r in range(len(cols)):
                p = coeffs[r, sel]
                gi, gj = cols[r, li], cols[r, lj]
                rows = np.concatenate([gi, gj[off]])
                cc = np.concatenate([gj, gi[off]])
                vals = np.concatenate([np.where(off, p / 2, p), p[off] / 2])
                out.append((f"{{ftype}}[{{r}}]:{{ident}}", rows, cc, vals))
    return out
'''


def _polynomial_templates(ds) -> dict[str, dict[str, Any]]:
    ts = ds.templates
    if ts is None:
        raise AutotightError("the set has no templates (format 1): re-save it with `autotight templates SET --out NEW`")
    types = sorted({t for t, _ in ds.pairs})
    out = {}
    for t in types:
        tpl = ts.templates.get(t)
        if tpl is None:
            raise AutotightError(f"factor type {t!r} has no template (it is re-learned per factor on every instance): "
                                 "it cannot be exported as code")
        if tpl.kind != "polynomial":
            raise AutotightError(f"factor type {t!r} has a {tpl.kind} template; only polynomial templates are "
                                 "exported as code")
        out[t] = {"identities": list(tpl.identities), "n_cols": tpl.n_cols, "n_data": tpl.n_data,
                  "degree": tpl.degree, "support": tpl.support.tolist(), "W": tpl.W.tolist()}
    return out


def python_source(ds, source: str) -> str:
    """The standalone module (see the module docstring)."""
    from . import __version__

    tpls = _polynomial_templates(ds)
    return PYTHON.format(source=source, problem=ds.problem, version=__version__,
                         templates=json.dumps(tpls, indent=1))


def latex_source(problem, ds) -> str:
    from .closed_form.table import family_table
    from .closed_form.tex import document

    return document(family_table(problem, ds))


def sparse_record(problem, ds, source: str, seed: int | None) -> dict[str, Any]:
    """Templates as triplets (feature, support position, W), and with ``seed`` one instance's constraints."""
    rec: dict[str, Any] = {"format": "autotight.sparse/1", "set": source, "problem": ds.problem,
                           "versions": versions(), "templates": {}}
    ts = ds.template_set(problem)
    for t, tpl in ts.templates.items():
        if tpl.kind != "polynomial":
            rec["templates"][t] = {"kind": tpl.kind, "note": "not a polynomial template: see the set file"}
            continue
        f, s = np.nonzero(tpl.W)
        rec["templates"][t] = {"kind": "polynomial", "identities": tpl.identities, "n_cols": tpl.n_cols,
                               "n_data": tpl.n_data, "degree": tpl.degree, "support": tpl.support.tolist(),
                               "W_triplets": [[int(a), int(b), float(tpl.W[a, b])] for a, b in zip(f, s)]}
    rec["convention"] = ("template: coefficients p = features(data) @ W on positions 'support' (identity = pos // m, "
                         "monomial pos % m, svec order of the factor's columns, no √2); features = [1, δ_i, δ_i δ_j "
                         "(i ≤ j, svec order)] up to 'degree'; constraint: Σ p_μ θ_iᵀθ_j = 0. instance: triplets "
                         "[i, j, A_ij] of the upper triangle of A, ⟨A, X⟩ = b")
    if seed is not None:
        from .constraint_set import ConstraintSet, resolve

        inst = problem.generate(ds.params, seed)
        model = problem.build(inst)
        cons = resolve(ConstraintSet(ds), problem, inst, model, np.random.default_rng([seed, 5]))
        import scipy.sparse as sp

        recs = []
        for c in cons:
            A = sp.coo_array(c.A)
            up = A.row <= A.col
            recs.append({"name": c.name, "b": c.b, "triplets": [[int(i), int(j), float(v)] for i, j, v in
                                                                 zip(A.row[up], A.col[up], A.data[up])]})
        rec["instance"] = {"seed": seed, "params": inst.params, "N": model.variables.N, "constraints": recs}
    return rec


def register(sub: argparse._SubParsersAction, add_problem_args=None) -> None:
    """The ``export`` subcommand (the set file names its problem)."""
    p = sub.add_parser("export", help="a saved constraint set as standalone Python, LaTeX or sparse triplets")
    p.add_argument("set", help="a constraint-set file (from `discover --out`)")
    p.add_argument("--to", required=True, choices=FORMATS, help="python: a NumPy-only module; latex: the closed "
                   "forms beside the paper's; json-sparse: triplets")
    p.add_argument("--out", default=None, help="write to this file (default: standard output)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--seed", type=int, default=None, help="json-sparse: also the constraints of the instance with "
                   "this seed at the set's parameters")
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from .cli_checks import check_set_file
    from .discovery.discovered import DiscoveredSet
    from .problem import load

    if args.out is not None:
        check_file(args.out, force=args.force)
    check_set_file(args.set)
    ds = DiscoveredSet.load(args.set)
    prob = load(ds.problem)
    if args.to == "python":
        text = python_source(ds, args.set)
    elif args.to == "latex":
        text = latex_source(prob, ds)
    else:
        text = json.dumps(jsonable(sparse_record(prob, ds, args.set, args.seed)), ensure_ascii=False)
    if args.out is None:
        print(text)
        return 0
    with writing(args.out):
        from .io import atomic_write_text

        atomic_write_text(args.out, text)
    print(f"saved to {args.out}")
    return 0
