"""One instance of a factor-graph problem: its ``Model`` and its stacked residual for the local solver.

The model's factors (``autotight.model.Factor``), which discovery learns on, are:

- one per variable type and index (type: the variables' ``type``, default the name; name: the type,
  suffixed ``_i`` for element i of a stack; blocks and roles: each variable's main block and lifting
  blocks, in declaration order; variables of one type share it, e.g. a pose's t and C), holding the
  manifold's and the lifting's primary constraints and the cost of every declared factor whose variables
  all belong to it and that has no constraints of its own;
- one per (type, variables) of the other declared factors without constraints of their own (their costs
  summed), named ``type:variables``;
- one per declared factor with constraints or auxiliary blocks of its own (named ``Factor.name``, default
  ``type_i``, with its ``data``).

Roles of a variable's blocks inside a factor: its main block's names without the index and its lifting
blocks' names, suffixed ``_k`` (k its position in the factor) when a variable of the same name appears twice;
then the factor's auxiliary blocks' names.  The auxiliary blocks of the factors, after every variable's
blocks in factor order: block ``b`` of the j-th factor declaring a block ``b`` is named ``b_j``.
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError
from ..model import Constraint, Factor, Model, canonical_coo
from .declare import Factor as Declared
from .declare import Variable
from .layout import Element, Layout
from .terms import Term


def _global(local: np.ndarray, columns: np.ndarray, N: int) -> sp.coo_array:
    """The N×N matrix of a matrix on local columns mapped to ``columns``."""
    r, c = np.nonzero(local)
    return canonical_coo(columns[r], columns[c], local[r, c], N)


def _roles(elements: Sequence[Element]) -> tuple[str, ...]:
    stems = [el.var.main_blocks() for el in elements]
    out: list[str] = ["h"]
    for k, el in enumerate(elements):
        sfx = f"_{k}" if stems.count(el.var.main_blocks()) > 1 else ""
        out += [b + sfx for b in el.var.main_blocks()] + [f.name + sfx for f in el.var.fits()]
    return tuple(out)


def _auxiliary_blocks(factors: Sequence[Declared]) -> list[list[str]]:
    """Per factor, its auxiliary blocks' names in the lifted vector (``b_j``: the j-th factor declaring ``b``)."""
    seen: dict[str, int] = {}
    out: list[list[str]] = []
    for f in factors:
        names = []
        for b in f.auxiliary.blocks if f.auxiliary is not None else ():
            names.append(f"{b}_{seen.get(b, 0)}")
            seen[b] = seen.get(b, 0) + 1
        out.append(names)
    return out


def _own_factors(layout: Layout) -> dict[tuple[str, int | None], list[Element]]:
    """The variables' own model factors: elements grouped by (type, index), in layout order."""
    out: dict[tuple[str, int | None], list[Element]] = {}
    for el in layout.elements:
        out.setdefault((el.var.type or el.var.name, el.index), []).append(el)
    return out


