"""What a factor-graph problem declares: its variables (manifold and lifting) and its factors.

``Variable(name, manifold, lifting={block: fn}, type=None, block=None)``: a state entry ``name`` on
``manifold`` (``autotight.graph.manifolds``).  The truth's entry fixes how many there are: an array of the
manifold's shape is one variable, a stack (N, *shape) is N of them (block names ``name0 … name{N−1}``;
``block`` renames the main block).  The lifted vector holds, per variable, its embedding (the main block)
and one block per ``lifting`` entry, ``fn(x) -> (E,)``, which must be a polynomial of degree ≤ 2 in the
embedding's entries (e.g. vech(p pᵀ)); its primary constraints fn(x) − h·z = 0 are derived from it
(``LiftingFit``).  ``type`` names the factor type of the variable's own model factor (default: ``name``):
variables of one type share it, element by element (e.g. a pose's rotation and translation; ``assemble``).

``Factor(variables, residual, …)``: a term eᵀWe of the cost, on one or more variables named by their
main block or by name and index (``"p0"``, or ``"C"`` for a single variable).  ``residual(*views) ->
(m,)`` gets one ``View`` per variable: ``view.x`` its value (an array of the manifold's shape) and
``view.<block>`` each lifting block.  When the residual is affine in the views' entries (constants
standing for h), the lifted cost is derived; otherwise give it (``cost``: the (n, n) symmetric matrix on
the factor's local columns [h, the variables' blocks in order]).  ``jacobian(*views) -> (m, Σ dof)`` is
optional (the chain rule through the lifting when the residual is affine, central finite differences on
the retraction otherwise).  ``constraints``: extra primary constraints [(name, (n, n) matrix)] on the same
local columns (value 0); ``data``: the factor's measurement vector (``autotight.model.Factor.data``);
``type``: its factor type.
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

View = SimpleNamespace


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
        for e in range(self.size):
            M = np.zeros((n, n))
            M[0, offset + e] = M[offset + e, 0] = -0.5
            M[0, 0] = self.c0[e]
            M[0, 1:1 + p] += 0.5 * self.G[e]
            M[1:1 + p, 0] += 0.5 * self.G[e]
            M[1:1 + p, 1:1 + p] += self.S[e]
            out.append(M)
        return out


def fit_lifting(name: str, fn: Callable[[np.ndarray], Any], manifold: Manifold, where: str) -> LiftingFit:
    """The polynomial of degree ≤ 2 that ``fn`` (of the manifold's ambient value) is in the embedding's entries,
    from exact differences at ``factor_batch.probe_points`` and checked at a random point."""
    p = manifold.size

    def call(v: np.ndarray) -> np.ndarray:
        z = np.asarray(fn(manifold.unembed(v)), dtype=float)
        if z.ndim > 1 or not z.size:
            raise ProblemDefinitionError(f"{where}: lifting block {name!r} must return a non-empty vector, "
                                         f"got shape {z.shape}")
        return z.reshape(-1)

    probes = probe_points(p, 2)
    values = np.array([call(v) for v in probes])
    coef = coefficients(values, p, 2)
    c0, lin, sq, cross = coef[0], coef[1:p + 1], coef[p + 1:2 * p + 1], coef[2 * p + 1:]
    E = values.shape[1]
    S = np.zeros((E, p, p))
    S[:, np.arange(p), np.arange(p)] = sq.T
    i, j = np.triu_indices(p, 1)
    S[:, i, j] = S[:, j, i] = 0.5 * cross.T
    fit = LiftingFit(name, fn, c0, lin.T.copy(), S)
    v = np.random.default_rng(0).standard_normal(p)
    want = call(v)
    got = features(v[None], 2)[0] @ coef
    if np.abs(got - want).max() > LIFTING_RTOL * max(1.0, float(np.abs(want).max())):
        raise ProblemDefinitionError(f"{where}: lifting block {name!r} is not a polynomial of degree ≤ 2 in the "
                                     "variable's entries")
    return fit


@dataclass
class Variable:
    """A state entry on a manifold, with its lifting blocks (see the module docstring)."""

    name: str
    manifold: Manifold
    lifting: Mapping[str, Callable[[np.ndarray], Any]] = field(default_factory=dict)
    #: the factor type of the variable's own model factor (default: its name)
    type: str | None = None
    #: the name of its main block (default: its name)
    block: str | None = None

    def __post_init__(self) -> None:
        for what, v in (("name", self.name), ("block", self.block if self.block is not None else "x")):
            if not isinstance(v, str) or not v.isidentifier() or v == "h":
                raise ProblemDefinitionError(f"a variable's {what} must be an identifier other than 'h', got {v!r}")
        bad = [b for b in self.lifting if not isinstance(b, str) or not b.isidentifier() or b in ("x", "h")]
        if bad:
            raise ProblemDefinitionError(f"variable {self.name!r}: lifting block names must be identifiers other "
                                         f"than 'x' and 'h', got {bad}")
        self._fits: list[LiftingFit] | None = None

    def fits(self) -> list[LiftingFit]:
        """The lifting blocks as fitted polynomials (computed once)."""
        if self._fits is None:
            where = f"variable {self.name!r}"
            self._fits = [fit_lifting(b, fn, self.manifold, where) for b, fn in self.lifting.items()]
        return self._fits

    def lifted(self, x: np.ndarray) -> np.ndarray:
        """[embed(x), lifting blocks…] (the variable's columns of the lifted vector, h excluded)."""
        parts = [self.manifold.embed(x)] + [np.asarray(f.fn(x), float).reshape(-1) for f in self.fits()]
        return np.concatenate(parts)

    def view(self, theta: np.ndarray) -> View:
        """The ``View`` of the variable's columns θ (h excluded): x = unembed(main block), then each block."""
        p = self.manifold.size
        out, o = {"x": self.manifold.unembed(theta[:p])}, p
        for f in self.fits():
            out[f.name] = theta[o:o + f.size]
            o += f.size
        return View(**out)

    def local_constraints(self) -> list[tuple[str, np.ndarray]]:
        """The manifold's and the lifting's equations on [h, main, lifting blocks…] (matrices padded to it)."""
        p = self.manifold.size
        n = 1 + p + sum(f.size for f in self.fits())
        out = []
        for name, M in self.manifold.constraints():
            out.append((name, _pad(M, n)))
        o = 1 + p
        for f in self.fits():
            for e, M in enumerate(f.constraint_matrices(p, o)):
                out.append((f"{f.name}[{e}]", _pad(M, n)))
            o += f.size
        return out


def _pad(M: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, n))
    out[:M.shape[0], :M.shape[1]] = M
    return out


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

    def __post_init__(self) -> None:
        self.variables = (self.variables,) if isinstance(self.variables, str) else tuple(self.variables)
        if not self.variables or len(set(self.variables)) != len(self.variables):
            raise ProblemDefinitionError(f"a factor needs distinct variables, got {self.variables}")
        if not callable(self.residual):
            raise ProblemDefinitionError(f"factor on {self.variables}: residual must be a function")
