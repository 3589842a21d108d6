"""A declared factor resolved on one instance: its local columns, lifted residual map, cost and Jacobian.

Local columns of a factor: [h, then each variable's columns (main block, lifting blocks)] in the order
the factor names its variables.  A factor without a declared ``cost`` must have a residual affine in its
views' entries: e = b·h + A θ is read off by evaluating ``residual`` at θ = e_h and e_h + e_j, and
checked at a fixed generic θ (``check_point``, ``AFFINE_RTOL``); its lifted cost is Mᵀ W M with
M = [b A], and its Jacobian with respect to the retraction steps is A·∂θ/∂ε (exact, through the
lifting's fitted polynomials; ``assemble``).  A factor with a declared ``cost`` has its residual
evaluated at states only (it may need its variables on their manifolds); its Jacobian is the declared
``jacobian`` or central differences of the residual along each retraction direction (step ``FD_STEP``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ProblemDefinitionError
from .declare import Factor, View
from .layout import Element, Layout

#: an affine residual must match its read-off map at a random point to this relative accuracy
AFFINE_RTOL = 1e-9
#: central-difference step along a retraction direction (residuals without an affine form or a jacobian)
FD_STEP = 1e-6


def _vector(e: object, where: str) -> np.ndarray:
    v = np.asarray(e, float)
    if v.ndim > 1 or not v.size or not np.all(np.isfinite(v)):
        raise ProblemDefinitionError(f"{where}: residual must return a non-empty finite vector, got shape {v.shape}")
    return v.reshape(-1)


def check_point(n: int) -> np.ndarray:
    """A fixed generic θ (h = 1, then ±√2, ±√3, … with alternating signs) at which an affine read-off is
    checked: an affine map matches there, a residual with any other term almost surely does not."""
    tail = np.sqrt(np.arange(2.0, n + 1)) * np.where(np.arange(n - 1) % 2, -1.0, 1.0)
    return np.r_[1.0, tail]


class Term:
    """One declared factor on one instance (see the module docstring)."""

    def __init__(self, factor: Factor, layout: Layout, name: str):
        self.factor, self.name = factor, name
        self.where = f"factor {name!r}"
        self.elements: list[Element] = [layout.element(v, self.where) for v in factor.variables]
        self.positions = [layout.position[el.main] for el in self.elements]
        self.columns = np.concatenate([[0]] + [layout.columns(el) for el in self.elements])
        self.sizes = [layout.columns(el).size for el in self.elements]
        self.n = int(self.columns.size)
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
        for nm, C in factor.constraints:
            self._local(C, f"constraint {nm!r}")

    @property
    def type(self) -> str:
        """The declared type, else the variables' names joined by '-' (one variable: ``name_factor``, apart from
        the type of the variable's own factor)."""
        names = [el.var.name for el in self.elements]
        return self.factor.type or ("-".join(names) if len(names) > 1 else f"{names[0]}_factor")

    def _views(self, theta: np.ndarray) -> list[View]:
        out: list[View] = []
        o = 1
        for el, k in zip(self.elements, self.sizes):
            out.append(el.var.view(theta[o:o + k]))
            o += k
        return out

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
        if W.shape != (m, m) or not np.all(np.isfinite(W)) or not np.allclose(W, W.T):
            raise ProblemDefinitionError(f"{self.where}: weight must be a number or a symmetric ({m}, {m}) matrix")
        return W

    def _local(self, C: object, what: str) -> np.ndarray:
        A = np.asarray(C, float)
        if A.shape != (self.n, self.n) or not np.all(np.isfinite(A)):
            raise ProblemDefinitionError(f"{self.where}: {what} must be a finite ({self.n}, {self.n}) matrix on the "
                                         "factor's local columns [h, its variables' blocks]")
        return 0.5 * (A + A.T)

    def cost_matrix(self) -> np.ndarray:
        """The lifted cost on the local columns: the declared one, else Mᵀ W M."""
        if self.factor.cost is not None:
            return self._local(self.factor.cost, "cost")
        assert self.M is not None
        return self.M.T @ self.W @ self.M

    def local_constraints(self) -> list[tuple[str, np.ndarray]]:
        return [(nm, self._local(C, f"constraint {nm!r}")) for nm, C in self.factor.constraints]

    # ------------------------------------------------------------------ at a state
    def own(self, values: Sequence[np.ndarray]) -> list[np.ndarray]:
        """The factor's variables' values, in its order, from the layout's value list."""
        return [values[p] for p in self.positions]

    def lifted(self, own: Sequence[np.ndarray]) -> np.ndarray:
        """θ on the local columns (h = 1) at the factor's variables' values."""
        return np.concatenate([[1.0]] + [el.var.lifted(v) for el, v in zip(self.elements, own)])

    def residual(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """The declared residual at the layout's values (its views of the lifted θ)."""
        return self._residual(self.lifted(self.own(values)))

    def linearize(self, values: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(e (m,), J (m, Σ dof)) of a residual that is not affine (``M`` is None; the affine ones are stacked,
        ``assemble.Graph.linearize``) at the layout's values, J with respect to the factor's variables'
        retraction steps in its order: the declared ``jacobian``, else central differences."""
        own = self.own(values)
        theta = self.lifted(own)
        dof = sum(el.dof for el in self.elements)
        if self.factor.jacobian is not None:
            e = self._residual(theta)
            J = np.asarray(self.factor.jacobian(*self._views(theta)), float)
            if J.shape != (e.size, dof):
                raise ProblemDefinitionError(f"{self.where}: jacobian returned shape {J.shape}, "
                                             f"expected ({e.size}, {dof})")
            return e, J
        cols = []
        for i, (el, v) in enumerate(zip(self.elements, own)):
            for k in range(el.dof):
                step = np.zeros(el.dof)
                step[k] = FD_STEP
                plus, minus = list(own), list(own)
                plus[i], minus[i] = el.var.manifold.retract(v, step), el.var.manifold.retract(v, -step)
                cols.append((self._residual(self.lifted(plus)) - self._residual(self.lifted(minus))) / (2 * FD_STEP))
        return self._residual(theta), np.stack(cols, axis=1)