class Graph:
    """The declared variables and factors on one instance (see the module docstring)."""

    def __init__(self, variables: Sequence[Variable], truth: Mapping[str, Any], factors: Iterable[Declared]):
        declared = list(factors)
        for f in declared:
            if not isinstance(f, Declared):
                raise ProblemDefinitionError(f"factors must yield autotight.graph.Factor, got {type(f).__name__}")
        aux = _auxiliary_blocks(declared)
        sizes = [list(f.auxiliary.blocks.values()) if f.auxiliary is not None else [] for f in declared]
        self.layout = layout = Layout(variables, truth, [(b, k) for bs, ks in zip(aux, sizes) for b, k in zip(bs, ks)])
        self.terms: list[Term] = []
        for i, (f, bs) in enumerate(zip(declared, aux)):
            self.terms.append(Term(f, layout, f.name or f"{f.type or 'factor'}_{i}", bs))
        self.aux_terms = [t for t in self.terms if t.aux is not None]
        names = [t.name for t in self.terms if t.factor.constraints or t.aux is not None]
        if len(set(names)) != len(names):
            raise ProblemDefinitionError(f"factors with constraints or auxiliary blocks need distinct names, "
                                         f"got {names}")
        self._stack: tuple[sp.csr_array, sp.csr_array, list[tuple[int, Term]]] | None = None

    def model(self) -> Model:
        L, N = self.layout, self.layout.V.N
        owners = _own_factors(L)
        home = {el.main: key for key, els in owners.items() for el in els}
        costs: dict[tuple[str, int | None], list[Term]] = {key: [] for key in owners}
        grouped: dict[tuple[str, tuple[str, ...]], list[Term]] = {}
        own: list[Term] = []
        for t in self.terms:
            keys = {home[el.main] for el in t.elements}
            if t.factor.constraints or t.aux is not None:
                own.append(t)
            elif len(keys) == 1:
                costs[keys.pop()].append(t)
            else:
                grouped.setdefault((t.type, tuple(el.main for el in t.elements)), []).append(t)
        factors = []
        for (typ, index), els in owners.items():
            name = typ if index is None else f"{typ}_{index}"
            cons = []
            for el in els:
                cols = np.concatenate([[0], L.columns(el)])
                split = len(el.var.main_blocks()) > 1  # named by the variable, not its first block
                label = el.var.name + ("" if index is None else str(index)) if split else el.main
                cons += [Constraint(_global(M, cols, N), 0.0, name=f"{name}:{label}:{nm}", factor=name)
                         for nm, M in el.var.local_constraints()]
            factors.append(Factor(name, typ, ("h",) + tuple(b for el in els for b in el.blocks),
                                  cost=self._cost(costs[(typ, index)], N), constraints=cons, roles=_roles(els)))
        for (typ, mains), ts in grouped.items():
            els = ts[0].elements
            factors.append(Factor(f"{typ}:{'-'.join(mains)}", typ, ("h",) + tuple(b for el in els for b in el.blocks),
                                  cost=self._cost(ts, N), roles=_roles(els)))
        for t in own:
            cons = [Constraint(_global(M, t.columns, N), 0.0, name=f"{t.name}:{nm}", factor=t.name)
                    for nm, M in t.local_constraints()]
            roles = _roles(t.elements) + (tuple(t.aux.blocks) if t.aux is not None else ())
            if len(set(roles)) != len(roles):
                raise ProblemDefinitionError(f"factor {t.name!r}: its blocks' roles {roles} are not distinct")
            blocks = ("h",) + tuple(b for el in t.elements for b in el.blocks) + t.aux_blocks
            factors.append(Factor(t.name, t.type, blocks, cost=self._cost([t], N), constraints=cons, roles=roles,
                                  data=t.factor.data))
        return Model(L.V, factors)

    @staticmethod
    def _cost(terms: Sequence[Term], N: int) -> sp.coo_array | None:
        """The sum of the terms' lifted costs on the model's columns (one COO assembly)."""
        if not terms:
            return None
        rows, cols, vals = [], [], []
        for t in terms:
            C = t.cost_matrix()
            i, j = np.nonzero(C)
            rows.append(t.columns[i])
            cols.append(t.columns[j])
            vals.append(C[i, j])
        return canonical_coo(np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), N)

    # ------------------------------------------------------------------ at a state
    def lift(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """x = [h, blocks…] (N,), h = 1: the layout's lift with each factor's auxiliary blocks (ValueError where
        an auxiliary value is undefined)."""
        x = self.layout.lift(values)
        for t in self.aux_terms:
            x[t.aux_columns] = t.aux_value(t.own(values))
        return x

    # ------------------------------------------------------------------ the local solver's view
    def cost(self, values: Sequence[np.ndarray]) -> float:
        """Σ eᵀWe of the declared residuals at the values."""
        total = 0.0
        for t in self.terms:
            e = t.residual(values)
            total += float(e @ t.W @ e)
        return total

    def _stacked(self) -> tuple[sp.csr_array, sp.csr_array, list[tuple[int, Term]]]:
        """(M (m, N): every affine residual's map on the lifted vector, rows in term order; W (m, m) block
        diagonal; the other terms with their first row), made once."""
        if self._stack is None:
            rows, cols, vals, others = [], [], [], []
            r0 = 0
            for t in self.terms:
                if t.M is not None:
                    i, j = np.nonzero(t.M)
                    rows.append(r0 + i)
                    cols.append(t.columns[j])
                    vals.append(t.M[i, j])
                else:
                    others.append((r0, t))
                r0 += t.m
            M = sp.csr_array((np.concatenate(vals or [np.zeros(0)]), (np.concatenate(rows or [np.zeros(0, int)]),
                                                                      np.concatenate(cols or [np.zeros(0, int)]))),
                             shape=(r0, self.layout.V.N))
            self._stack = (M, sp.csr_array(sp.block_diag([t.W for t in self.terms])), others)
        return self._stack

    def linearize(self, values: Sequence[np.ndarray]) -> tuple[np.ndarray, sp.csr_array, sp.csr_array]:
        """Stacked (e, J, W) for ``gauss_newton``: J (m, n_tangent) sparse, W block diagonal.  The affine
        residuals in two sparse products, e = M x and J = M ∂x/∂ε (x and ∂x/∂ε: the variables' by their
        polynomials, the auxiliary blocks' term by term); the others term by term."""
        M, W, others = self._stacked()
        rows, cols, vals, aux = [], [], [], []
        for t in self.aux_terms:
            a, Ja = t.aux_linearize(t.own(values))
            aux.append((t.aux_columns, a))
            i, j = np.nonzero(Ja)
            rows.append(t.aux_columns[i])
            cols.append(t.tangent[j])
            vals.append(Ja[i, j])
        x, dx = self.layout.lift_polynomial(values, (rows, cols, vals))
        for columns, a in aux:
            x[columns] = a
        e, J = M @ x, M @ dx
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
