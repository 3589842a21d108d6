"""One instance of a factor-graph problem: its ``Model`` and its stacked residual for the local solver.

The model's factors (``autotight.model.Factor``), which discovery learns on, are:

- one per variable type and index (type: the variables' ``type``, default the name; name: the type,
  suffixed ``_i`` for element i of a stack; blocks and roles: the main blocks of the variables of its product
  blocks, then each variable's main block, lifting and product blocks, in declaration order; variables of one
  type share it, e.g. a pose's t and C), holding the manifold's, the lifting's and the products' primary
  constraints and the cost of every declared factor whose variables all belong to it, or are one element and
  the variables of its products, and that has no constraints of its own;
- one per (type, variables) of the other declared factors without constraints of their own (their costs
  summed), named ``type:variables``;
- one per declared factor with constraints or auxiliary blocks of its own, or declared ``own`` (named
  ``Factor.name``, default ``type_i``, with its ``data``; roles ``Factor.roles`` when given), and one per factor
  of a ``Family`` with auxiliary blocks or paper rows (``family.FamilyTerm``; the family's other factors' costs
  go where a ``Factor``'s would);
- one per ``Group`` (blocks h and its blocks, no cost, no constraints), in declaration order among the
  factors of their own;
- no factor for a variable with neither primary constraints nor a cost of its own.

A declared ``Factor``'s model factor lists h, its variables' blocks, then its auxiliary blocks; with the module's
order of the lifted vector (``derive(blocks=…)``), h, then its blocks in that order.

The families' paper rows make ``Model.paper``, their clique hints ``Model.cliques``.  Primary constraints are
named by the variables' and factors' ``constraint_names`` formats; the names must be distinct in the model.

Cost-only variables (``Variable.cost_only``) have no factor of their own and are left out of the model
factors' blocks and roles; a declared cost on one (``Factor`` or ``Family``) joins no model factor (one with
constraints or auxiliary blocks of its own keeps them and has no cost), and the model then carries its whole
cost explicitly, ``Model.cost``: every declared cost summed in declaration order (a family's factor by factor),
each as two halves (``Graph._cost``).

Roles of a variable's blocks inside a factor: its main block's names without the index and its lifting and
product blocks' names, suffixed ``_k`` (k its position in the factor) when a variable of the same name appears twice;
then the factor's auxiliary blocks' names.  The auxiliary blocks of the factors, after every variable's
blocks in factor order (a family's factors in their order): block ``b`` of the j-th factor declaring a block
``b`` is named ``Auxiliary.element`` of b and j (default ``b_j``).
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError
from ..model import Constraint, Factor, Model, canonical_coo
from .declare import Factor as Declared
from .declare import Family, Group, Variable
from .family import FamilyTerm, scatter
from .layout import Element, Layout, gram_form
from .terms import Term, equation_names


def _global(local: np.ndarray, columns: np.ndarray, N: int) -> sp.coo_array:
    """The N×N matrix of a matrix on local columns mapped to ``columns``."""
    r, c = np.nonzero(local)
    return canonical_coo(columns[r], columns[c], local[r, c], N)


def _modelled(elements: Sequence[Element]) -> list[Element]:
    """The elements a model factor lists: all but the cost-only variables'."""
    return [el for el in elements if not el.var.cost_only]


def _touches_cost_only(elements: Sequence[Element]) -> bool:
    return any(el.var.cost_only for el in elements)


def _roles(elements: Sequence[Element], over: Sequence[Element] = ()) -> tuple[str, ...]:
    """h, the main and lifting blocks' names of ``over`` (the variables of the elements' products; a lifting's
    suffixed ``_`` and its variable's name where an element's block has the same name), then each element's main,
    lifting and product blocks' names (suffixed ``_k`` for a variable appearing twice)."""
    elements = _modelled(elements)
    stems = [el.var.main_blocks() for el in elements]
    own: list[str] = []
    for k, el in enumerate(elements):
        sfx = f"_{k}" if stems.count(el.var.main_blocks()) > 1 else ""
        own += [b + sfx for b in el.var.main_blocks()] + [f.name + sfx for f in el.var.fits()] + \
            [b + sfx for b in el.var.products]
    out: list[str] = ["h"]
    for el in over:
        out += list(el.var.main_blocks()) + [f.name if f.name not in own else f"{f.name}_{el.var.name}"
                                             for f in el.var.fits()]
    return tuple(out + own)


