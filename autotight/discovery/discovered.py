"""A discovered set: (factor type, identity) pairs that carry over to any instance, saved as JSON.

Format 2 (``autotight.constraint_set/2``, see ``docs/constraint_sets.md``) is self-contained: the
problem and its parameters, the pairs, their templates (``templates``: coefficients as polynomials in a
factor's measurement entries) or, for factor types without one, the reason and the settings to re-learn
them per factor, the variable order with each block's size, offset and the factor roles it plays, the
svec/triplet convention, and the learning instance's full constraint list (h², primary and learned).
Format 1 files (``autotight.discovered/1``: pairs and learned constraints only) still load; their
templates are learned on first use.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import AutotightError, LearningError
from ..io import versions
from ..model import Constraint, Model, Variables
from ..outpaths import save_json
from ..pretty import polynomial
from ..problem import Instance, Problem
from .catalog import Pair, carry_over
from .learn import LearnOptions
from .templates import TemplateSet, apply_templates, learn_templates

#: the ``format`` of a constraint-set file, and the older one still read
FORMAT = "autotight.constraint_set/2"
FORMAT_V1 = "autotight.discovered/1"


CONVENTION = {
    "lifting": "Θ = [h, x_1, …] (d × N); X = ΘᵀΘ; blocks are consecutive columns of Θ in the order of "
               "'variables' (h first, d columns)",
    "constraint": "⟨A, X⟩ = b with A symmetric N×N; 'triplets' [i, j, A_ij] list the upper triangle (i ≤ j), "
                  "the lower is its mirror",
    "template": "for a factor with local columns c_0…c_{n−1} (its blocks in order), coefficient vector "
                "p = features(data) @ W on positions 'support' of the k·m stacked vector (identity q = pos // m, "
                "monomial pos % m, m = n(n+1)/2); monomial μ is θ_{c_i}ᵀθ_{c_j}, i ≤ j, in svec order (column-"
                "major upper triangle, no √2); the constraint is Σ p_μ θ_{c_i}ᵀθ_{c_j} = 0, i.e. A_ii = p, "
                "A_ij = A_ji = p/2; features(δ) = [1, δ_i, δ_i δ_j (i ≤ j, svec order)] up to 'degree'",
    "transport template": "kind 'transport': 'basis_triplets' [μ, q, value] hold the type's basic solutions at "
                          "the reference measurement (m × n_relations); for a factor with data δ, M = the problem "
                          "module's TRANSPORTS[type](δ) (n × n), each relation A_q becomes Mᵀ A_q M, and the "
                          "coefficients are the basic solutions of that span with coefficient 1 on monomial "
                          "'free'[j] and 0 on the other free monomials; identity j of 'identities' is row "
                          "'want'[j] (autotight/discovery/transport.py)",
    "svec": "svec(X) stacks the upper triangle column by column, off-diagonal entries times √2 (Clarabel's "
            "PSDTriangle layout); ⟨A, X⟩ = svec(A)·svec(X)",
}


def constraint_record(c: Constraint, model: Model) -> dict[str, Any]:
    """A constraint as sparse upper-triangle triplets (i, j, A_ij) with its readable form."""
    A = sp.coo_array(c.A)
    up = A.row <= A.col
    return {"name": c.name, "factor": c.factor, "identity": c.identity, "family": c.family, "b": c.b,
            "triplets": [[int(i), int(j), float(v)] for i, j, v in zip(A.row[up], A.col[up], A.data[up])],
            "readable": readable(c, model)}


def readable(c: Constraint, model: Model) -> str:
    """``pretty.polynomial`` of ``c`` on the blocks it touches only (its cost is then independent of N)."""
    V = model.variables
    A = sp.coo_array(c.A)
    touched = {V.block_of(int(k))[0] for k in np.unique(np.concatenate([A.row, A.col]))} - {"h"}
    names = [n for n in V.names[1:] if n in touched]
    sub = Variables([(n, V.sizes[n]) for n in names], d=V.d)
    old = np.concatenate([np.arange(V.offsets[n], V.offsets[n] + V.sizes[n]) for n in ["h", *names]])
    new = np.full(V.N, -1, dtype=np.int64)
    new[old] = np.arange(old.size)
    As = sp.coo_array((A.data, (new[A.row], new[A.col])), shape=(sub.N, sub.N))
    return polynomial(As, sub, c.b)


def variables_record(model: Model) -> list[dict[str, Any]]:
    """Each block: name, size, offset and the (factor type, role) pairs it plays."""
    roles: dict[str, set] = {}
    for f in model.factors:
        for b, r in zip(f.blocks, f.roles or f.blocks):
            roles.setdefault(b, set()).add((f.type, r))
    V = model.variables
    return [{"block": n, "size": V.sizes[n], "offset": V.offsets[n],
             "roles": [list(x) for x in sorted(roles.get(n, set()))]} for n in V.names]


@dataclass
class DiscoveredSet:
    """The pairs found by discovery on (problem, params, seed), how they were learned and their templates."""

    problem: str
    params: dict[str, Any]
    seed: int | None
    pairs: list[Pair]
    learn_options: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    groups: str | list[list[str]] = "factors"
    templates: TemplateSet | None = None
    d: int | None = None

    def validation_warning(self) -> str:
        """'' or one line: the discovery that saved this set ran out of budget before a held-out batch passed
        (``info["validation"]``, written by ``autotight.discovery.engine``)."""
        v = self.info.get("validation") if isinstance(self.info, dict) else None
        if isinstance(v, dict) and v.get("passed") is False:
            return f"this set failed validation when it was discovered ({v.get('message', '')})"
        return ""

    def validated_points(self) -> list[dict[str, Any]] | None:
        """The parameters of every point at which discovery's held-out validation solved instances with this
        set (``info["validation"]["rounds"]``: the set's parameters with each point's varied ones, over all
        rounds, without repeats), or None when the file records no such evidence (older formats, sets made
        from Python)."""
        v = self.info.get("validation") if isinstance(self.info, dict) else None
        rounds = v.get("rounds") if isinstance(v, dict) else None
        if not rounds:
            return None
        out: list[dict[str, Any]] = []
        for r in rounds:
            for p in r.get("points", []):
                if p.get("instances", 0) and (point := dict(self.params) | dict(p.get("varied") or {})) not in out:
                    out.append(point)
        return out or None

    def scope_note(self, points: Sequence[dict[str, Any]]) -> str:
        """'' when held-out validation ran at every parameter point of ``points`` (full parameters; equal when every
        parameter the validated point has is equal, numbers to a relative 1e-9), else one line: where it ran and the
        points of ``points`` it did not reach, by the parameters that differ.  A verdict there is still that
        instance's own (its validity check and certificate); the note says the set's held-out evidence does not
        cover it."""
        done = self.validated_points()
        if done is None:
            return ""

        def same(a: Any, b: Any) -> bool:
            if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
                return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=0.0))
            return bool(a == b)

        def differ(point: dict[str, Any], params: dict[str, Any]) -> list[str]:
            return [k for k in point if k in params and not same(point[k], params[k])]

        missed = [p for p in points if all(differ(q, p) for q in done)]
        if not missed:
            return ""
        keys = sorted({k for p in missed for q in done for k in differ(q, p)})

        def label(p: dict[str, Any]) -> str:
            return ", ".join(f"{k} = {p[k]}" for k in keys)

        return (f"held-out validation of this set ran at {'; '.join(dict.fromkeys(map(label, done)))} only, not at "
                f"{'; '.join(dict.fromkeys(map(label, missed)))}: verdicts there are the instances' own, outside the "
                "set's evidence (`autotight discover` over those parameters, e.g. with --sigmas, validates a set "
                "there)")

    def options(self) -> LearnOptions:
        return LearnOptions(**self.learn_options) if self.learn_options else LearnOptions()

    def template_set(self, problem: Problem, progress=None, cache: dict | None = None) -> TemplateSet:
        """The templates (learned once, on fresh instances at ``template_points``, when not loaded; ``cache``:
        ``templates.learn_templates``'s)."""
        if self.templates is None:
            if self.groups != "factors":
                self.templates = TemplateSet({}, {t: f"learned on groups {self.groups!r}, not factors: no template"
                                                  for t in sorted({t for t, _ in self.pairs})})
            else:
                self.templates = learn_templates(problem, self.template_points(problem), self.pairs,
                                                 int(self.seed or 0), self.options(), progress=progress, cache=cache)
        return self.templates

    def template_points(self, problem: Problem) -> list[dict[str, Any]]:
        """Where the templates are fitted and checked: the set's parameters, or, for a set discovered over a
        range (``info["range"]["over"]``), every point of that range at the set's other parameters (its
        learning size, for a set selected at another one)."""
        from ..points import points_of

        over = (self.info.get("range") or {}).get("over") or {}
        if not over:
            return [dict(self.params)]
        fixed = {k: v for k, v in self.params.items() if k not in over}
        return [full for full, _ in points_of(problem, fixed, over)]

    def _check(self, problem: Problem, model: Model | None) -> None:
        if problem.name != self.problem:
            raise AutotightError(f"the constraint set is for {self.problem!r}, not {problem.name!r}")
        if model is not None and self.d is not None and model.d != self.d:
            raise AutotightError(f"the constraint set has lifting width d = {self.d}, this model d = {model.d}")

    def apply(self, problem: Problem, inst: Instance, model: Model, rng: np.random.Generator,
              skip_invalid: bool = False) -> list[Constraint]:
        """The set's constraints on ``inst``: templates evaluated (each checked on fresh states of ``inst``),
        the pairs of types without a template re-learned per factor (strict, see ``instantiate``)."""
        self._check(problem, model)
        ts = self.template_set(problem)
        out, _, relearn = apply_templates(problem, inst, model, ts, rng, self.options(), skip_invalid)
        rest = [p for p in self.pairs if p[0] not in ts.templates]
        if relearn:  # factors where a transport template has no basic solutions: learned as without templates
            here = {model.factor(f).type for f in relearn}
            out += self._carry(problem, inst, model, rng, [p for p in self.pairs if p[0] in here], skip_invalid,
                               names=relearn)
        if rest:
            out += self._carry(problem, inst, model, rng, rest, skip_invalid)
        return out

    def _carry(self, problem: Problem, inst: Instance, model: Model, rng: np.random.Generator, pairs: list[Pair],
               skip_invalid: bool, names: list[str] | None = None) -> list[Constraint]:
        co = carry_over(problem, inst, pairs, rng, self.options(), model, self.groups, names=names)
        if co.issues and not skip_invalid:
            raise LearningError(f"cannot re-instantiate the discovered set: {co.message() or co.issues[0]}")
        return co.constraints

    def instantiate(self, problem: Problem, inst: Instance, rng: np.random.Generator,
                    model: Model | None = None, strict: bool = True) -> list[Constraint]:
        """The set's constraints on ``inst``, re-learned on every factor (each checked on held-out samples of
        ``inst``): the route without templates.

        strict: any shortfall (per factor type, fewer constraints than pairs × factors of the type)
        or identity rejected on held-out samples raises LearningError naming the factor types and
        their counts; strict=False returns what was instantiated."""
        self._check(problem, model)
        co = carry_over(problem, inst, self.pairs, rng, self.options(), model, self.groups)
        if co.issues and strict:
            raise LearningError(f"cannot re-instantiate the discovered set: {co.message() or co.issues[0]}")
        return co.constraints

    def save(self, path: str | Path, model: Model | None = None, constraints: list[Constraint] | None = None,
             extra: dict[str, Any] | None = None, problem: Problem | None = None, replace: bool = False) -> Path:
        """Write format 2; learns the templates first when they are missing (``problem``: default, the
        problem module named by the set).  replace=False never writes over an existing file
        (``outpaths.save_json``: kept beside it instead); returns the path written."""
        templates = self.templates
        if templates is None:
            from ..problem import load

            templates = self.template_set(problem or load(self.problem))
        obj: dict[str, Any] = {
            "format": FORMAT, "problem": self.problem, "params": self.params, "seed": self.seed,
            "versions": versions(), "learn_options": self.learn_options, "groups": self.groups,
            "pairs": [{"factor_type": t, "identity": i} for t, i in self.pairs], "info": self.info,
            "convention": CONVENTION,
        }
        obj |= templates.record()
        if model is not None:
            obj["variables"] = variables_record(model)
            obj["d"] = model.d
        if constraints is not None and model is not None:
            groups: dict[str, list] = {}
            for c in constraints:
                groups.setdefault(c.factor or "", []).append(constraint_record(c, model))
            obj["constraints_by_factor"] = groups
            obj["learning_instance"] = {"constraints": [constraint_record(c, model) for c in model.primary()]
                                        + [r for g in groups.values() for r in g],
                                        "note": "every constraint of the learning instance's SDP: h², primary, learned"}
        obj |= extra or {}
        return save_json(path, obj, replace=replace, what="the constraint set")

    @classmethod
    def load(cls, path: str | Path) -> "DiscoveredSet":
        try:
            obj = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as e:
            raise AutotightError(f"cannot read constraint set {path}: {e}") from None
        fmt = obj.get("format") if isinstance(obj, dict) else None
        if fmt not in (FORMAT, FORMAT_V1):
            raise AutotightError(f"{path} is not a constraint-set file (format {fmt!r})")
        try:
            pairs = [(p["factor_type"], p["identity"]) for p in obj["pairs"]]
            ts = TemplateSet.from_record(obj) if fmt == FORMAT else None
            return cls(obj["problem"], obj["params"], obj.get("seed"), pairs, obj.get("learn_options", {}),
                       obj.get("info", {}), obj.get("groups", "factors"), ts, obj.get("d"))
        except (KeyError, TypeError, ValueError) as e:
            raise AutotightError(f"{path}: malformed constraint-set file ({type(e).__name__}: {e})") from None
