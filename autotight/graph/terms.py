"""A declared factor resolved on one instance: its local columns, lifted residual map, cost and Jacobian.

Local columns of a factor: [h, then each variable's columns (main, lifting and product blocks)] in the order
the factor names its variables, then its auxiliary blocks (``declare.Auxiliary``), whose values at a state
are ``value`` of its variables' views and whose ``equations`` are fitted into primary constraints on the
local columns (``declare.fit_quadratic``, checked at a random point to ``EQUATION_RTOL``; the views then
hold arbitrary entries, so the equations must be polynomials of the views' entries, not of points of the
manifolds).  A factor without a declared ``cost`` must have a residual affine in its
views' entries: e = b·h + A θ is read off by evaluating ``residual`` at θ = e_h and e_h + e_j, and
checked at a fixed generic θ (``check_point``, ``AFFINE_RTOL``); its lifted cost is Mᵀ W M with
M = [b A], and its Jacobian with respect to the retraction steps is A·∂θ/∂ε (exact, through the
lifting's fitted polynomials; ``assemble``).  A factor with a declared ``cost`` has its residual
evaluated at states only (it may need its variables on their manifolds); its Jacobian is the declared
``jacobian`` or central differences of the residual along each retraction direction (step ``FD_STEP``).
An affine residual of a factor with auxiliary blocks is stacked likewise, the auxiliary rows of ∂θ/∂ε the
auxiliary's ``jacobian`` or central differences of its ``value`` (``aux_linearize``).

In a lifting of width d > 1 (``derive(width=…)``) the local columns are h's d columns, then each variable's k
(``columns``); the factor's declared cost and constraints are Gram forms on them (required: nothing is read
off), while its residual and views keep the variables' embeddings (``sizes``, ``n``) and are evaluated at states.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence, cast

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError
from .declare import Auxiliary, Factor, View, fit_quadratic, quadratic_forms
from .layout import Element, Layout, cost_only_columns

#: an affine residual must match its read-off map at a random point to this relative accuracy
AFFINE_RTOL = 1e-9
#: central-difference step along a retraction direction (residuals without an affine form or a jacobian)
FD_STEP = 1e-6
#: an auxiliary's equations must match their fitted polynomials of degree ≤ 2 to this relative accuracy
EQUATION_RTOL = 1e-9


def _vector(e: object, where: str) -> np.ndarray:
    v = np.asarray(e, float)
    if v.ndim > 1 or not v.size or not np.all(np.isfinite(v)):
        raise ProblemDefinitionError(f"{where}: residual must return a non-empty finite vector, got shape {v.shape}")
    return v.reshape(-1)


def equation_names(aux: Auxiliary, k: int, where: str) -> list[str]:
    """The names of an auxiliary's k equations: its ``names``, else ``aux[0] … aux[k−1]``."""
    if aux.names is None:
        return [f"aux[{i}]" for i in range(k)]
    if len(aux.names) != k:
        raise ProblemDefinitionError(f"{where}: the auxiliary names {len(aux.names)} equations, its equations "
                                     f"return {k}")
    return list(aux.names)


def check_point(n: int) -> np.ndarray:
    """A fixed generic θ (h = 1, then ±√2, ±√3, … with alternating signs) at which an affine read-off is
    checked: an affine map matches there, a residual with any other term almost surely does not."""
    tail = np.sqrt(np.arange(2.0, n + 1)) * np.where(np.arange(n - 1) % 2, -1.0, 1.0)
    return np.r_[1.0, tail]


