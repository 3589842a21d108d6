"""``autotight export SET --to python|latex|json-sparse``: a saved constraint set as code, LaTeX or triplets.

- ``python``: a standalone module (NumPy only, no autotight) whose ``constraint_matrices(factors, N)`` returns
  the learned constraints of an instance as symmetric sparse triplets, from each factor's measurement
  entries and columns; it evaluates the set's polynomial templates exactly as ``solve --set`` does
  (``autotight.discovery.templates``: coefficients = features(data) @ W, monomial μ = θ_iᵀθ_j in svec
  order, A_ii = p, A_ij = A_ji = p/2) and its transport templates (``autotight.discovery.transport``, with the
  module's M(data) written as a polynomial in the data, fitted exactly).  A factor type without a template
  (re-learned per factor) needs autotight's learning and is refused with a one-line error.
- ``latex``: the closed forms of the set's families beside the paper's (``autotight.closed_form``).
- ``json-sparse``: the templates as plain triplets, and with ``--seed`` the constraints of one instance
  (primary and learned) as upper-triangle triplets (i, j, A_ij), for another solver.
"""

from __future__ import annotations

import inspect
import json
from typing import Any

import numpy as np

from .errors import AutotightError
from .io import versions

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


# ---- transport templates: relations carried from a reference factor by M(data) (a polynomial in the data)
CLEAN = {clean!r}
MAX_FREE_COND = {max_free_cond!r}


{cleaned}


def _syms(P, n):
    """coefficient vectors (..., m) -> symmetric (..., n, n) with x^T A x = p . monomials"""
    jj, ii = np.tril_indices(n)
    S = np.zeros((*P.shape[:-1], n, n))
    S[..., ii, jj] = np.where(ii != jj, P / 2.0, P)
    S[..., jj, ii] = S[..., ii, jj]
    return S


def _polys(S):
    n = S.shape[-1]
    jj, ii = np.tril_indices(n)
    vals = S[..., ii, jj]
    return np.where(ii == jj, vals, 2.0 * vals)


def _carried_basic(P, Ms, free, rows):
    """the basic solutions ``rows`` (coefficient 1 on free[row], 0 on the other free monomials) of the
    relations P (m, k) carried by each M of Ms (c, n, n): A -> M^T A M"""
    c, n = Ms.shape[0], Ms.shape[1]
    k = P.shape[1]
    jj, ii = np.tril_indices(n)
    fi, fj = ii[free], jj[free]
    S = _syms(P.T, n).reshape(k * n, n)
    BF = np.empty((c, k, len(free)))
    for j in np.unique(fj):
        at = np.nonzero(fj == j)[0]
        AMj = (Ms[:, :, j] @ S.T).reshape(c, k, n)
        BF[:, :, at] = AMj @ Ms[:, :, fi[at]]
    BF = np.where(fi != fj, 2.0, 1.0) * BF
    E = np.eye(len(free))[:, rows]
    G = np.full((c, len(free), len(rows)), np.nan)
    for i in range(c):
        try:
            G[i] = np.linalg.solve(np.swapaxes(BF, 1, 2)[i], E)
        except np.linalg.LinAlgError:
            pass
    Pc = np.swapaxes(P @ G, 1, 2)  # (c, |rows|, m)
    Sc = _syms(Pc, n)
    V = _polys(np.swapaxes(Sc @ Ms[:, None], 2, 3) @ Ms[:, None])
    return _cleaned(V, free, rows)[0]


def _transport_coefficients(tpl, D):
    n = tpl["n_cols"]
    m = n * (n + 1) // 2
    MW = np.asarray(tpl["M_W"], dtype=float)

    def M(data):
        return (features(data, tpl["M_degree"]) @ MW).reshape(-1, n, n)

    M0inv = np.linalg.inv(M(np.asarray(tpl["data"], dtype=float))[0])
    P = np.zeros((m, tpl["n_relations"]))
    for i, j, v in tpl["basis_triplets"]:
        P[int(i), int(j)] = v
    free = np.asarray(tpl["free"], dtype=np.int64)
    want = np.asarray(tpl["want"], dtype=np.int64)
    return _carried_basic(P, M0inv @ M(D), free, want).reshape(len(D), -1)


