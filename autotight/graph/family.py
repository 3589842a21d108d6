"""A declared factor family (``declare.Family``) resolved on one instance: F factors of one type at once.

Every function of the family is called on stacks: views of (R, …) arrays (``View``: ``x`` through the
manifold's embedding, each lifting block; the auxiliary's blocks), then the data stack (R, *shape).  Local
columns of each factor as for one factor (``terms``): [h, its variables' blocks, its auxiliary blocks].

- The residual, affine in the views' entries, is read off for all F factors in one call (θ = e_h and
  e_h + e_j with each factor's data, checked at ``terms.check_point``): M (F, m, n); lifted costs Mᵀ W M.
- The auxiliary's equations and the paper rows are fitted once per family and layout (``Fit``; later builds reuse
  the probe fit, ``_PROBE_FITS``): a polynomial of degree
  ≤ 2 in the n − 1 local entries whose coefficients are polynomials of degree ≤ ``Family.degree`` in the
  data, from exact differences at the probe points of both (``factor_batch``), in one call on the stack
  of every (data probe, entry probe) pair; coefficients at the rounding of the evaluations are zero.  The
  fit is checked at random entries with random data and with each factor's data (``EQUATION_RTOL``).
  Each factor's constraint matrices are then one matrix product away (``Fit.matrices``).
- At a state: the auxiliary values and Jacobians for all F factors in one call each.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError
from ..factor_batch import coefficients, features, probe_points, relocated
from .declare import ROUNDING, Auxiliary, Family, Variable, View
from .layout import Element, Layout, cost_only_columns
from .manifolds import Euclidean, Rotation
from .terms import AFFINE_RTOL, EQUATION_RTOL, FD_STEP, check_point


def unembed_stack(var: Variable, V: np.ndarray) -> np.ndarray:
    """The manifold's ``unembed`` of each row of V (R, size), (R, *shape)."""
    man = var.manifold
    if isinstance(man, Euclidean):
        return V.reshape((len(V),) + man.shape)
    if isinstance(man, Rotation):
        return V.reshape(len(V), man.d, man.d).swapaxes(1, 2)
    return np.array([man.unembed(v) for v in V]).reshape((len(V),) + tuple(man.shape))


def embed_stack(var: Variable, X: np.ndarray) -> np.ndarray:
    """The manifold's ``embed`` of each element of X (R, *shape), (R, size)."""
    man = var.manifold
    if isinstance(man, Euclidean):
        return X.reshape(len(X), man.size)
    if isinstance(man, Rotation):
        return X.swapaxes(1, 2).reshape(len(X), man.size)
    return np.array([man.embed(x) for x in X]).reshape(len(X), man.size)


def _aux_view(aux: Auxiliary, A: np.ndarray) -> View:
    out, o = {}, 0
    for b, k in aux.blocks.items():
        out[b] = A[:, o:o + k]
        o += k
    return View(**out)


def scatter(values: np.ndarray, group: np.ndarray, rows: np.ndarray, cols: np.ndarray, ngroups: int,
            columns: np.ndarray, N: int) -> list[list[sp.coo_array]]:
    """[factor][group]: N×N canonical COO arrays of local entries (rows, cols) (E,) with values (F, E), entry e
    in matrix group[e], local column u of factor f at columns[f, u] (entries that are 0 for a factor dropped;
    each (group, row, col) at most once)."""
    columns = np.asarray(columns, np.int64 if N >= 2 ** 31 else np.int32)
    F = values.shape[0]
    out: list[list[sp.coo_array]] = [[] for _ in range(F)]
    for g in range(ngroups):
        sel = np.flatnonzero(group == g)
        for f, A in enumerate(relocated(columns[:, rows[sel]], columns[:, cols[sel]], values[:, sel], N)):
            out[f].append(A)
    return out


#: the probe fits of ``Fit`` by (function, layout key, p, q, degree): the same on every instance of a problem, so
#: each build after the first reuses them (the check against each build's data still runs).  Bounded: the
#: oldest entry goes first.
_PROBE_FITS: dict[tuple, tuple[int, np.ndarray, np.ndarray, np.ndarray]] = {}
PROBE_FITS_MAX = 256