class Term:
    """One declared factor on one instance (see the module docstring)."""

    def __init__(self, factor: Factor, layout: Layout, name: str, aux_blocks: Sequence[str] = ()):
        self.factor, self.name, self.aux = factor, name, factor.auxiliary
        self.where = f"factor {name!r}"
        self.elements: list[Element] = [layout.element(v, self.where) for v in factor.variables]
        #: the declared variables come first; the variables of their product blocks that the factor does not
        #: declare follow (its residual, jacobian and auxiliary see the declared ones: ``_views``, ``_state_views``)
        self.n_declared = len(self.elements)
        k = 0
        while k < len(self.elements):  # and theirs, if they have product blocks too
            for src in layout.sources.get(id(self.elements[k].var), []):
                self.elements += [o for o in src if all(o is not e for e in self.elements)]
            k += 1
        self.positions = [layout.position[el.main] for el in self.elements]
        #: per variable, per product block of it, the positions in the factor of the block's variables
        self.sources: list[list[list[int]]] = [
            [[next(j for j, e in enumerate(self.elements) if e is o) for o in src]
             for src in layout.sources.get(id(el.var), [])] for el in self.elements]
        #: the auxiliary blocks' names in the lifted vector and their columns
        self.aux_blocks = tuple(aux_blocks)
        self.aux_columns = layout.V.index(self.aux_blocks) if self.aux_blocks else np.zeros(0, int)
        #: the model's columns of its local columns (with a lifting width d: h's d columns, then the variables')
        self.columns = np.concatenate([np.arange(layout.V.d)] + [layout.columns(el) for el in self.elements] +
                                      [self.aux_columns])
        #: the local columns that declared matrices are on: h's, the declared variables' and the auxiliary blocks'
        added = np.concatenate([np.zeros(layout.V.d, bool)] + [np.full(layout.columns(el).size, k >= self.n_declared)
                                                                for k, el in enumerate(self.elements)] +
                               [np.zeros(self.aux_columns.size, bool)])
        self.declared_columns = np.flatnonzero(~added)
        #: the size of each variable's lifted vector, its entries in the views (in a lifting of width d > 1, its
        #: embedding, which the model holds as a d × k block)
        self.sizes = [el.var.manifold.size if layout.V.d > 1 else layout.columns(el).size for el in self.elements]
        #: the factor's variables' entries of the stacked tangent vector, in its order
        self.tangent = np.concatenate([np.arange(el.tangent_offset, el.tangent_offset + el.dof)
                                       for el in self.elements])
        self.n = 1 + sum(self.sizes) + int(self.aux_columns.size)
        if layout.V.d > 1 and factor.cost is None:
            raise ProblemDefinitionError(f"{self.where}: in a lifting of width {layout.V.d} give its lifted cost "
                                         "(Factor(cost=…), on h's d columns and its variables' columns)")
        self._aux_constraints = self._fit_equations() if self.aux is not None and self.aux.equations is not None \
            else []
        if factor.cost is None:
            M = self._affine_map()
            if M is None:
                raise ProblemDefinitionError(f"{self.where}: its residual is not affine in its variables' lifted "
                                             "blocks; give its lifted cost (Factor(cost=…))")
            self.M: np.ndarray | None = M
            self.m = M.shape[0]
        else:  # the residual is only evaluated at states (it may need them on their manifolds)
            self.M = None
            self.m = self.residual(layout.truth_values).size
        self.W = self._weight(self.m)
        #: the declared constraints on the local columns, checked and converted once
        self._declared = [(nm, self._local(C, f"constraint {nm!r}")) for nm, C in factor.constraints]
        #: the local columns of cost-only variables (``Variable.cost_only``), which its constraints must not touch
        self.cost_only = cost_only_columns(self.sizes, [el.var for el in self.elements])
        if self.cost_only.size and any(np.any(M[self.cost_only]) for _, M in self.local_constraints()):
            raise ProblemDefinitionError(f"{self.where}: its constraints involve a cost-only variable")

    @property
    def type(self) -> str:
        """The declared type, else the variables' names joined by '-' (one variable: ``name_factor``, apart from
        the type of the variable's own factor)."""
        names = [el.var.name for el in self.elements[:self.n_declared]]
        return self.factor.type or ("-".join(names) if len(names) > 1 else f"{names[0]}_factor")

    def _var_views(self, theta: np.ndarray) -> list[View]:
        """One view per variable of the local columns θ."""
        out: list[View] = []
        o = 1
        for el, k in zip(self.elements, self.sizes):
            out.append(el.var.view(theta[o:o + k]))
            o += k
        return out

    def _views(self, theta: np.ndarray) -> list[View]:
        """The residual's arguments: the declared variables' views, then the auxiliary blocks' view (if any)."""
        out = self._var_views(theta)[:self.n_declared]
        if self.aux is not None:
            out.append(self.aux.view(theta[self.n - self.aux.size:]))
        return out

    def _fit_equations(self) -> list[tuple[str, np.ndarray]]:
        """The auxiliary's equations as (name, (n, n) matrix) on the local columns."""
        aux = self.aux
        assert aux is not None and aux.equations is not None
        equations = aux.equations

        def call(v: np.ndarray) -> np.ndarray:
            theta = np.concatenate(([1.0], v))
            try:
                e = np.asarray(equations(*self._views(theta)), dtype=np.float64)
            except (ArithmeticError, ValueError, np.linalg.LinAlgError) as err:
                raise ProblemDefinitionError(
                    f"{self.where}: the auxiliary's equations raised {type(err).__name__} ({err}) at entries off the "
                    "manifolds; write them as polynomials of the views' entries") from err
            if e.ndim > 1 or not e.size or not np.all(np.isfinite(e)):
                raise ProblemDefinitionError(f"{self.where}: the auxiliary's equations must return a non-empty "
                                             f"finite vector, got shape {e.shape}")
            return e.reshape(-1)

        c0, G, S, err = fit_quadratic(call, self.n - 1)
        if err > EQUATION_RTOL:
            raise ProblemDefinitionError(f"{self.where}: the auxiliary's equations are not polynomials of degree "
                                         "≤ 2 in the factor's local entries (its variables' blocks and its own)")
        return list(zip(equation_names(aux, len(c0), self.where), quadratic_forms(c0, G, S)))

    def _thetas(self, k: int, own: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per product block of the factor's k-th variable, θ at the factor's variables' values."""
        return [np.concatenate([self.elements[j].var.manifold.embed(own[j]) for j in src]) for src in self.sources[k]]

    def _state_views(self, own: Sequence[np.ndarray]) -> list[View]:
        """The variables' views at their values (x, each lifting block and each product block)."""
        out = []
        for k, (el, v) in enumerate(zip(self.elements, own)):
            blocks = {f.name: np.asarray(f.fn(v), float).reshape(-1) for f in el.var.fits()}
            blocks |= {b: np.kron(el.var.manifold.embed(v), th) for b, th in zip(el.var.products, self._thetas(k, own))}
            out.append(View(x=np.asarray(v, float), **blocks))
        return out[:self.n_declared]

    def aux_value(self, own: Sequence[np.ndarray]) -> np.ndarray:
        """The auxiliary blocks' values at the factor's variables' values (ValueError where undefined)."""
        assert self.aux is not None
        a = np.asarray(self.aux.value(*self._state_views(own)), float)
        if a.shape not in ((self.aux.size,), (1, self.aux.size)) or not np.all(np.isfinite(a)):
            raise ProblemDefinitionError(f"{self.where}: the auxiliary's value must be a finite vector of size "
                                         f"{self.aux.size}, got shape {a.shape}")
        return a.reshape(-1)

    def aux_linearize(self, own: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(a, ∂a/∂ε (Σ sizes, Σ dof)) of the auxiliary blocks at the factor's variables' values, ε the variables'
        retraction steps in its order: the declared ``jacobian``, else central differences of ``value``."""
        assert self.aux is not None
        a = self.aux_value(own)
        if self.aux.jacobian is None:
            return a, self._differences(own, self.aux_value)
        J = self.aux.jacobian(*self._state_views(own), self.aux.view(a))
        return a, self._declared_jacobian(J, self.aux.size, "the auxiliary's jacobian")

    def _declared_jacobian(self, J: object, rows: int, what: str) -> np.ndarray:
        """A declared jacobian, checked to be (rows, dof of the declared variables), with zero columns for the
        variables after them (the product blocks' variables the factor does not name)."""
        J = np.asarray(J, float)
        dof = sum(el.dof for el in self.elements[:self.n_declared])
        if J.shape != (rows, dof):
            raise ProblemDefinitionError(f"{self.where}: {what} returned shape {J.shape}, expected ({rows}, {dof})")
        extra = sum(el.dof for el in self.elements[self.n_declared:])
        return np.hstack([J, np.zeros((rows, extra))]) if extra else J

    def _residual(self, theta: np.ndarray) -> np.ndarray:
        return _vector(self.factor.residual(*self._views(theta)), self.where)

    def _probe(self, theta: np.ndarray) -> np.ndarray | None:
        """The residual at an arbitrary θ (off the lifting), or None when it is not a finite vector there."""
        v = np.asarray(self.factor.residual(*self._views(theta)), float)
        if v.ndim > 1 or not v.size:
            raise ProblemDefinitionError(f"{self.where}: residual must return a non-empty vector, got shape {v.shape}")
        return v.reshape(-1) if np.all(np.isfinite(v)) else None

    def _affine_map(self) -> np.ndarray | None:
        """M = [b A] (m, n) when the residual is affine in θ (read off at θ = e_h and e_h + e_j, checked at
        ``check_point``), else None."""
        I = np.eye(self.n)
        b = self._probe(I[0])
        if b is None:
            return None
        cols = [b]
        for j in range(1, self.n):
            e = self._probe(I[0] + I[j])
            if e is None or e.size != b.size:
                return None
            cols.append(e - b)
        M = np.stack(cols, axis=1)
        theta = check_point(self.n)
        want = self._probe(theta)
        if want is None or want.size != b.size:
            return None
        scale = max(1.0, float(np.abs(want).max()), float(np.abs(M).max())) * float(np.abs(theta).max())
        return M if np.abs(M @ theta - want).max() <= AFFINE_RTOL * scale else None

    def _weight(self, m: int) -> np.ndarray:
        w = self.factor.weight
        if w is None:
            return np.eye(m)
        W = np.asarray(w, float)
        W = W * np.eye(m) if W.ndim == 0 else W
        # non-finite entries pass: they come from the measurements, which autotight.validate reports by name
        if W.shape != (m, m) or not np.allclose(W, W.T, equal_nan=True):
            raise ProblemDefinitionError(f"{self.where}: weight must be a number or a symmetric ({m}, {m}) matrix")
        return 0.5 * (W + W.T)  # symmetric to the last bit (eᵀWe is the same), so is the lifted cost

    def _local(self, C: object, what: str) -> np.ndarray:
        """A declared matrix on [h, the declared variables' blocks, the auxiliary blocks], placed on the local
        columns (which hold the undeclared variables of product blocks after the declared ones)."""
        A = cast(Any, C).toarray() if sp.issparse(C) else np.asarray(C, float)
        shown = self.declared_columns
        if A.shape != (shown.size, shown.size) or not np.all(np.isfinite(A)):
            raise ProblemDefinitionError(f"{self.where}: {what} must be a finite ({shown.size}, {shown.size}) matrix "
                                         "on the factor's local columns [h, its variables' blocks]")
        full = np.zeros((self.columns.size, self.columns.size))
        full[np.ix_(shown, shown)] = A
        return 0.5 * (full + full.T)

    def cost_matrix(self) -> np.ndarray:
        """The lifted cost on the local columns: the declared one, else Mᵀ W M."""
        if self.factor.cost is not None:
            return self._local(self.factor.cost, "cost")
        assert self.M is not None
        return self.M.T @ self.W @ self.M

    def local_constraints(self) -> list[tuple[str, np.ndarray]]:
        """The declared constraints, then the auxiliary's fitted equations."""
        return self._declared + self._aux_constraints

    # ------------------------------------------------------------------ at a state
    def own(self, values: Sequence[np.ndarray]) -> list[np.ndarray]:
        """The factor's variables' values, in its order, from the layout's value list."""
        return [values[p] for p in self.positions]

    def lifted(self, own: Sequence[np.ndarray]) -> np.ndarray:
        """θ on the local columns (h = 1) at the factor's variables' values."""
        parts = [[1.0]] + [el.var.lifted(v, self._thetas(k, own)) for k, (el, v) in enumerate(zip(self.elements, own))]
        return np.concatenate(parts + ([self.aux_value(own)] if self.aux is not None else []))

    def residual(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """The declared residual at the layout's values (its views of the lifted θ)."""
        return self._residual(self.lifted(self.own(values)))

    def linearize(self, values: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(e (m,), J (m, Σ dof)) of a residual that is not affine (``M`` is None; the affine ones are stacked,
        ``assemble.Graph.linearize``) at the layout's values, J with respect to the factor's variables'
        retraction steps in its order: the declared ``jacobian``, else central differences."""
        own = self.own(values)
        theta = self.lifted(own)
        e = self._residual(theta)
        if self.factor.jacobian is not None:
            return e, self._declared_jacobian(self.factor.jacobian(*self._views(theta)), e.size, "jacobian")
        return e, self._differences(own, lambda vals: self._residual(self.lifted(vals)))

    def _differences(self, own: Sequence[np.ndarray], fn: Callable[[list], np.ndarray]) -> np.ndarray:
        """Central differences of fn(values of the factor's variables) along each retraction direction, (·, Σ dof)."""
        cols = []
        for i, (el, v) in enumerate(zip(self.elements, own)):
            for k in range(el.dof):
                step = np.zeros(el.dof)
                step[k] = FD_STEP
                plus, minus = list(own), list(own)
                plus[i], minus[i] = el.var.manifold.retract(v, step), el.var.manifold.retract(v, -step)
                cols.append((fn(plus) - fn(minus)) / (2 * FD_STEP))
        return np.stack(cols, axis=1)