def _over(layout: Layout, elements: Sequence[Element]) -> list[Element]:
    """The variables of the elements' products (single elements), in order, each once."""
    out: list[Element] = []
    for el in elements:
        out += [o for src in layout.sources.get(id(el.var), []) for o in src if all(o is not p for p in out)]
    return out


def _holder(layout: Layout, elements: Sequence[Element], home: Mapping[str, tuple[str, int | None]]
            ) -> tuple[str, int | None] | None:
    """The variables' own factor that a cost on the elements joins: their common one, else that of the element
    whose products' variables are all the others (e.g. w_i's, holding t and C); None if there is none."""
    keys = {home[el.main] for el in elements}
    if len(keys) == 1:
        return keys.pop()
    for el in elements:
        over = _over(layout, [el])
        if over and all(o is el or any(o is p for p in over) for o in elements):
            return home[el.main]
    return None


def _auxiliary_blocks(items: Sequence[Declared | Family | Group]) -> list[list[list[str]]]:
    """Per declared item, per factor in it (one for a ``Factor`` or ``Group``, F for a ``Family``), its auxiliary
    blocks' names in the lifted vector (``Auxiliary.element`` of ``b`` and j: the j-th factor declaring ``b``)."""
    seen: dict[str, int] = {}
    out: list[list[list[str]]] = []
    for f in items:
        members = []
        aux = None if isinstance(f, Group) else f.auxiliary
        blocks, element = (list(aux.blocks), aux.element) if aux is not None else ([], "")
        given = f.aux_names if isinstance(f, Family) else None
        for j in range(f.size if isinstance(f, Family) else 1):
            names = []
            for b in blocks:
                names.append(element.format(block=b, i=seen.get(b, 0) if given is None else given[j]))
                seen[b] = seen.get(b, 0) + 1
            members.append(names)
        out.append(members)
    return out


class _Member:
    """A factor of a family without auxiliary blocks or paper rows, whose cost joins a variable's factor or a
    grouped one as a ``Term``'s does."""

    def __init__(self, term: FamilyTerm, f: int, cost: sp.coo_array):
        self.elements, self.type, self.columns, self._cost = term.elements[f], term.type, term.columns[f], cost

    def global_cost(self) -> sp.coo_array:
        return self._cost


def _alone(t: Term) -> bool:
    """Whether a declared ``Factor`` is a model factor of its own (constraints, auxiliary blocks or ``own``)."""
    return bool(t.factor.constraints) or t.aux is not None or t.factor.own


def _own(t: FamilyTerm) -> bool:
    """Whether a family's factors are model factors of their own (auxiliary blocks or paper rows)."""
    return t.aux is not None or bool(t.paper)


def _own_factors(layout: Layout) -> dict[tuple[str, int | None], list[Element]]:
    """The variables' own model factors: elements grouped by (type, index), in layout order."""
    out: dict[tuple[str, int | None], list[Element]] = {}
    for el in _modelled(layout.elements):
        out.setdefault((el.var.type or el.var.name, el.index), []).append(el)
    return out


