"""What a factor-graph problem declares: its variables (manifold and lifting) and its factors.

``Variable(name, manifold, lifting={block: fn}, type=None, block=None)``: a state entry ``name`` on
``manifold`` (``autotight.graph.manifolds``).  The truth's entry fixes how many there are: an array of the
manifold's shape is one variable, a stack (N, *shape) is N of them (block names ``name0 … name{N−1}``;
``block`` renames the main block, or splits it into equal named parts, e.g. ("c1", "c2", "c3") for the
columns of vec C).  The lifted vector holds, per variable, its embedding (the main block)
and one block per ``lifting`` entry, ``fn(x) -> (E,)``, which must be a polynomial of degree ≤ 2 in the
embedding's entries (e.g. vech(p pᵀ)); its primary constraints fn(x) − h·z = 0 are derived from it
(``LiftingFit``).  ``type`` names the factor type of the variable's own model factor (default: ``name``):
variables of one type share it, element by element (e.g. a pose's rotation and translation; ``assemble``).
``constraint_names`` formats the model names of its constraints (default "{factor}:{variable}:{constraint}"),
or is a function of them (``Variable.constraint_names``).

``Factor(variables, residual, …)``: a term eᵀWe of the cost, on one or more variables named by their
main block or by name and index (``"p0"``, or ``"C"`` for a single variable).  ``residual(*views) ->
(m,)`` gets one ``View`` per variable: ``view.x`` its value (an array of the manifold's shape) and
``view.<block>`` each lifting block.  When the residual is affine in the views' entries (constants
standing for h), the lifted cost is derived; otherwise give it (``cost``: the (n, n) symmetric matrix on
the factor's local columns [h, the variables' blocks in order]).  ``jacobian(*views) -> (m, Σ dof)`` is
optional (the chain rule through the lifting when the residual is affine, central finite differences on
the retraction otherwise).  ``constraints``: extra primary constraints [(name, (n, n) matrix)] on the same
local columns (value 0); ``data``: the factor's measurement vector (``autotight.model.Factor.data``);
``type``: its factor type; ``name``: its model factor's name; ``constraint_names``: the format of its
constraints' model names (default "{factor}:{constraint}"); ``own``: a model factor of its own even without
constraints; ``roles``: its model factor's roles after h (its blocks then in its variables' order).  ``cost`` and
the constraints' matrices may be dense or scipy sparse.

``Factor(…, auxiliary=Auxiliary(blocks, value, equations, jacobian=None))``: lifted blocks the factor owns,
which are not a polynomial lifting of one variable but functions of the factor's variables and data (e.g.
a Cayley residual φ = cay⁻¹(C C̃ᵀ)).  ``blocks``: {name: size}; their columns follow every variable's
blocks in the lifted vector (block ``b_j`` for the j-th factor declaring ``b``) and the factor's local
columns (after its variables').  ``value(*views) -> (Σ sizes,)``: their value at states (ValueError where
undefined: ``sample`` draws again).  ``equations(*views, aux) -> (k,)``: their defining relations, each a
polynomial of degree ≤ 2 in the local entries (``aux.<block>`` the blocks' entries), zero at the value;
fitted into k primary constraints of the factor (``terms``).  ``jacobian(*views, aux) -> (Σ sizes, Σ dof)``:
∂value/∂ε for the local solver (default central differences); ``names``: the equations' constraint names
(default ``aux[k]``).  The residual then gets ``aux`` after the views, e.g. ``lambda C, aux: aux.phi``, so a
cost on the blocks is an affine residual.  ``equations`` may be None when the factor's declared ``constraints``
define the blocks (matrices used as given); ``element`` names the blocks in the lifted vector (default
"{block}_{i}").

``Group(blocks, type, roles, data, name)``: a model factor with no cost and no constraints on blocks of the
lifted vector (by name, h prepended), a learning group for discovery.

``Variable(…, products={block: variables})``: blocks z = x ⊗ θ, the variable's embedding x times θ, the
embeddings of the given single ``Variable`` objects stacked (Kronecker, entry a·q + c = x_a θ_c; e.g. a label w
with z = w [t; vec C]), after its lifting blocks; their primary constraints h·z = x ⊗ θ.  The element's own
model factor then holds those variables' main and lifting blocks first (h, t, c, w_i, z_i), so that discovery
learns the relations between the products and the liftings (for z = a ⊗ b with liftings vech(a aᵀ), vech(b bᵀ):
z₀² = a₀²·b₀²), and the cost of a factor on the element and those variables joins it.  A factor declared on
such a variable without its products' variables is on them too, after the ones it names (``terms.Term``).

``Variable(…, cost_only=True)``: a variable that only costs see (no constraints, no lifting; e.g. the twists of
a motion prior): its blocks come last in the lifted vector, it has no model factor and the model factors of the
declared factors on it leave its blocks out; their costs then make the model's explicit cost (``assemble``).

``Family(variables, residual, data, type, …)``: F factors of one type at once, their data stacked (F, *shape)
and every function called on stacks with the data last (``family``); their auxiliary's equations and their
``paper`` rows (the paper's redundant constraints) fitted once per family, their blocks optionally clique hints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import ProblemDefinitionError
from ..factor_batch import coefficients, features, probe_points
from .manifolds import Manifold

#: a lifting block must equal its fitted polynomial of degree ≤ 2 to this relative accuracy at a random point
LIFTING_RTOL = 1e-9

#: relative size (to the largest value at the probe points) below which a fitted coefficient is rounding
ROUNDING = 32 * np.finfo(float).eps

View = SimpleNamespace


def _distinct_names(names: Sequence[Any], *excluded: str) -> bool:
    """Whether ``names`` are distinct non-empty strings, none of them in ``excluded``."""
    return (all(isinstance(n, str) and n and n not in excluded for n in names)
            and len(set(names)) == len(names))


@dataclass
class LiftingFit:
    """One lifting block z = c0 + G v + [vᵀ S_e v]_e as a polynomial in the embedding v (size p):
    c0 (E,), G (E, p), S (E, p, p) symmetric."""

    name: str
    fn: Callable[[np.ndarray], Any]
    c0: np.ndarray
    G: np.ndarray
    S: np.ndarray

    @property
    def size(self) -> int:
        return int(self.c0.size)

    def gradient(self, v: np.ndarray) -> np.ndarray:
        """∂z/∂v at v, (E, p)."""
        return self.G + 2.0 * np.einsum("epq,q->ep", self.S, v)

    def values(self, V: np.ndarray) -> np.ndarray:
        """z at each row of V (n, p) by the polynomial, (n, E) (``fn``'s values up to rounding)."""
        return self.c0 + V @ self.G.T + np.einsum("np,epq,nq->ne", V, self.S, V)

    def gradients(self, V: np.ndarray) -> np.ndarray:
        """∂z/∂v at each row of V (n, p), (n, E, p)."""
        return self.G + 2.0 * np.einsum("epq,nq->nep", self.S, V)

    def constraint_matrices(self, p: int, offset: int) -> list[np.ndarray]:
        """c0_e h² + G_e v h + vᵀ S_e v − h·z_e = 0 on local columns [h, v (p), …, z at ``offset``, …]."""
        n = offset + self.size
        out = []
        for e, form in enumerate(quadratic_forms(self.c0, self.G, self.S)):
            M = np.zeros((n, n))
            M[:1 + p, :1 + p] = form
            M[0, offset + e] = M[offset + e, 0] = -0.5
            out.append(M)
        return out


def fit_quadratic(call: Callable[[np.ndarray], np.ndarray], p: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The polynomial c0 + G v + [vᵀ S_e v]_e of degree ≤ 2 that ``call(v) -> (E,)`` is in v (size p), from exact
    differences at ``factor_batch.probe_points``: (c0 (E,), G (E, p), S (E, p, p) symmetric, the relative
    error of the fit at a random point, which is rounding when ``call`` is such a polynomial).  Coefficients
    within ``ROUNDING`` of the largest value at the probes are rounding of the differences and set to 0, so
    a polynomial's absent monomials stay exactly absent (e.g. ½φ × c̃ at φ = ±e_j leaves ~1e-17 on φ_j²)."""
    values = np.array([call(v) for v in probe_points(p, 2)])
    coef = coefficients(values, p, 2)
    coef[np.abs(coef) <= ROUNDING * max(1.0, float(np.abs(values).max()))] = 0.0
    c0, lin, sq, cross = coef[0], coef[1:p + 1], coef[p + 1:2 * p + 1], coef[2 * p + 1:]
    S = np.zeros((values.shape[1], p, p))
    S[:, np.arange(p), np.arange(p)] = sq.T
    i, j = np.triu_indices(p, 1)
    S[:, i, j] = S[:, j, i] = 0.5 * cross.T
    v = np.random.default_rng(0).standard_normal(p)
    want = call(v)
    got = features(v[None], 2)[0] @ coef
    return c0, lin.T.copy(), S, float(np.abs(got - want).max() / max(1.0, float(np.abs(want).max())))


def fit_lifting(name: str, fn: Callable[[np.ndarray], Any], manifold: Manifold, where: str) -> LiftingFit:
    """The polynomial of degree ≤ 2 that ``fn`` (of the manifold's ambient value) is in the embedding's entries
    (``fit_quadratic``), checked at a random point to ``LIFTING_RTOL``."""

    def call(v: np.ndarray) -> np.ndarray:
        z = np.asarray(fn(manifold.unembed(v)), dtype=float)
        if z.ndim > 1 or not z.size:
            raise ProblemDefinitionError(f"{where}: lifting block {name!r} must return a non-empty vector, "
                                         f"got shape {z.shape}")
        return z.reshape(-1)

    c0, G, S, err = fit_quadratic(call, manifold.size)
    if err > LIFTING_RTOL:
        raise ProblemDefinitionError(f"{where}: lifting block {name!r} is not a polynomial of degree ≤ 2 in the "
                                     "variable's entries")
    return LiftingFit(name, fn, c0, G, S)


def quadratic_forms(c0: np.ndarray, G: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(E, 1 + p, 1 + p): each polynomial c0_e + G_e v + vᵀ S_e v homogenised, [h; v]ᵀ M_e [h; v]."""
    E, p = G.shape
    M = np.zeros((E, 1 + p, 1 + p))
    M[:, 0, 0] = c0
    M[:, 0, 1:] = M[:, 1:, 0] = 0.5 * G
    M[:, 1:, 1:] = S
    return M


@dataclass
class Variable:
    """A state entry on a manifold, with its lifting blocks (see the module docstring)."""

    name: str
    manifold: Manifold
    lifting: Mapping[str, Callable[[np.ndarray], Any]] = field(default_factory=dict)
    #: the factor type of the variable's own model factor (default: its name)
    type: str | None = None
    #: the name of its main block (default: its name), or a tuple of names splitting it into that many equal
    #: consecutive blocks (e.g. ("c1", "c2", "c3"): the columns of vec C)
    block: str | tuple[str, ...] | None = None
    #: the block names of element i of a stack, a format of ``block`` and ``i`` (default "{block}{i}"; e.g.
    #: "T{i}_{block}" names pose i's blocks T{i}_c1, …)
    element: str = "{block}{i}"
    #: the name stem of its own model factor (default: its type), suffixed ``_i`` for element i of a stack
    factor: str | None = None
    #: the names of its manifold's and lifting's constraints in the model, a format of {factor} (its model factor's
    #: name), {variable} (its main block's name, or its name and index when ``block`` splits it) and {constraint}
    #: (e.g. "orth(0,1)"); "{constraint}" keeps the bare names (then they must be distinct in the model).  Or a
    #: function of keyword arguments: those three, ``equation`` and ``row`` (a manifold's equation name and None,
    #: or a lifting or product block's name and the row: "orth(0,1)", None; "z", 3) and ``index`` (the element's,
    #: None for a single variable), e.g. for names a saved set carries, "w²(2)" and "z(2:3)"
    constraint_names: str | Callable[..., str] = "{factor}:{variable}:{constraint}"
    #: product blocks {block: variables}, z = x ⊗ θ: the variable's embedding times θ, the embeddings of the given
    #: single variables stacked (Kronecker; e.g. {"z": (t, C)}: z = w [t; vec C]); primary constraints h·z = x ⊗ θ;
    #: its own model factor holds those variables' main and lifting blocks first
    products: Mapping[str, Sequence[Variable]] = field(default_factory=dict)
    #: a variable of the cost only (e.g. twists under a motion prior): blocks last in the lifted vector (after
    #: the factors' auxiliary blocks), no model factor of its own, left out of the model factors' blocks; the
    #: declared costs on it make the model's explicit cost (``assemble``).  Needs no constraints, no lifting and
    #: no products
    cost_only: bool = False

    def __post_init__(self) -> None:
        check_element(self.element, f"variable {self.name!r}")
        if not callable(self.constraint_names):
            check_format(self.constraint_names, ("factor", "variable", "constraint"), f"variable {self.name!r}")
        if self.factor is not None and (not isinstance(self.factor, str) or not self.factor):
            raise ProblemDefinitionError(f"variable {self.name!r}: factor must be a non-empty string")
        parts = self.block if isinstance(self.block, tuple) else ("x" if self.block is None else self.block,)
        for what, v in (("name", self.name),) + tuple(("block", b) for b in parts):
            if not isinstance(v, str) or not v.isidentifier() or v == "h":
                raise ProblemDefinitionError(f"a variable's {what} must be an identifier other than 'h', got {v!r}")
        if len(set(parts)) != len(parts) or self.manifold.size % len(parts):
            raise ProblemDefinitionError(f"variable {self.name!r}: its main block of size {self.manifold.size} "
                                         f"does not split into the distinct blocks {parts}")
        bad = [b for b in self.lifting if not isinstance(b, str) or not b.isidentifier() or b in ("x", "h")]
        if bad:
            raise ProblemDefinitionError(f"variable {self.name!r}: lifting block names must be identifiers other "
                                         f"than 'x' and 'h', got {bad}")
        self.products = {b: tuple(vs) for b, vs in dict(self.products).items()}
        bad = [b for b, vs in self.products.items() if not isinstance(b, str) or not b.isidentifier()
               or b in ("x", "h") or b in self.lifting or not vs or not all(isinstance(v, Variable) for v in vs)]
        if bad:
            raise ProblemDefinitionError(f"variable {self.name!r}: product blocks must map identifiers other than 'x', "
                                         f"'h' and the lifting blocks to non-empty sequences of Variable, got {bad}")
        if self.cost_only and (self.lifting or self.products or self.manifold.constraints()):
            raise ProblemDefinitionError(f"variable {self.name!r}: a cost-only variable has no lifting, no products "
                                         "and no manifold equations (it is in no model factor)")
        self._fits: list[LiftingFit] | None = None

    def element_block(self, block: str, i: int | None) -> str:
        """The name of a block of element i (None: a single variable, whose blocks keep their names)."""
        return block if i is None else self.element.format(block=block, i=i)

    def main_blocks(self) -> tuple[str, ...]:
        """The names of its main block's parts (one, unless ``block`` splits it), without an element's index."""
        return self.block if isinstance(self.block, tuple) else (self.block or self.name,)

    def fits(self) -> list[LiftingFit]:
        """The lifting blocks as fitted polynomials (computed once)."""
        if self._fits is None:
            where = f"variable {self.name!r}"
            self._fits = [fit_lifting(b, fn, self.manifold, where) for b, fn in self.lifting.items()]
        return self._fits

    def product_sizes(self) -> list[tuple[int, int]]:
        """Per product block, (its size p·q, q the size of θ)."""
        p = self.manifold.size
        return [(p * q, q) for q in (sum(v.manifold.size for v in vs) for vs in self.products.values())]

    def lifted(self, x: np.ndarray, thetas: Sequence[np.ndarray] = ()) -> np.ndarray:
        """[embed(x), lifting blocks…, product blocks…] (the variable's columns of the lifted vector, h excluded);
        ``thetas``: each product block's θ (its variables' embeddings stacked)."""
        v = self.manifold.embed(x)
        parts = [v] + [np.asarray(f.fn(x), float).reshape(-1) for f in self.fits()]
        return np.concatenate(parts + [np.kron(v, th) for th in thetas])

    def view(self, theta: np.ndarray) -> View:
        """The ``View`` of the variable's columns θ (h excluded): x = unembed(main block), then each block."""
        p = self.manifold.size
        out, o = {"x": self.manifold.unembed(theta[:p])}, p
        for f in self.fits():
            out[f.name] = theta[o:o + f.size]
            o += f.size
        for b, (k, _) in zip(self.products, self.product_sizes()):
            out[b] = theta[o:o + k]
            o += k
        return View(**out)

    def equations(self) -> list[tuple[str, int | None]]:
        """(equation, row) of each of ``local_constraints``, in order (see ``constraint_names``)."""
        blocks = [(f.name, f.size) for f in self.fits()] + [(b, k) for b, (k, _) in zip(self.products,
                                                                                      self.product_sizes())]
        return [(name, None) for name, _ in self.manifold.constraints()] + [(b, e) for b, k in blocks for e in range(k)]

    def local_constraints(self) -> list[tuple[str, np.ndarray]]:
        """The manifold's, the lifting's and the products' equations on [h, main, lifting blocks…, product
        blocks…, then each product's θ] (matrices padded to it)."""
        p = self.manifold.size
        sizes = self.product_sizes()
        start = 1 + p + sum(f.size for f in self.fits()) + sum(k for k, _ in sizes)  # the first θ's column
        n = start + sum(q for _, q in sizes)
        out = []
        for name, M in self.manifold.constraints():
            out.append((name, _pad(M, n)))
        o = 1 + p
        for f in self.fits():
            for e, M in enumerate(f.constraint_matrices(p, o)):
                out.append((f"{f.name}[{e}]", _pad(M, n)))
            o += f.size
        for b, (k, q) in zip(self.products, sizes):  # h·z_e − x_a θ_c = 0, e = a q + c
            for e in range(k):
                a, c = divmod(e, q)
                M = np.zeros((n, n))
                M[0, o + e] = M[o + e, 0] = 0.5
                M[1 + a, start + c] = M[start + c, 1 + a] = -0.5
                out.append((f"{b}[{e}]", M))
            o += k
            start += q
        return out


def _pad(M: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, n))
    out[:M.shape[0], :M.shape[1]] = M
    return out


def check_element(fmt: object, where: str) -> None:
    """Refuse a block-name format that is not a string of {block} and {i} giving identifiers."""
    try:
        ok = isinstance(fmt, str) and "{block}" in fmt and "{i}" in fmt and fmt.format(block="b", i=7).isidentifier()
    except (AttributeError, KeyError, IndexError, ValueError):
        ok = False
    if not ok:
        raise ProblemDefinitionError(f"{where}: element must be a format of {{block}} and {{i}} giving identifiers, "
                                     f"got {fmt!r}")


def check_format(fmt: object, fields: tuple[str, ...], where: str) -> None:
    """Refuse a constraint name format that is not a string holding {constraint} and no field but ``fields``."""
    probe = {f: "x" for f in fields}
    try:
        ok = isinstance(fmt, str) and "{constraint}" in fmt and bool(fmt.format(**probe))
    except (AttributeError, KeyError, IndexError, ValueError):
        ok = False
    if not ok:
        raise ProblemDefinitionError(f"{where}: constraint_names must be a format holding {{constraint}} and no field "
                                     f"but {', '.join('{' + f + '}' for f in fields)}, got {fmt!r}")


@dataclass
class Auxiliary:
    """Lifted blocks owned by one factor, functions of its variables' values and its data (see the module
    docstring): ``blocks`` {name: size} in order, ``value(*views) -> (Σ sizes,)`` at states (ValueError where
    undefined), ``equations(*views, aux) -> (k,)`` their defining relations, each a polynomial of degree ≤ 2 in
    the factor's local entries and zero at the value, ``jacobian(*views, aux) -> (Σ sizes, Σ dof)`` optional.

    ``equations`` may be None on a ``Factor`` whose declared ``constraints`` (matrices on its local columns, used
    as given) are the defining relations, e.g. to keep a hand-written model's matrices to the last bit (a fit
    from evaluations at h = 1 rounds where a constant meets a data-dependent coefficient).  ``element``: the
    blocks' names in the lifted vector, a format of {block} and {i} (i: the factor's rank among those declaring
    the block, or its ``Family.aux_names`` suffix), e.g. "{block}{i}" for u0, u1, …"""

    blocks: Mapping[str, int]
    value: Callable[..., Any]
    equations: Callable[..., Any] | None = None
    jacobian: Callable[..., Any] | None = None
    element: str = "{block}_{i}"
    #: the equations' names, one per row (the constraints ``{factor}:{name}``; default ``aux[k]``)
    names: Sequence[str] | None = None

    def __post_init__(self) -> None:
        self.blocks = dict(self.blocks)
        if self.names is not None:
            self.names = tuple(self.names)
            if not self.names or not all(isinstance(n, str) and n for n in self.names):
                raise ProblemDefinitionError(f"auxiliary blocks {list(self.blocks)}: names must be non-empty strings")
        bad = [b for b, k in self.blocks.items() if not isinstance(b, str) or not b.isidentifier() or b in ("x", "h")
               or isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1]
        if not self.blocks or bad:
            raise ProblemDefinitionError("auxiliary blocks must map identifiers other than 'x' and 'h' to positive "
                                         f"sizes, got {self.blocks}")
        for what, fn in (("value", self.value), ("equations", self.equations)):
            if not callable(fn) and not (what == "equations" and fn is None):
                raise ProblemDefinitionError(f"auxiliary blocks {list(self.blocks)}: {what} must be a function")
        check_element(self.element, f"auxiliary blocks {list(self.blocks)}")

    @property
    def size(self) -> int:
        return int(sum(self.blocks.values()))

    def view(self, a: np.ndarray) -> View:
        """The ``View`` of the blocks' entries a (Σ sizes,): one attribute per block."""
        out, o = {}, 0
        for b, k in self.blocks.items():
            out[b] = a[o:o + k]
            o += k
        return View(**out)


@dataclass
class Factor:
    """A cost term on variables (see the module docstring)."""

    variables: str | Sequence[str]
    residual: Callable[..., Any]
    type: str | None = None
    weight: float | np.ndarray | None = None
    jacobian: Callable[..., Any] | None = None
    cost: np.ndarray | None = None
    constraints: Sequence[tuple[str, np.ndarray]] = ()
    data: np.ndarray | None = None
    #: lifted blocks of its own (``Auxiliary``), after every variable's blocks in the lifted vector
    auxiliary: Auxiliary | None = None
    #: its model factor's name (default ``type_i``, i its position among the declared factors)
    name: str | None = None
    #: the names of its constraints (declared, and its auxiliary's fitted ``aux[i]``) in the model, a format of
    #: {factor} (its model factor's name) and {constraint}; "{constraint}" keeps the declared names (then they must
    #: be distinct in the model)
    constraint_names: str = "{factor}:{constraint}"
    #: whether it is a model factor of its own (named ``name``, holding its cost) even without constraints or
    #: auxiliary blocks of its own, e.g. one factor per measurement, as a paper writes its cost terms
    own: bool = False
    #: the roles of its model factor's blocks after h (its variables' blocks, then its auxiliary blocks), e.g.
    #: ("C_i", "r_i", "C_j", "r_j"); given, the model factor lists its blocks in the factor's order of its
    #: variables, also with the module's order of the lifted vector (``derive(blocks=…)``).  Default derived
    #: (``assemble``)
    roles: Sequence[str] | None = None

    def __post_init__(self) -> None:
        self.variables = (self.variables,) if isinstance(self.variables, str) else tuple(self.variables)
        if self.roles is not None:
            self.roles = tuple(self.roles)
            if not _distinct_names(self.roles, "h"):
                raise ProblemDefinitionError(f"factor on {self.variables}: roles must be distinct non-empty strings "
                                             f"other than 'h', got {self.roles}")
        if not self.variables or len(set(self.variables)) != len(self.variables):
            raise ProblemDefinitionError(f"a factor needs distinct variables, got {self.variables}")
        if not callable(self.residual):
            raise ProblemDefinitionError(f"factor on {self.variables}: residual must be a function")
        if self.auxiliary is not None and not isinstance(self.auxiliary, Auxiliary):
            raise ProblemDefinitionError(f"factor on {self.variables}: auxiliary must be an autotight.graph.Auxiliary")
        if self.auxiliary is not None and self.auxiliary.equations is None and not self.constraints:
            raise ProblemDefinitionError(f"factor on {self.variables}: its auxiliary blocks need equations or the "
                                         "factor's declared constraints to define them")
        if self.name is not None and (not isinstance(self.name, str) or not self.name):
            raise ProblemDefinitionError(f"factor on {self.variables}: name must be a non-empty string")
        check_format(self.constraint_names, ("factor", "constraint"), f"factor on {self.variables}")


@dataclass
class Family:
    """F factors of one type declared at once, their functions evaluated on stacks (see ``family``).

    ``variables``: the variables of every factor (one name or a sequence of names), or F such sequences (the
    k-th variables of all factors the same ``Variable``, e.g. ``[("p0", "p1"), ("p1", "p2")]``).  ``data``:
    the factors' measurements stacked, (F, *shape); each factor's model ``Factor.data`` is its row, raveled.
    ``residual(*views, [aux,] data) -> (F, m)``: views of stacks (``view.x`` (F, *shape), ``view.<block>``
    (F, size)), the auxiliary's view when there is one, the data stack; affine in the views' entries (the
    lifted cost is derived), or None: the factors have no cost (constraints only: the auxiliary's equations and
    the paper rows).  ``weight``: a number, an (m, m) or an (F, m, m) stack of symmetric matrices.
    ``auxiliary``: an ``Auxiliary`` whose functions take the same stacks and the data (``value(*views,
    data) -> (F, Σ sizes)``, ``equations(*views, aux, data) -> (F, k)``, ``jacobian(*views, aux, data) ->
    (F, Σ sizes, Σ dof)``).  ``paper``: redundant constraints {family: rows(*views, [aux,] data) -> (F, k)},
    valid at every state, each row a polynomial of degree ≤ 2 in the local entries (as the equations), kept
    in ``Model.paper[family]``.  The equations' and paper rows' coefficients must be polynomials of degree
    ≤ ``degree`` (1 or 2) in the data: they are fitted once per family.  ``names``: the factors' model
    names (default ``type_i``).  ``clique``: each factor's blocks are a clique hint (``Model.cliques``).
    ``aux_names``: the suffixes of the factors' auxiliary block names; ``roles``: the roles of their blocks;
    ``paper_labels``: the labels of a paper family's rows; ``record_data``: False leaves the model factors'
    ``data`` None (all optional).
    """

    variables: str | Sequence[str] | Sequence[Sequence[str]]
    residual: Callable[..., Any] | None
    data: np.ndarray
    type: str
    weight: float | np.ndarray | None = None
    auxiliary: Auxiliary | None = None
    paper: Mapping[str, Callable[..., Any]] = field(default_factory=dict)
    names: Sequence[str] | None = None
    clique: bool = False
    degree: int = 2
    #: the suffixes of each factor's auxiliary block names, ``b_{suffix}`` (``Auxiliary.element`` with i the suffix;
    #: default: the factor's rank among the factors declaring ``b``)
    aux_names: Sequence[str] | None = None
    #: the roles of its factors' blocks (h, the variables' blocks, the auxiliary blocks); default derived
    #: (``assemble``: a variable appearing twice gets its roles suffixed ``_k``)
    roles: Sequence[str] | None = None
    #: per paper family, the labels of its rows (constraints ``name:family[label]``; default 1, 2, …)
    paper_labels: Mapping[str, Sequence[str]] | None = None
    #: whether each model factor's ``Factor.data`` is its row of ``data`` (False: None, the data only feeding
    #: the family's functions, e.g. for a module whose learned sets were found without factor data)
    record_data: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.type, str) or not self.type:
            raise ProblemDefinitionError(f"a factor family needs a type (a non-empty string), got {self.type!r}")
        where = f"factor family {self.type!r}"
        self.data = np.asarray(self.data, dtype=float)
        if self.data.ndim < 1 or not len(self.data):
            raise ProblemDefinitionError(f"{where}: data must be a non-empty (F, …) stack, got shape "
                                         f"{self.data.shape}")
        F = len(self.data)
        v = self.variables
        members: list[tuple[str, ...]]
        if isinstance(v, str):
            members = [(v,)] * F
        elif v and all(isinstance(x, str) for x in v):
            members = [tuple(str(x) for x in v)] * F
        else:
            members = [(x,) if isinstance(x, str) else tuple(x) for x in v]
        if len(members) != F or any(not m or len(set(m)) != len(m) or len(m) != len(members[0]) for m in members):
            raise ProblemDefinitionError(f"{where}: variables must be one sequence of distinct names or {F} of them, "
                                         "each as long")
        #: each factor's variables
        self.members = members
        if self.residual is not None and not callable(self.residual):
            raise ProblemDefinitionError(f"{where}: residual must be a function (or None: no cost)")
        if self.auxiliary is not None and not isinstance(self.auxiliary, Auxiliary):
            raise ProblemDefinitionError(f"{where}: auxiliary must be an autotight.graph.Auxiliary")
        if self.auxiliary is not None and self.auxiliary.equations is None:
            raise ProblemDefinitionError(f"{where}: a family's auxiliary blocks need equations (a family declares no "
                                         "constraints of its own)")
        self.paper = dict(self.paper)
        if any(not isinstance(k, str) or not k or not callable(fn) for k, fn in self.paper.items()):
            raise ProblemDefinitionError(f"{where}: paper must map family names to functions")
        if self.paper_labels is not None:
            self.paper_labels = {k: tuple(str(x) for x in v) for k, v in dict(self.paper_labels).items()}
            if not set(self.paper_labels) <= set(self.paper):
                raise ProblemDefinitionError(f"{where}: paper_labels names families not in paper")
        if self.names is not None:
            self.names = list(self.names)
            if len(self.names) != F or not _distinct_names(self.names):
                raise ProblemDefinitionError(f"{where}: names must be {F} distinct non-empty strings")
        if self.degree not in (1, 2):
            raise ProblemDefinitionError(f"{where}: degree must be 1 or 2, got {self.degree!r}")
        if self.aux_names is not None:
            self.aux_names = [str(a) for a in self.aux_names]
            if self.auxiliary is None or len(self.aux_names) != F or len(set(self.aux_names)) != F:
                raise ProblemDefinitionError(f"{where}: aux_names must be {F} distinct suffixes of a family with "
                                             "auxiliary blocks")
        if self.roles is not None:
            self.roles = tuple(self.roles)
            if not _distinct_names(self.roles):
                raise ProblemDefinitionError(f"{where}: roles must be distinct non-empty strings, got {self.roles}")

    @property
    def size(self) -> int:
        """F, the number of factors."""
        return len(self.data)


@dataclass
class Group:
    """A model factor with neither a cost nor constraints: a learning group for discovery, on blocks of the lifted
    vector (variables' or factors' auxiliary blocks, by their names in it), e.g. two landmarks' substitution
    blocks, whose relations no declared factor holds together.

    ``blocks``: the block names after h (the model factor's blocks are h, then these); ``type``: its factor type;
    ``roles``: their roles (default the block names; h's role is "h"); ``data``: its ``Factor.data``;
    ``name``: its model factor's name (default ``type_i``, i its position among the declared factors).  Model
    factors of one type list corresponding blocks in the same order.
    """

    blocks: Sequence[str]
    type: str
    roles: Sequence[str] | None = None
    data: np.ndarray | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        self.blocks = (self.blocks,) if isinstance(self.blocks, str) else tuple(self.blocks)
        where = f"group on {self.blocks}"
        if not isinstance(self.type, str) or not self.type:
            raise ProblemDefinitionError(f"{where}: type must be a non-empty string, got {self.type!r}")
        if not self.blocks or not _distinct_names(self.blocks, "h"):
            raise ProblemDefinitionError(f"{where}: blocks must be distinct block names other than 'h'")
        self.roles = self.blocks if self.roles is None else tuple(self.roles)
        if len(self.roles) != len(self.blocks) or not _distinct_names(self.roles, "h"):
            raise ProblemDefinitionError(f"{where}: roles must be {len(self.blocks)} distinct non-empty strings "
                                         f"other than 'h', got {self.roles}")
        if self.data is not None:
            self.data = np.asarray(self.data, dtype=float).ravel()
        if self.name is not None and (not isinstance(self.name, str) or not self.name):
            raise ProblemDefinitionError(f"{where}: name must be a non-empty string")