def _probe_fit(call: Callable[[np.ndarray, np.ndarray], np.ndarray], p: int, q: int,
               degree: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(k, mono, row, coef) of ``Fit`` from exact differences at the probe points (module docstring)."""
    Pe, Pd = probe_points(p, 2), probe_points(q, degree)
    ne, nd = len(Pe), len(Pd)
    theta = np.hstack([np.ones((nd * ne, 1)), np.tile(Pe, (nd, 1))])
    vals = call(theta, np.repeat(Pd, ne, axis=0))
    k = vals.shape[1]
    ce = coefficients(vals.reshape(nd, ne, k).transpose(1, 0, 2), p, 2)  # (entry monomials, nd, k)
    coef = coefficients(ce.transpose(1, 0, 2), q, degree)  # (data monomials, entry monomials, k)
    coef[np.abs(coef) <= ROUNDING * max(1.0, float(np.abs(vals).max()))] = 0.0
    used = np.flatnonzero((coef != 0).any(axis=0).ravel())
    mono, row = np.divmod(used, k)
    out = (k, mono, row, coef.reshape(coef.shape[0], -1)[:, used])
    for a in out[1:]:
        a.flags.writeable = False  # shared by every Fit of the same key
    return out


class Fit:
    """k polynomials of degree ≤ 2 in p local entries (h = 1 first), coefficients polynomials of ``degree`` in q
    data entries: coef (data monomials, [entry monomial, row] pairs that are nonzero for some datum).

    ``key``: what ``call`` computes besides its arguments (the family's function and the layout of the views it
    is called with, ``FamilyTerm._fit_key``); fits of equal keys share the probe fit (``_PROBE_FITS``).  None:
    fitted afresh."""

    def __init__(self, call: Callable[[np.ndarray, np.ndarray], np.ndarray], p: int, data: np.ndarray,
                 degree: int, where: str, what: str, key: tuple | None = None):
        F = data.shape[0]
        D = data.reshape(F, -1)
        q = D.shape[1]
        full = None if key is None else (key, p, q, degree)
        probe = _PROBE_FITS.get(full) if full is not None else None
        if probe is None:
            probe = _probe_fit(call, p, q, degree)
            if full is not None:
                if len(_PROBE_FITS) >= PROBE_FITS_MAX:
                    _PROBE_FITS.pop(next(iter(_PROBE_FITS)))
                _PROBE_FITS[full] = probe
        k, self.mono, self.row, self.coef = probe
        self.p, self.q, self.k, self.degree = p, q, k, degree
        # checked at random entries with two random data and with every factor's data
        rng = np.random.default_rng(0)
        Dc = np.vstack([rng.standard_normal((2, q)), D])
        Tc = rng.standard_normal((len(Dc), p))
        want = call(np.hstack([np.ones((len(Dc), 1)), Tc]), Dc)
        got = np.zeros_like(want)
        np.add.at(got.T, self.row, (self.per_factor(Dc) * features(Tc, 2)[:, self.mono]).T)
        scale = np.maximum(1.0, np.abs(want).max(axis=1))
        if not np.all(np.abs(got - want).max(axis=1) <= EQUATION_RTOL * scale):
            raise ProblemDefinitionError(
                f"{where}: the {what} are not polynomials of degree ≤ 2 in the factors' local entries with "
                f"coefficients of degree ≤ {degree} in their data")

    def per_factor(self, D: np.ndarray) -> np.ndarray:
        """The used coefficients for each datum (R, q): (R, used)."""
        return features(D.reshape(len(D), self.q), self.degree) @ self.coef

    def _positions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each entry monomial's positions in the (1 + p)² matrix and its factor there: 1, θ_j, θ_j², θ_iθ_j."""
        p = self.p
        i, j = np.triu_indices(p, 1)
        first = np.concatenate([[0], np.zeros(p, int), 1 + np.arange(p), 1 + i])
        second = np.concatenate([[0], 1 + np.arange(p), 1 + np.arange(p), 1 + j])
        half = np.concatenate([[1.0], np.full(p, 0.5), np.ones(p), np.full(i.size, 0.5)])
        return first, second, half

    def columns(self) -> np.ndarray:
        """The local columns (0: h) that some row involves for some datum."""
        first, second, _ = self._positions()
        return np.unique(np.concatenate([first[self.mono], second[self.mono]]))

    def matrices(self, data: np.ndarray, columns: np.ndarray, N: int) -> list[list[sp.coo_array]]:
        """[factor][row]: each row homogenised, [h; θ]ᵀ A [h; θ], as an N×N matrix on the factors' columns."""
        first, second, half = self._positions()
        a, b, mono = first[self.mono], second[self.mono], np.arange(self.mono.size)
        off = a != b
        rows = np.concatenate([a, b[off]])
        cols = np.concatenate([b, a[off]])
        src = np.concatenate([mono, mono[off]])
        group = self.row[src]
        V = self.per_factor(data) * half[self.mono]
        return scatter(V[:, src], group, rows, cols, self.k, columns, N)


class FamilyTerm:
    """One declared family on one instance (see the module docstring)."""

    def __init__(self, fam: Family, layout: Layout, names: Sequence[str], aux_blocks: Sequence[Sequence[str]]):
        self.family, self.names, self.aux = fam, list(names), fam.auxiliary
        self.where = where = f"factor family {fam.type!r}"
        self.type = fam.type
        self.F = F = fam.size
        self.data = fam.data
        self.elements: list[list[Element]] = [[layout.element(v, where) for v in vs] for vs in fam.members]
        self.vars = [el.var for el in self.elements[0]]
        if any(el.var is not var for els in self.elements for el, var in zip(els, self.vars)):
            raise ProblemDefinitionError(f"{where}: the k-th variables of its factors must be the same declared "
                                         "variable")
        if any(var.products for var in self.vars):
            raise ProblemDefinitionError(f"{where}: a family's variables cannot have product blocks (declare its "
                                         "factors one by one)")
        self.positions = np.array([[layout.position[el.main] for el in els] for els in self.elements])
        self.sizes = [layout.columns(el).size for el in self.elements[0]]
        var_cols = np.array([np.concatenate([layout.columns(el) for el in els]) for els in self.elements])
        V = layout.V
        self.aux_blocks = [tuple(bs) for bs in aux_blocks]
        if self.aux is not None:
            starts = np.array([[V.offsets[b] for b in bs] for bs in self.aux_blocks])
            within = np.concatenate([np.arange(k) for k in self.aux.blocks.values()])
            block_of = np.repeat(np.arange(len(self.aux.blocks)), list(self.aux.blocks.values()))
            self.aux_columns = starts[:, block_of] + within
        else:
            self.aux_columns = np.zeros((F, 0), int)
        self.columns = np.hstack([np.zeros((F, 1), int), var_cols, self.aux_columns])
        self.n = self.columns.shape[1]
        dofs = [el.dof for el in self.elements[0]]
        self.tangent = np.array([np.concatenate([np.arange(el.tangent_offset, el.tangent_offset + el.dof)
                                                 for el in els]) for els in self.elements])
        self.dof = int(sum(dofs))
        nblocks = 1 + sum(len(el.blocks) for el in self.elements[0] if not el.var.cost_only) + len(self.aux_blocks[0])
        if fam.roles is not None and len(fam.roles) != nblocks:
            raise ProblemDefinitionError(f"{where}: roles must name its factors' {nblocks} blocks (h, the variables' "
                                         f"but the cost-only ones, the auxiliary's), got {len(fam.roles)}")
        self.M = self._affine_map()
        self.m = self.M.shape[1]
        self.W = self._weights()
        self.equations = None if self.aux is None or self.aux.equations is None else \
            Fit(self._caller(self.aux.equations), self.n - 1, self.data, fam.degree, where, "auxiliary's equations",
                self._fit_key(self.aux.equations))
        self.paper = {name: Fit(self._caller(fn), self.n - 1, self.data, fam.degree, where, f"paper rows {name!r}",
                                self._fit_key(fn))
                      for name, fn in fam.paper.items()}
        #: the local columns of cost-only variables (``Variable.cost_only``): in the cost, in no constraint
        self.cost_only = cost_only_columns(self.sizes, self.vars)
        fits = ([self.equations] if self.equations is not None else []) + list(self.paper.values())
        if self.cost_only.size and any(np.isin(fit.columns(), self.cost_only).any() for fit in fits):
            raise ProblemDefinitionError(f"{where}: its equations or paper rows involve a cost-only variable")

    # ------------------------------------------------------------------ stacks of local columns
    def _views(self, theta: np.ndarray) -> list[View]:
        """The views of local columns θ (R, n): one per variable, then the auxiliary's."""
        out: list[View] = []
        o = 1
        for var, k in zip(self.vars, self.sizes):
            block = theta[:, o:o + k]
            p = var.manifold.size
            views = {"x": unembed_stack(var, block[:, :p])}
            q = p
            for f in var.fits():
                views[f.name] = block[:, q:q + f.size]
                q += f.size
            out.append(View(**views))
            o += k
        if self.aux is not None:
            out.append(_aux_view(self.aux, theta[:, o:]))
        return out

    def _fit_key(self, fn: Callable[..., Any]) -> tuple | None:
        """What ``_caller(fn)`` computes besides its arguments: fn itself and the layout ``_views`` reads (each
        variable's manifold, its lifting blocks' names and sizes, its columns; the auxiliary's blocks) and the
        data's shape.  None (no reuse) for a manifold outside the shipped kinds, whose embedding may hold more."""
        parts: list[tuple] = []
        for var, k in zip(self.vars, self.sizes):
            man = var.manifold
            if not isinstance(man, (Euclidean, Rotation)):
                return None
            parts.append((type(man).__name__, man.size, tuple(man.shape), k,
                          tuple((f.name, f.size) for f in var.fits())))
        aux = None if self.aux is None else tuple(self.aux.blocks.items())
        key = (fn, tuple(parts), aux, tuple(self.data.shape[1:]))
        try:
            hash(key)
        except TypeError:  # a callable object that cannot be a key
            return None
        return key

    def _caller(self, fn: Callable[..., Any]) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """fn as a function of (θ (R, n), data (R, q)) -> (R, k), checked."""
        shape = self.data.shape[1:]

        def call(theta: np.ndarray, D: np.ndarray) -> np.ndarray:
            try:
                out = np.asarray(fn(*self._views(theta), D.reshape((len(D),) + shape)), dtype=np.float64)
            except (ArithmeticError, ValueError, np.linalg.LinAlgError) as err:
                raise ProblemDefinitionError(
                    f"{self.where}: a function raised {type(err).__name__} ({err}) at entries off the manifolds; "
                    "write it as a polynomial of the views' entries") from err
            if out.ndim == 1 and len(theta) == len(out):
                out = out[:, None]
            if out.ndim != 2 or out.shape[0] != len(theta) or not out.shape[1] or not np.all(np.isfinite(out)):
                raise ProblemDefinitionError(f"{self.where}: a function must return a finite ({len(theta)}, k) "
                                             f"stack, got shape {out.shape}")
            return out

        return call

    def _affine_map(self) -> np.ndarray:
        """M (F, m, n): each factor's residual map [b A], read off at θ = e_h, e_h + e_j and checked; m = 0 for a
        family without a residual."""
        F, n = self.F, self.n
        if self.family.residual is None:
            return np.zeros((F, 0, n))
        call = self._caller(self.family.residual)
        probes = np.eye(n)
        probes[1:, 0] = 1.0
        vals = call(np.tile(probes, (F, 1)), np.repeat(self.data.reshape(F, -1), n, axis=0)).reshape(F, n, -1)
        b = vals[:, 0]
        M = np.concatenate([b[:, None], vals[:, 1:] - b[:, None]], axis=1).transpose(0, 2, 1)
        theta = check_point(n)
        want = call(np.tile(theta, (F, 1)), self.data.reshape(F, -1))
        scale = np.maximum(1.0, np.maximum(np.abs(want).max(axis=1), np.abs(M).max(axis=(1, 2)))) * np.abs(theta).max()
        if want.shape != b.shape or np.any(np.abs(M @ theta - want).max(axis=1) > AFFINE_RTOL * scale):
            raise ProblemDefinitionError(f"{self.where}: a family's residual must be affine in its variables' lifted "
                                         "blocks (and its auxiliary blocks)")
        return M

    def _weights(self) -> np.ndarray:
        """W (F, m, m), symmetrised."""
        F, m, w = self.F, self.m, self.family.weight
        W = np.broadcast_to(np.eye(m), (F, m, m)) if w is None else np.asarray(w, float)
        if W.ndim == 0:
            W = W * np.broadcast_to(np.eye(m), (F, m, m))
        elif W.ndim == 2:
            W = np.broadcast_to(W, (F,) + W.shape)
        if W.shape != (F, m, m) or not np.allclose(W, W.swapaxes(1, 2), equal_nan=True):
            raise ProblemDefinitionError(f"{self.where}: weight must be a number, a symmetric ({m}, {m}) matrix or "
                                         f"a ({F}, {m}, {m}) stack of them")
        return 0.5 * (W + W.swapaxes(1, 2))

    # ------------------------------------------------------------------ the model's matrices
    def costs(self, N: int) -> list[sp.coo_array]:
        """Each factor's lifted cost Mᵀ W M as an N×N matrix."""
        C = self.M.transpose(0, 2, 1) @ (self.W @ self.M)
        r, c = np.nonzero((C != 0).any(axis=0))
        return [mats[0] for mats in scatter(C[:, r, c], np.zeros(r.size, int), r, c, 1, self.columns, N)]

    def roles(self, roles: tuple[str, ...]) -> tuple[str, ...]:
        """The declared roles, else the variables' (``roles``, the cost-only ones left out) and the auxiliary
        blocks' names."""
        if self.family.roles is not None:
            return tuple(self.family.roles)
        return roles + (tuple(self.aux.blocks) if self.aux is not None else ())

    # ------------------------------------------------------------------ at a state
    def stacks(self, values: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per variable position, the factors' values (F, *shape)."""
        out = []
        for k, var in enumerate(self.vars):
            pos = self.positions[:, k]
            if (pos == pos[0]).all():
                out.append(np.broadcast_to(np.asarray(values[pos[0]], float), (self.F,) + tuple(var.manifold.shape)))
            else:
                out.append(np.stack([np.asarray(values[p], float) for p in pos]))
        return out

    def _state_views(self, stacks: Sequence[np.ndarray]) -> list[View]:
        out = []
        for var, X in zip(self.vars, stacks):
            E = embed_stack(var, np.asarray(X))
            out.append(View(x=X, **{f.name: f.values(E) for f in var.fits()}))
        return out

    def aux_value(self, stacks: Sequence[np.ndarray]) -> np.ndarray:
        """The auxiliary blocks at the factors' values (F, Σ sizes) (ValueError where undefined)."""
        assert self.aux is not None
        a = np.asarray(self.aux.value(*self._state_views(stacks), self.data), float)
        if a.shape != (self.F, self.aux.size) or not np.all(np.isfinite(a)):
            raise ProblemDefinitionError(f"{self.where}: the auxiliary's value must be a finite ({self.F}, "
                                         f"{self.aux.size}) stack, got shape {a.shape}")
        return a

    def aux_linearize(self, values: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(a (F, Σ sizes), ∂a/∂ε (F, Σ sizes, Σ dof)): the declared ``jacobian``, else central differences."""
        assert self.aux is not None
        stacks = self.stacks(values)
        a = self.aux_value(stacks)
        if self.aux.jacobian is not None:
            J = np.asarray(self.aux.jacobian(*self._state_views(stacks), _aux_view(self.aux, a), self.data), float)
            if J.shape != (self.F, self.aux.size, self.dof):
                raise ProblemDefinitionError(f"{self.where}: the auxiliary's jacobian returned shape {J.shape}, "
                                             f"expected ({self.F}, {self.aux.size}, {self.dof})")
            return a, J
        cols = []
        for k, var in enumerate(self.vars):
            for d in range(var.manifold.dof):
                step = np.zeros(var.manifold.dof)
                step[d] = FD_STEP
                moved = []
                for s in (step, -step):
                    st = list(stacks)
                    st[k] = np.array([var.manifold.retract(x, s) for x in stacks[k]])
                    moved.append(self.aux_value(st))
                cols.append((moved[0] - moved[1]) / (2 * FD_STEP))
        return a, np.stack(cols, axis=2)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """The declared residual at local columns θ (F, n), (F, m) (m = 0 without a residual)."""
        if self.family.residual is None:
            return np.zeros((self.F, 0))
        return self._caller(self.family.residual)(theta, self.data.reshape(self.F, -1))