class Graph:
    """The declared variables and factors on one instance (see the module docstring)."""

    def __init__(self, variables: Sequence[Variable], truth: Mapping[str, Any],
                 factors: Iterable[Declared | Family | Group], by_element: bool = False,
                 tangent: Sequence[str] | None = None, order: Sequence[str] | None = None,
                 width: int | None = None):
        declared = list(factors)
        for f in declared:
            if not isinstance(f, (Declared, Family, Group)):
                raise ProblemDefinitionError("factors must yield autotight.graph.Factor, Family or Group, got "
                                             f"{type(f).__name__}")
        if width is not None and width > 1 and any(isinstance(f, Family) for f in declared):
            raise ProblemDefinitionError(f"a lifting of width {width} holds no factor families; declare Factor")
        aux = _auxiliary_blocks(declared)
        blocks = [(b, k) for f, members in zip(declared, aux) if not isinstance(f, Group) and f.auxiliary is not None
                  for bs in members for b, k in zip(bs, f.auxiliary.blocks.values())]
        self.layout = layout = Layout(variables, truth, blocks, by_element, tangent, order, width)
        self.terms: list[Term] = []
        self.families: list[FamilyTerm] = []
        #: the declared items in order, resolved (a ``Group`` with its model factor's name)
        self.items: list[Term | FamilyTerm | tuple[str, Group]] = []
        for i, (f, members) in enumerate(zip(declared, aux)):
            if isinstance(f, Family):
                names = f.names or [f"{f.type}_{j}" for j in range(f.size)]
                self.families.append(FamilyTerm(f, layout, names, members))
                self.items.append(self.families[-1])
            elif isinstance(f, Group):
                unknown = [b for b in f.blocks if b not in layout.V]
                if unknown:
                    raise ProblemDefinitionError(f"group {f.name or f.type!r}: unknown blocks {unknown}; blocks are "
                                                 f"{layout.V.names}")
                self.items.append((f.name or f"{f.type}_{i}", f))
            else:
                self.terms.append(Term(f, layout, f.name or f"{f.type or 'factor'}_{i}", members[0]))
                self.items.append(self.terms[-1])
        self.aux_terms = [t for t in self.terms if t.aux is not None]
        #: whether some factor has auxiliary blocks (whose values may be undefined at a state)
        self.has_auxiliary = bool(self.aux_terms) or any(t.aux is not None for t in self.families)
        names = [t.name for t in self.terms if _alone(t)]
        names += [n for t in self.families if _own(t) for n in t.names]
        names += [item[0] for item in self.items if isinstance(item, tuple)]
        if len(set(names)) != len(names):
            raise ProblemDefinitionError(f"factors with constraints or auxiliary blocks, and groups, need distinct "
                                         f"names, got {sorted(n for n in set(names) if names.count(n) > 1)}")
        self._stack: tuple[sp.csr_array, sp.csr_array, list[tuple[int, Term]]] | None = None

    def model(self) -> Model:
        L, N = self.layout, self.layout.V.N
        owners = _own_factors(L)
        home = {el.main: key for key, els in owners.items() for el in els}
        costs: dict[tuple[str, int | None], list[Term | _Member]] = {key: [] for key in owners}
        grouped: dict[tuple[str, tuple[str, ...]], list[Term | _Member]] = {}
        own: list[Term | FamilyTerm | tuple[str, Group]] = []
        every: list[Term | _Member] = []  # every declared cost, in order (the model's, with cost-only variables)
        loose = False  # whether some cost is on a cost-only variable (then in no model factor)
        family_costs: dict[int, list[sp.coo_array]] = {}
        for item in self.items:
            if isinstance(item, tuple):
                own.append(item)
                continue
            if isinstance(item, FamilyTerm):
                fam_costs = item.costs(N) if item.family.residual is not None else []
                family_costs[id(item)] = fam_costs
                members: list[Term | _Member] = [_Member(item, f, C) for f, C in enumerate(fam_costs)]
                every += members
                loose = loose or bool(members) and _touches_cost_only(item.elements[0])
                if _own(item):
                    own.append(item)
                    continue
            else:
                every.append(item)
                loose = loose or _touches_cost_only(item.elements)
                if _alone(item):
                    own.append(item)
                    continue
                members = [item]
            for t in members:
                if _touches_cost_only(t.elements):
                    continue  # in the model's explicit cost only
                key = _holder(L, t.elements, home)
                if key is not None:
                    costs[key].append(t)
                else:
                    grouped.setdefault((t.type, tuple(el.main for el in t.elements)), []).append(t)
        names, mats = self._variable_constraints()
        var_factors: dict[tuple[str, int | None], Factor] = {}
        for (typ, index), els in owners.items():
            stem = els[0].var.factor or typ
            name = stem if index is None else f"{stem}_{index}"
            cons = []
            for el in els:
                split = len(el.var.main_blocks()) > 1  # named by the variable, not its first block
                label = el.var.name + ("" if index is None else str(index)) if split else el.main
                fmt = el.var.constraint_names
                if callable(fmt):
                    labels = [fmt(factor=name, variable=label, constraint=nm, equation=eq, row=row, index=index)
                              for nm, (eq, row) in zip(names[id(el.var)], el.var.equations())]
                else:
                    labels = [fmt.format(factor=name, variable=label, constraint=nm) for nm in names[id(el.var)]]
                cons += [Constraint(A, 0.0, name=lab, factor=name) for lab, A in zip(labels, mats[L.position[el.main]])]
            cost = self._cost(costs[(typ, index)], N)
            if cons or cost is not None:  # a variable with neither (e.g. a free translation) has no factor
                over = _over(L, els)
                blocks = ("h",) + tuple(b for o in over for b in o.blocks[:len(o.var.main_blocks()) +
                                                                           len(o.var.fits())]) + \
                    tuple(b for el in els for b in el.blocks)
                var_factors[(typ, index)] = Factor(name, typ, blocks, cost=cost, constraints=cons,
                                                   roles=_roles(els, over))
        factors = []
        for (typ, mains), ts in grouped.items():
            els = ts[0].elements
            factors.append(Factor(f"{typ}:{'-'.join(mains)}", typ, ("h",) + tuple(b for el in els for b in el.blocks),
                                  cost=self._cost(ts, N), roles=_roles(els)))
        paper: dict[str, list[Constraint]] = {}
        cliques: list[tuple[str, ...]] = []
        owned: list[tuple[list[Element], Factor]] = []  # the own model factors with their variables
        for item in own:
            if isinstance(item, FamilyTerm):
                fam_costs = [] if _touches_cost_only(item.elements[0]) else family_costs[id(item)]
                owned += list(zip(item.elements, self._family_factors(item, N, paper, cliques, fam_costs)))
                continue
            if isinstance(item, tuple):  # a group: blocks and roles, no cost, no constraints
                gname, g = item
                owned.append(([], Factor(gname, g.type, ("h",) + tuple(g.blocks), roles=("h",) + tuple(g.roles or ()),
                                         data=g.data)))
                continue
            t = item
            fmt = t.factor.constraint_names
            cons = [Constraint(_global(M, t.columns, N), 0.0, name=fmt.format(factor=t.name, constraint=nm),
                               factor=t.name) for nm, M in t.local_constraints()]
            roles = _roles(t.elements) + (tuple(t.aux.blocks) if t.aux is not None else ())
            if t.factor.roles is not None:
                if len(t.factor.roles) != len(roles) - 1:
                    raise ProblemDefinitionError(f"factor {t.name!r}: roles must name its {len(roles) - 1} blocks "
                                                 f"after h, got {t.factor.roles}")
                roles = ("h",) + tuple(t.factor.roles)
            if len(set(roles)) != len(roles):
                raise ProblemDefinitionError(f"factor {t.name!r}: its blocks' roles {roles} are not distinct")
            blocks = ("h",) + tuple(b for el in _modelled(t.elements) for b in el.blocks) + t.aux_blocks
            if L.ordered and t.factor.roles is None:  # in the module's order of the lifted vector, h first
                at = sorted(range(1, len(blocks)), key=lambda k: L.V.offsets[blocks[k]])
                blocks, roles = ("h",) + tuple(blocks[k] for k in at), ("h",) + tuple(roles[k] for k in at)
            cost = None if _touches_cost_only(t.elements) else self._cost([t], N)
            owned.append((t.elements, Factor(t.name, t.type, blocks, cost=cost, constraints=cons, roles=roles,
                                             data=t.factor.data)))
        factors = self._ordered(var_factors, factors, owned, home)
        seen: set[str] = set()
        for c in (c for f in factors for c in f.constraints):
            if c.name in seen:
                raise ProblemDefinitionError(f"two primary constraints are named {c.name!r}; give the variables' or "
                                             "factors' constraint_names a {factor} or distinct constraint names")
            seen.add(c.name)
        self._stacked()  # the local solver's residual map, made with the model (the solver follows the build)
        total = self._cost(every, N, halves=True) if loose else None  # then in no factor's cost alone
        return Model(L.V, factors, paper=paper, cliques=cliques or None, cost=total)

    def _variable_constraints(self) -> tuple[dict[int, list[str]], dict[int, list[sp.coo_array]]]:
        """The manifolds', liftings' and products' constraints of every element, a variable's elements at once: (per
        variable (by id), the constraints' names; per element position, their N×N matrices)."""
        L, N = self.layout, self.layout.V.N
        names: dict[int, list[str]] = {}
        mats: dict[int, list[sp.coo_array]] = {}
        for var, idx, columns in L.families:
            local = var.local_constraints()
            if L.V.d > 1:  # on h's d columns and the element's k: the Gram form of each equation
                local = [(nm, gram_form(M, L.V.d)) for nm, M in local]
            names[id(var)] = [nm for nm, _ in local]
            if not local or not len(idx):
                mats.update({int(k): [] for k in idx})
                continue
            entries = [np.nonzero(M) for _, M in local]
            rows = np.concatenate([r for r, _ in entries])
            cols = np.concatenate([c for _, c in entries])
            group = np.repeat(np.arange(len(local)), [r.size for r, _ in entries])
            vals = np.concatenate([M[r, c] for (_, M), (r, c) in zip(local, entries)])
            theta = L.product_columns(var)  # the products' θ, after the element's own columns
            cols_of = np.hstack([np.broadcast_to(np.arange(L.V.d), (len(idx), L.V.d)), columns,
                                 np.broadcast_to(theta, (len(idx), theta.size))])
            per = scatter(np.broadcast_to(vals, (len(idx), vals.size)), group, rows, cols, len(local), cols_of, N)
            mats.update({int(k): m for k, m in zip(idx, per)})
        return names, mats

    def _ordered(self, var_factors: dict[tuple[str, int | None], Factor], grouped: list[Factor],
                 owned: list[tuple[list[Element], Factor]], home: dict[str, tuple[str, int | None]]) -> list[Factor]:
        """The model's factors in order: the variables' own, the grouped costs, the factors of their own; with
        ``by_element``, each variable's own factor right before the first factor of its own on it (those on no
        such factor first), as a factor graph is written pose by pose."""
        if not self.layout.by_element:
            return list(var_factors.values()) + grouped + [f for _, f in owned]
        placed: set[tuple[str, int | None]] = set()
        seq: list[Factor] = []
        for els, fac in owned:
            for el in _modelled(els):
                key = home[el.main]
                if key in var_factors and key not in placed:
                    placed.add(key)
                    seq.append(var_factors[key])
            seq.append(fac)
        return [f for k, f in var_factors.items() if k not in placed] + grouped + seq

    @staticmethod
    def _family_factors(t: FamilyTerm, N: int, paper: dict[str, list[Constraint]],
                        cliques: list[tuple[str, ...]], costs: Sequence[sp.coo_array]) -> list[Factor]:
        """The family's model factors (each with its cost, one per factor in ``costs`` or None, its fitted
        equations, its data unless ``record_data`` is False); its paper rows added to ``paper`` (named
        ``name:family[k]``, k from 1 or ``paper_labels``, or ``name:family`` for one unlabelled row) and its
        factors' blocks to ``cliques`` when it declares them clique hints."""
        roles = t.roles(_roles(t.elements[0]))
        if len(set(roles)) != len(roles):
            raise ProblemDefinitionError(f"{t.where}: its blocks' roles {roles} are not distinct")
        eqs = t.equations.matrices(t.data, t.columns, N) if t.equations is not None else [[] for _ in t.names]
        rows = equation_names(t.aux, t.equations.k, t.where) if t.aux is not None and t.equations is not None else []
        out = []
        for f, name in enumerate(t.names):
            blocks = ("h",) + tuple(b for el in _modelled(t.elements[f]) for b in el.blocks) + t.aux_blocks[f]
            cons = [Constraint(A, 0.0, name=f"{name}:{r}", factor=name) for A, r in zip(eqs[f], rows)]
            out.append(Factor(name, t.type, blocks, cost=costs[f] if costs else None, constraints=cons, roles=roles,
                              data=t.data[f] if t.family.record_data else None))
            if t.family.clique:
                cliques.append(blocks)
        given = t.family.paper_labels or {}
        for fam, fit in t.paper.items():
            labels = [fam] if fit.k == 1 and fam not in given else [f"{fam}[{lab}]" for lab in
                                                                   given.get(fam, range(1, fit.k + 1))]
            if len(labels) != fit.k:
                raise ProblemDefinitionError(f"{t.where}: paper_labels gives {len(labels)} labels for the {fit.k} "
                                             f"rows of {fam!r}")
            paper.setdefault(fam, []).extend(
                Constraint(A, 0.0, name=f"{name}:{lab}", family=fam, factor=name)
                for name, mats in zip(t.names, fit.matrices(t.data, t.columns, N)) for A, lab in zip(mats, labels))
        return out

    @staticmethod
    def _cost(terms: Sequence[Term | _Member], N: int, halves: bool = False) -> sp.coo_array | None:
        """The sum of the terms' lifted costs on the model's columns (one COO assembly), in order; ``halves``: each
        term's (symmetric) matrix entering as two halves C/2 + C/2, as ``autotight.model.QuadForm`` sums a form
        (the model's explicit cost: a module that summed its cost with QuadForm keeps it to the bit)."""
        if not terms:
            return None
        rows, cols, vals = [], [], []
        for t in terms:
            if isinstance(t, _Member):
                G = t.global_cost()
                r, c, v = G.row, G.col, G.data
            else:
                C = t.cost_matrix()
                i, j = np.nonzero(C)
                r, c, v = t.columns[i], t.columns[j], C[i, j]
            for _ in range(2 if halves else 1):
                rows.append(r)
                cols.append(c)
                vals.append(0.5 * v if halves else v)
        return canonical_coo(np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), N)

    # ------------------------------------------------------------------ at a state
    def lift(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """x = [h, blocks…] (N,), h = 1: the layout's lift with each factor's auxiliary blocks (ValueError where
        an auxiliary value is undefined)."""
        x = self.layout.lift(values)
        for t in self.aux_terms:
            x[t.aux_columns] = t.aux_value(t.own(values))
        for ft in self.families:
            if ft.aux is not None:
                x[ft.aux_columns] = ft.aux_value(ft.stacks(values))
        return x

    # ------------------------------------------------------------------ the local solver's view
    @property
    def all_affine(self) -> bool:
        """Whether every residual is affine in the lifted vector (stacked in one map, ``_stacked``)."""
        return not self._stacked()[2]

    def cost(self, values: Sequence[np.ndarray]) -> float:
        """Σ eᵀWe of the declared residuals at the values."""
        total = 0.0
        for t in self.terms:
            e = t.residual(values)
            total += float(e @ t.W @ e)
        if self.families:
            x = self.lift(values)
            for ft in self.families:
                E = ft.residuals(x[ft.columns])
                total += float(np.einsum("fa,fab,fb->", E, ft.W, E))
        return total

    def _stacked(self) -> tuple[sp.csr_array, sp.csr_array, list[tuple[int, Term]]]:
        """(M (m, N): every affine residual's map on the lifted vector, rows in term order, then the families'
        factor by factor; W (m, m) block diagonal; the other terms with their first row), made once."""
        if self._stack is None:
            rows, cols, vals, others = [], [], [], []
            wr, wc, wv = [], [], []
            r0 = 0
            for t in self.terms:
                if t.M is not None:
                    i, j = np.nonzero(t.M)
                    rows.append(r0 + i)
                    cols.append(t.columns[j])
                    vals.append(t.M[i, j])
                else:
                    others.append((r0, t))
                i, j = np.nonzero(t.W)
                wr.append(r0 + i)
                wc.append(r0 + j)
                wv.append(t.W[i, j])
                r0 += t.m
            for ft in self.families:
                F, m, n = ft.M.shape
                base = r0 + m * np.arange(F)[:, None, None]
                f, i, j = np.nonzero(ft.M)
                rows.append((base[:, :, 0] + np.arange(m))[f, i])
                cols.append(ft.columns[f, j])
                vals.append(ft.M[f, i, j])
                f, i, j = np.nonzero(ft.W)
                wr.append(r0 + m * f + i)
                wc.append(r0 + m * f + j)
                wv.append(ft.W[f, i, j])
                r0 += F * m

            def csr(r: list, c: list, v: list, shape: tuple[int, int]) -> sp.csr_array:
                return sp.csr_array((np.concatenate(v or [np.zeros(0)]), (np.concatenate(r or [np.zeros(0, int)]),
                                                                         np.concatenate(c or [np.zeros(0, int)]))),
                                    shape=shape)

            self._stack = (csr(rows, cols, vals, (r0, self.layout.V.N)), csr(wr, wc, wv, (r0, r0)), others)
        return self._stack

    def linearize(self, values: Sequence[np.ndarray], dense: bool = False) -> tuple[np.ndarray, Any, sp.csr_array]:
        """Stacked (e, J, W) for ``gauss_newton``: J (m, n_tangent) sparse (``dense``: an array, for few tangent
        directions and affine residuals only), W block diagonal.  The affine residuals in two products, e = M x
        and J = M ∂x/∂ε (x and ∂x/∂ε: the variables' by their polynomials, the auxiliary blocks' term by term
        and family by family); the others term by term."""
        M, W, others = self._stacked()
        rows, cols, vals, aux = [], [], [], []
        for t in self.aux_terms:
            a, Ja = t.aux_linearize(t.own(values))
            aux.append((t.aux_columns, a))
            i, j = np.nonzero(Ja)
            rows.append(t.aux_columns[i])
            cols.append(t.tangent[j])
            vals.append(Ja[i, j])
        for ft in self.families:
            if ft.aux is not None:
                a, Ja = ft.aux_linearize(values)
                aux.append((ft.aux_columns, a))
                rows.append(np.broadcast_to(ft.aux_columns[:, :, None], Ja.shape).ravel())
                cols.append(np.broadcast_to(ft.tangent[:, None, :], Ja.shape).ravel())
                vals.append(Ja.ravel())
        x, dx = self.layout.lift_polynomial(values, (rows, cols, vals), dense=dense)
        for columns, a in aux:
            x[columns] = a
        e, J = M @ x, M @ dx
        if dense:
            return e, J, W
        if others:
            rows, cols, vals = [], [], []
            for r0, t in others:
                et, Jt = t.linearize(values)
                e[r0:r0 + et.size] = et
                i, j = np.nonzero(Jt)
                rows.append(r0 + i)
                cols.append(t.tangent[j])
                vals.append(Jt[i, j])
            J = sp.csr_array(J + sp.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                              shape=J.shape))
        return e, sp.csr_array(J), W
