"""The lifted vector of one instance of a factor-graph problem: its blocks, lift, recover and samples.

The truth fixes the variables' multiplicity (``declare.Variable``).  Blocks, in order: per variable
(declaration order), per element (index order), the main block ``name`` (one variable) or ``name{i}``
(a stack; ``Variable.block`` for ``name`` when given, each of its parts when it splits the block; a stack's
names by ``Variable.element``), then its lifting and product blocks ``block`` or ``block{i}``; with ``by_element``, the
single variables' blocks, then element 0 of every stacked variable (declaration order), element 1, …; after
every variable, the factors' auxiliary blocks (``assemble``); last, the cost-only variables' blocks
(``Variable.cost_only``), in the same order among themselves.  ``order`` (``derive(blocks=…)``): the blocks
before the cost-only ones in the module's order instead, every one of them once.  A state is
``{name: value or (N, *shape) stack}`` with one entry per declared variable.  The stacked tangent vector (the
retraction steps ε, the sampler's draws) holds each variable's elements in index order, the variables in
declaration order or in the ``tangent`` order.

``width`` (``derive(width=…)``): the lifted variable is a matrix Θ (d × N, d = width) instead of a vector, the
paper's "matrix lifting" Θ = [I_d, C_0, r_0, …] with X = ΘᵀΘ.  A variable's value then contributes a d × k block
(k = size / d columns): its embedding v, which must be vec of a d × k matrix (columns stacked: Euclidean(d) gives
the column x, Rotation(d) the matrix C), reshaped; h is the block I_d (``Variables(d=width)``).  Only main blocks:
no lifting, product, auxiliary or cost-only blocks.  With a width (1 included) ``lift`` returns Θ as a (d, N) array
and ``recover`` takes one, normalised by Θ_h⁻¹ (``np.linalg.solve``, which a rank-d factor needs: it is defined up
to a left factor).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError
from ..model import Variables
from .declare import Variable
from .manifolds import Rotation


def cost_only_columns(sizes: Sequence[int], variables: Sequence[Variable]) -> np.ndarray:
    """The local columns (h is column 0, then blocks of ``sizes`` in order, one per variable) of the cost-only
    variables (``Variable.cost_only``), sorted."""
    starts = np.cumsum([1, *sizes])
    return np.concatenate([np.zeros(0, int)] + [np.arange(starts[k], starts[k + 1])
                                                for k, var in enumerate(variables) if var.cost_only])


@dataclass
class Element:
    """One variable of the instance: the declaration, its index in a stack (None: a single variable),
    its block names (main first) and its offset in the stacked tangent vector."""

    var: Variable
    index: int | None
    blocks: tuple[str, ...]
    tangent_offset: int

    @property
    def main(self) -> str:
        return self.blocks[0]

    @property
    def dof(self) -> int:
        return self.var.manifold.dof

    def value(self, state: Mapping[str, Any]) -> np.ndarray:
        v = np.asarray(state[self.var.name], float)
        return v if self.index is None else v[self.index]


def _check_width(variables: Sequence[Variable], width: int, auxiliary: bool) -> None:
    """Refuse what a lifting of width d cannot hold (see the module docstring), in one line."""
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width not in (1, 2, 3):
        raise ProblemDefinitionError(f"the lifting's width must be 1, 2 or 3, got {width!r}")
    if auxiliary:
        raise ProblemDefinitionError("a lifting of a given width holds no auxiliary blocks")
    for var in variables:
        if var.lifting or var.products or var.cost_only or var.manifold.size % width:
            raise ProblemDefinitionError(f"variable {var.name!r}: a lifting of width {width} holds d × k blocks of "
                                         "main blocks only (no lifting, product or cost-only blocks; size a multiple "
                                         "of d)")


def gram_form(M: np.ndarray, d: int) -> np.ndarray:
    """An equation [h; v]ᵀ M [h; v] = 0 of a variable's embedding v = vec B (B d × k, columns stacked) as the
    (d + k) × (d + k) matrix G on the columns [h (I_d), B] of a lifting of width d, ⟨G, [I_d B]ᵀ[I_d B]⟩ the same
    polynomial: G_hh = M_hh/d · I_d, G_{h_i, b_j} = M_{h, v_(j, i)} and M_vv = G_bb ⊗ I_d, as only dot products of
    columns are expressible (a one-line error otherwise)."""
    p = M.shape[0] - 1
    k = p // d
    S = M[1:, 1:]
    Gbb = S[::d, ::d]
    if not np.array_equal(S, np.kron(Gbb, np.eye(d))):
        raise ProblemDefinitionError(f"an equation of a variable is not a form in the dot products of its {k} "
                                     f"columns, which a lifting of width {d} holds")
    G = np.zeros((d + k, d + k))
    G[:d, :d] = (M[0, 0] / d) * np.eye(d)
    G[:d, d:] = M[0, 1:].reshape(d, k, order="F")
    G[d:, :d] = M[1:, 0].reshape(d, k, order="F").T
    G[d:, d:] = Gbb
    return G


class Layout:
    """The instance's elements and ``Variables`` (d = 1, or ``width``), with lift, recover and retraction."""

    def __init__(self, variables: Sequence[Variable], truth: Mapping[str, Any],
                 auxiliary: Sequence[tuple[str, int]] = (), by_element: bool = False,
                 tangent: Sequence[str] | None = None, order: Sequence[str] | None = None,
                 width: int | None = None):
        if not variables or not all(isinstance(v, Variable) for v in variables):
            raise ProblemDefinitionError("VARIABLES must be a non-empty list of autotight.graph.Variable")
        names = [v.name for v in variables]
        if len(set(names)) != len(names):
            raise ProblemDefinitionError(f"variable names must be unique, got {names}")
        if tangent is not None and sorted(tangent) != sorted(names):
            raise ProblemDefinitionError(f"the tangent order must name every variable once, got {list(tangent)} for "
                                         f"variables {names}")
        self.variables = list(variables)
        #: the lifting's width d (None: a vector, d = 1, as ``lift`` returns it); see the module docstring
        self.width = width
        d = 1 if width is None else width
        if width is not None:
            _check_width(self.variables, width, bool(auxiliary))
        self.elements: list[Element] = []
        self.counts: dict[str, int | None] = {}
        #: whether the blocks are ordered element by element (``derive(by_element=True)``)
        self.by_element = by_element
        placed: list[tuple[int, list[tuple[str, int]], bool]] = []  # (element index, its blocks, cost-only)
        offset = 0
        for var in self.variables:
            if var.name not in truth:
                raise ProblemDefinitionError(f"the truth has no entry {var.name!r} for variable {var.name!r}")
            shape, want = np.shape(truth[var.name]), var.manifold.shape
            if shape == want:
                count = None
            elif len(shape) == len(want) + 1 and shape[1:] == want:
                count = shape[0]
            else:
                raise ProblemDefinitionError(f"variable {var.name!r} on {var.manifold!r}: the truth's entry has shape "
                                             f"{shape}, expected {want} or (N, *{want})")
            self.counts[var.name] = count
            fits, parts = var.fits(), var.main_blocks()
            sizes = [var.manifold.size // len(parts) // d] * len(parts) + [f.size for f in fits] + \
                [k for k, _ in var.product_sizes()]
            for i in [None] if count is None else range(count):
                own = tuple(var.element_block(b, i) for b in parts + tuple(f.name for f in fits) + tuple(var.products))
                el = Element(var, i, own, offset)
                self.elements.append(el)
                placed.append((-1 if i is None else i, list(zip(el.blocks, sizes)), var.cost_only))
                offset += el.dof
        if by_element:  # element i of every variable (declaration order) before element i + 1; single ones first
            placed.sort(key=lambda p: p[0])
        blocks = [b for _, bs, last in placed if not last for b in bs]
        trailing = [b for _, bs, last in placed if last for b in bs]
        if tangent is not None:  # the stacked tangent vector in the given order of the variables
            offset = 0
            for name in tangent:
                for el in self.elements:
                    if el.var.name == name:
                        el.tangent_offset = offset
                        offset += el.dof
        self.n_tangent = offset
        taken = {b for b, _ in blocks + trailing}
        clash = [b for b, _ in auxiliary if b in taken or b == "h"]
        if clash:
            raise ProblemDefinitionError(f"auxiliary blocks {clash} have the names of other blocks")
        blocks += list(auxiliary)
        #: whether the module gave the blocks' order (``derive(blocks=…)``)
        self.ordered = order is not None
        if order is not None:  # the module's order: a permutation of the blocks above
            order, size = list(order), dict(blocks)
            if sorted(order) != sorted(size):
                missing = [b for b in size if b not in order]
                other = [b for b in order if b not in size or order.count(b) > 1]
                raise ProblemDefinitionError(f"the lifted vector's order must name every block once: missing "
                                             f"{missing}, unknown or repeated {sorted(set(other))}")
            blocks = [(b, size[b]) for b in order]
        self.V = Variables(blocks + trailing, d=d)
        self.by_main = {el.main: el for el in self.elements}
        for el in self.elements:  # also by name and index when the main block is renamed
            self.by_main.setdefault(el.var.name + ("" if el.index is None else str(el.index)), el)
        #: an element's index in ``elements`` (and in a value list), by main block
        self.position = {el.main: k for k, el in enumerate(self.elements)}
        self._columns = [self.V.index(el.blocks) for el in self.elements]
        single = {id(el.var): el for el in self.elements if el.index is None}
        #: per variable with product blocks (by id): per product block, the elements of its variables
        self.sources: dict[int, list[list[Element]]] = {}
        for var in self.variables:
            for b, over in var.products.items():
                if not all(id(o) in single for o in over):
                    raise ProblemDefinitionError(f"variable {var.name!r}: the variables of its product block {b!r} "
                                                 "must be declared single variables")
                self.sources.setdefault(id(var), []).append([single[id(o)] for o in over])
        #: per variable: its elements' positions (count,) and columns (count, k)
        self.families: list[tuple[Variable, np.ndarray, np.ndarray]] = []
        for var in self.variables:
            idx = np.array([k for k, el in enumerate(self.elements) if el.var is var])
            self.families.append((var, idx, np.array([self._columns[k] for k in idx])))
        #: the truth's values, element by element
        self.truth_values = self.values(truth)

    def element(self, main: str, where: str) -> Element:
        if main not in self.by_main:
            raise ProblemDefinitionError(f"{where}: unknown variable {main!r}; variables are {list(self.by_main)}")
        return self.by_main[main]

    def columns(self, el: Element) -> np.ndarray:
        """The element's columns of the lifted vector, main block first."""
        return self._columns[self.position[el.main]]

    def thetas(self, var: Variable, values: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per product block of the variable, θ: its variables' embeddings at the values, stacked."""
        return [np.concatenate([o.var.manifold.embed(values[self.position[o.main]]) for o in src])
                for src in self.sources.get(id(var), [])]

    def product_columns(self, var: Variable) -> np.ndarray:
        """The columns of the variable's products' θ, in order (their variables' main blocks), (Σ q,)."""
        cols = [self._columns[self.position[o.main]][:o.var.manifold.size]
                for src in self.sources.get(id(var), []) for o in src]
        return np.concatenate(cols) if cols else np.zeros(0, int)

    def values(self, state: Mapping[str, Any]) -> list[np.ndarray]:
        """The elements' values in order (checked against the manifold's shape)."""
        out = []
        for el in self.elements:
            if el.var.name not in state:
                raise ProblemDefinitionError(f"the state has no entry {el.var.name!r}")
            x = el.value(state)
            if x.shape != el.var.manifold.shape:
                raise ProblemDefinitionError(f"state entry {el.var.name!r} has an element of shape {x.shape}, "
                                             f"expected {el.var.manifold.shape}")
            out.append(x)
        return out

    def state(self, values: Sequence[np.ndarray]) -> dict[str, np.ndarray]:
        """The state holding the elements' values."""
        out: dict[str, np.ndarray] = {}
        k = 0
        for var in self.variables:
            count = self.counts[var.name]
            if count is None:
                out[var.name] = np.asarray(values[k], float)
                k += 1
            else:
                out[var.name] = np.array(values[k:k + count], float).reshape((count,) + var.manifold.shape)
                k += count
        return out

    def lift(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """x = [h, blocks…] (N,) with h = 1; with a ``width`` d, Θ = [I_d, blocks…] (d, N)."""
        if self.width is not None:
            Theta = np.zeros((self.width, self.V.N))
            Theta[:, :self.width] = np.eye(self.width)
            for cols, el, v in zip(self._columns, self.elements, values):
                Theta[:, cols] = el.var.manifold.embed(v).reshape(self.width, -1, order="F")
            return Theta
        x = np.zeros(self.V.N)
        x[0] = 1.0
        for cols, el, v in zip(self._columns, self.elements, values):
            x[cols] = el.var.lifted(v, self.thetas(el.var, values))
        return x

    def lift_polynomial(self, values: Sequence[np.ndarray], extra: tuple[list, list, list] | None = None,
                        dense: bool = False) -> tuple[np.ndarray, Any]:
        """(x, ∂x/∂ε) at the values from the liftings' fitted polynomials, a variable's elements at once: x as
        ``lift`` (up to rounding), ∂x/∂ε (N, n_tangent) the embedding's tangent map T and each lifting block's
        gradient times T (the h row zero), plus ``extra`` entries (rows, columns, values lists) of ∂x/∂ε (summed
        where they meet); ∂x/∂ε sparse, or an array when ``dense``.  For the local solver, which evaluates them
        at every step."""
        x = np.zeros(self.V.N)
        x[0] = 1.0
        rows, cols, vals = extra if extra is not None else ([], [], [])
        for var, idx, columns in self.families:
            man, fits = var.manifold, var.fits()
            E = np.array([man.embed(values[k]) for k in idx])  # (n, p)
            T = np.array([man.tangent(values[k]) for k in idx])  # (n, p, dof)
            X = [E] + [f.values(E) for f in fits]
            Ds = [T] + [np.einsum("nep,npd->ned", f.gradients(E), T) for f in fits]
            o = sum(a.shape[1] for a in X)
            for src, th in zip(self.sources.get(id(var), []), self.thetas(var, values)):
                # z = x ⊗ θ: ∂z = ∂x ⊗ θ along the element's steps, x ⊗ ∂θ along its variables' (sparse rows below)
                k = E.shape[1] * th.size
                X.append((E[:, :, None] * th).reshape(len(idx), k))
                Ds.append((T[:, :, None, :] * th[:, None]).reshape(len(idx), k, T.shape[2]))
                Tth = np.zeros((th.size, sum(el.dof for el in src)))
                q = dof = 0
                for el in src:
                    Tth[q:q + el.var.manifold.size, dof:dof + el.dof] = el.var.manifold.tangent(
                        values[self.position[el.main]])
                    q, dof = q + el.var.manifold.size, dof + el.dof
                steps = np.concatenate([np.arange(el.tangent_offset, el.tangent_offset + el.dof) for el in src])
                G = (E[:, :, None, None] * Tth).reshape(len(idx), k, Tth.shape[1])
                n, r, c = np.nonzero(G)
                rows.append(columns[n, o + r])
                cols.append(steps[c])
                vals.append(G[n, r, c])
                o += k
            x[columns] = np.hstack(X)
            D = np.concatenate(Ds, axis=1)
            offsets = np.array([self.elements[k].tangent_offset for k in idx])
            n, r, c = np.nonzero(D)
            rows.append(columns[n, r])
            cols.append(offsets[n] + c)
            vals.append(D[n, r, c])
        if dense:
            flat = np.concatenate(rows).astype(np.int64) * self.n_tangent + np.concatenate(cols)
            D = np.bincount(flat, weights=np.concatenate(vals), minlength=self.V.N * self.n_tangent)
            return x, D.reshape(self.V.N, self.n_tangent)
        J = sp.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(self.V.N, self.n_tangent))
        return x, J

    def raw(self, x: np.ndarray) -> list[np.ndarray]:
        """Each element's main block, unembedded, from x divided by h (when h ≠ 0): not yet on its manifold.  With
        a ``width`` d, x is Θ (d, N) (or (N,) when d = 1), normalised as Θ_h⁻¹ Θ."""
        if self.width is not None:
            T = np.asarray(x, float).reshape(self.width, -1)
            T = np.linalg.solve(T[:, :self.width], T)
            return [el.var.manifold.unembed(T[:, cols].ravel(order="F"))
                    for el, cols in zip(self.elements, self._columns)]
        x = np.asarray(x, float).reshape(-1)
        x = x / x[0] if x[0] != 0 else x
        return [el.var.manifold.unembed(x[cols[:el.var.manifold.size]])
                for el, cols in zip(self.elements, self._columns)]

    def recover(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The state of x: each element's ``raw`` value projected onto its manifold; for the rotations, the
        determinants of the raw values as ``det_raw`` (one rotation variable: its value or (N,) stack) or
        ``<name>_det_raw`` (several), as the shipped problems report an O(d) solution's reflection."""
        raw = self.raw(x)
        state = self.state([el.var.manifold.project(a) for el, a in zip(self.elements, raw)])
        rotations = [var for var in self.variables if isinstance(var.manifold, Rotation)]
        for var in rotations:
            dets = np.array([np.linalg.det(a) for el, a in zip(self.elements, raw) if el.var is var])
            key = "det_raw" if len(rotations) == 1 else f"{var.name}_det_raw"
            state[key] = dets.reshape(()) if self.counts[var.name] is None else dets
        return state

    def retract(self, values: Sequence[np.ndarray], eps: np.ndarray) -> list[np.ndarray]:
        """Each element retracted by its slice of the stacked tangent vector ε (n_tangent,)."""
        return [el.var.manifold.retract(v, eps[el.tangent_offset:el.tangent_offset + el.dof])
                for el, v in zip(self.elements, values)]