def constraint_matrices(factors, N):
    """see the module docstring; a factor where a transport template has no basic solutions (NaN) is left
    out and named in ``constraint_matrices.skipped``"""
    out = []
    constraint_matrices.skipped = []
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
        if tpl["kind"] == "transport":
            coeffs = _transport_coefficients(tpl, D)
        else:
            coeffs = features(D, tpl["degree"]) @ np.asarray(tpl["W"], dtype=float)
        q, mono = support // m, support % m
        for a, ident in enumerate(tpl["identities"]):
            sel = np.flatnonzero(q == a)
            li, lj = ii[mono[sel]], jj[mono[sel]]
            off = li != lj
            for r in range(len(cols)):
                p = coeffs[r, sel]
                if np.isnan(p).any():
                    constraint_matrices.skipped.append(f"{{ftype}}[{{r}}]:{{ident}}")
                    continue
                nz = p != 0
                p, gi, gj, o = p[nz], cols[r, li][nz], cols[r, lj][nz], off[nz]
                rows = np.concatenate([gi, gj[o]])
                cc = np.concatenate([gj, gi[o]])
                vals = np.concatenate([np.where(o, p / 2, p), p[o] / 2])
                out.append((f"{{ftype}}[{{r}}]:{{ident}}", rows, cc, vals))
    return out
'''


#: the polynomial fit of a transport M(data) must reproduce the module's to this relative accuracy
TRANSPORT_RTOL = 1e-13


def transport_polynomial(problem, ds, tpl) -> tuple[int, np.ndarray]:
    """(degree, W) with M(data) = features(data, degree) @ W (n² entries, row-major) for the module's
    ``TRANSPORTS[type]``, fitted on factors of fresh instances (degree ≤ 2; entries snapped to fractions
    when that keeps the accuracy); AutotightError when no such polynomial reproduces it to
    ``TRANSPORT_RTOL`` on factors that took no part in the fit."""
    from .closed_form.polynomials import fractions_array, to_fractions
    from .closed_form.samples import data_params
    from .discovery.templates import features, n_features

    pars = problem.parse_params(data_params(problem, ds.params))
    D: list[np.ndarray] = []
    for i in range(200):
        model = problem.build(problem.generate(pars, np.random.default_rng([int(ds.seed or 0), 9000 + i])))
        D += [f.data for f in model.factors if f.type == tpl.factor_type and f.data is not None]
        if len(D) >= 2 * n_features(tpl.n_data, 2) + 20:
            break
    D_arr = np.array(D).reshape(len(D), tpl.n_data)
    Y = np.array([problem.transport(tpl.factor_type, d, tpl.n_cols).ravel() for d in D_arr])
    n_fit = len(D_arr) - 20
    for g in (0, 1, 2):
        Phi = features(D_arr, g)
        if n_fit < Phi.shape[1]:
            break
        W = np.linalg.lstsq(Phi[:n_fit], Y[:n_fit], rcond=None)[0]
        Wf = fractions_array(to_fractions(W))
        for cand in (Wf, W):
            err = np.max(np.abs(Phi @ cand - Y)) / max(np.max(np.abs(Y)), 1e-300)
            if err <= TRANSPORT_RTOL:
                return g, cand
    raise AutotightError(f"the transport of factor type {tpl.factor_type!r} is not a polynomial of degree ≤ 2 in "
                         "its data: it cannot be exported as code")


def exported_templates(problem, ds) -> dict[str, dict[str, Any]]:
    """Each factor type's template as plain lists for the exported module (polynomial, or transport with
    its M(data) as a polynomial); AutotightError for a type without a template."""
    ts = ds.templates
    if ts is None:
        raise AutotightError("the set has no templates (format 1): re-save it with `autotight templates SET --out NEW`")
    out = {}
    for t in sorted({t for t, _ in ds.pairs}):
        tpl = ts.templates.get(t)
        if tpl is None:
            raise AutotightError(f"factor type {t!r} has no template (it is re-learned per factor on every instance): "
                                 "it cannot be exported as code; `autotight templates SET --out NEW` learns one")
        rec = {"kind": tpl.kind, "identities": list(tpl.identities), "n_cols": tpl.n_cols, "n_data": tpl.n_data,
               "support": tpl.support.tolist()}
        if tpl.kind == "polynomial":
            rec |= {"degree": tpl.degree, "W": tpl.W.tolist()}
        else:
            g, MW = transport_polynomial(problem, ds, tpl)
            r, c = np.nonzero(tpl.basis)
            rec |= {"M_degree": g, "M_W": MW.tolist(), "data": tpl.data.tolist(), "free": tpl.free.tolist(),
                    "want": tpl.want.tolist(), "n_relations": int(tpl.basis.shape[1]),
                    "basis_triplets": [[int(i), int(j), float(tpl.basis[i, j])] for i, j in zip(r, c)]}
        out[t] = rec
    return out


def python_source(problem, ds, source: str) -> str:
    """The standalone module (see the module docstring)."""
    from ._version import __version__
    from .discovery.nullspace import CLEAN, MAX_FREE_COND
    from .discovery.transport import _cleaned

    tpls = exported_templates(problem, ds)
    return PYTHON.format(source=source, problem=ds.problem, version=__version__, templates=json.dumps(tpls),
                         clean=CLEAN, max_free_cond=MAX_FREE_COND, cleaned=inspect.getsource(_cleaned).strip())


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
    rec["fallback"] = dict(ts.fallback)  # types re-learned per factor: no template to write
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
