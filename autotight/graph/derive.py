"""The problem contract's parts derived from a factor graph's declarations.

``derive(variables, factors)`` returns ``Parts(build, lift, cost, sample, local_solve, recover)``, each with
the signature ``autotight.problem`` expects, so a module on the factor-graph layer writes four parts,
``PARAMS``, ``generate``, ``VARIABLES`` and ``factors``, and one line::

    build, lift, cost, sample, local_solve, recover = derive(VARIABLES, factors)

- ``variables``: a list of ``Variable``, or ``variables(instance) -> list`` when they depend on the
  parameters (e.g. the dimension);
- ``factors(instance) -> iterable of Factor, Family or Group`` (``Family``: factors of one type at once;
  ``Group``: a learning group of blocks, with no cost and no constraints).

The derived parts: ``build`` (``assemble.Graph.model``); ``lift`` (h, each variable's embedding, lifting and
product blocks); ``cost`` (Σ eᵀWe of the declared residuals; the lifted cost equals it when the residuals are
affine in the lifting, so the check's ``cost`` test then checks the declarations' consistency, not an
independent formula); ``sample`` (each variable retracted from the nominal by spread·ν, ν ~ N(0, I): a
state on the manifolds, whose lifting meets every derived primary constraint; factors' own constraints must
hold for every value of their variables; drawn again, up to ``SAMPLE_TRIES`` times (``tries``), while an
auxiliary value raises ValueError, e.g. at a singularity of its map, or the module's ``keep`` refuses it);
``local_solve`` (``autotight.gauss_newton`` on the retractions, options ``max_iter``, ``rel_tol``); ``recover``
(each variable's main block, projected onto its manifold; the rotations' raw determinants as ``det_raw``,
``layout.Layout.recover``).  ``errors`` and ``random_state`` are the contract's defaults (``autotight.problem``).
"""

from __future__ import annotations

import weakref
from typing import Any, Callable, Iterable, Mapping, NamedTuple, Sequence, cast

import numpy as np

from ..errors import ParameterError, ProblemDefinitionError, SolverError
from ..gauss_newton import gauss_newton
from ..model import Model
from .assemble import Graph
from .declare import Factor, Family, Group, Variable

#: up to this many tangent directions the local solver's Jacobian is a dense array (m × n_tangent): its normal
#: equations are cheaper than sparse products (pose averaging M = 1000: 6 directions, 6000 rows)
DENSE_TANGENT = 32

#: draws of ``sample`` before it gives up on states where every auxiliary value is defined
SAMPLE_TRIES = 100


class Parts(NamedTuple):
    """The derived contract parts, in the order of ``derive``'s one-line use."""

    build: Callable[[Any], Model]
    lift: Callable[[Any, dict], np.ndarray]
    cost: Callable[[Any, dict], float]
    sample: Callable[[Any, np.random.Generator, dict, float], dict]
    local_solve: Callable[..., Any]
    recover: Callable[[Any, np.ndarray], dict]


def derive(variables: Sequence[Variable] | Callable[[Any], Sequence[Variable]],
           factors: Callable[[Any], Iterable[Factor | Family | Group]], by_element: bool = False,
           tangent: Sequence[str] | None = None, keep: Callable[[Any, dict], bool] | None = None,
           tries: int = SAMPLE_TRIES, state: Callable[[Mapping[str, Any]], Mapping[str, Any]] | None = None,
           blocks: Callable[[Any], Sequence[str]] | None = None,
           width: Callable[[Any], int | None] | None = None) -> Parts:
    """The contract's parts from the declarations (see the module docstring).  ``by_element``: the lifted vector
    and the model's factors ordered element by element (``layout.Layout``, ``assemble.Graph``): element i of
    every stacked variable before element i + 1, and each variable's own factor right before the first factor of
    its own on it (e.g. pose k's blocks and rotation factor, its measurement factor, then pose k + 1).

    The sampler's policy: ``tangent``, the variables' names in the order of the stacked tangent vector (default
    their declaration order), which orders ``sample``'s draws ν (and the local solver's steps), e.g. ("C", "t")
    draws a pose's rotation step before its translation step; ``keep(instance, state) -> bool``, the states
    ``sample`` may return (it draws again while False, e.g. a camera pose with every landmark at a least depth:
    default every state); ``tries``, the draws ``sample`` makes before it gives up (ParameterError when the last
    draw was refused by ``keep``, SolverError when an auxiliary value was undefined).

    ``state``: for a module whose states do not hold its variables by name (e.g. poses T (K, 4, 4) for variables
    C and r), the map from its state to {variable: value or stack}, applied to the instance's truth and to every
    state the parts take (``lift``, ``cost``, ``sample``'s nominal, ``local_solve``'s start); the states the
    parts return (``sample``, ``local_solve``, ``recover``) and ``keep`` sees hold the variables.

    ``blocks(instance) -> names``: the lifted vector's blocks after h in the module's order (every block once,
    e.g. a label's blocks beside the auxiliary blocks of its measurement, as a paper writes x); each declared
    ``Factor``'s model factor then lists its blocks in that order too.  Default: the variables' blocks, then
    the auxiliary blocks (``layout.Layout``).

    ``width(instance) -> d or None``: the lifting's width (``layout.Layout``): None, a vector x (d = 1); d, a
    matrix Θ = [I_d, blocks…] (d × N) with X = ΘᵀΘ, each variable's value a d × k block (k = size / d), which
    ``lift`` returns and ``recover`` takes (normalised by Θ_h⁻¹); its factors declare their lifted costs and
    constraints in the Gram form on h's d columns and their variables' columns, and the manifolds' equations are
    translated to it (``layout.gram_form``).  The derived ``local_solve`` is for vectors only (d = 1)."""
    if not callable(factors):
        raise ProblemDefinitionError("factors must be a function factors(instance) -> iterable of Factor")
    if keep is not None and not callable(keep):
        raise ProblemDefinitionError("keep must be a function keep(instance, state) -> bool")
    if blocks is not None and not callable(blocks):
        raise ProblemDefinitionError("blocks must be a function blocks(instance) -> the lifted vector's block names")
    if isinstance(tries, bool) or not isinstance(tries, int) or tries < 1:
        raise ProblemDefinitionError(f"tries must be a positive integer, got {tries!r}")
    if state is not None and not callable(state):
        raise ProblemDefinitionError("state must be a function of a state, or None")
    cache: dict[int, tuple[weakref.ref, Graph]] = {}

    def held(s: Mapping[str, Any]) -> Mapping[str, Any]:
        return s if state is None else state(s)

    def graph(inst: Any) -> Graph:
        hit = cache.get(id(inst))
        if hit is not None and hit[0]() is inst:
            return hit[1]
        declared = variables(inst) if callable(variables) else variables
        g = Graph(list(declared), held(inst.truth), factors(inst), by_element, tangent,
                  None if blocks is None else blocks(inst), None if width is None else width(inst))
        for k in [k for k, (ref, _) in cache.items() if ref() is None]:
            del cache[k]
        cache[id(inst)] = (weakref.ref(inst), g)
        return g

    def build(inst: Any) -> Model:
        return graph(inst).model()

    def lift(inst: Any, state: dict) -> np.ndarray:
        g = graph(inst)
        return g.lift(g.layout.values(held(state)))

    def cost(inst: Any, state: dict) -> float:
        g = graph(inst)
        return g.cost(g.layout.values(held(state)))

    def sample(inst: Any, rng: np.random.Generator, nominal: dict, spread: float) -> dict:
        g = graph(inst)
        L = g.layout
        start = L.values(held(nominal))
        refused = False
        for _ in range(tries):
            values = L.retract(start, spread * rng.standard_normal(L.n_tangent))
            if keep is not None and not keep(inst, L.state(values)):
                refused = True
                continue
            refused = False
            if not g.has_auxiliary:
                break
            try:
                g.lift(values)
                break
            except ValueError as e:
                undefined = e
        else:
            if refused:
                raise ParameterError(f"no sample within spread {spread:g} that {getattr(keep, '__name__', 'keep')} "
                                     f"keeps in {tries} draws; reduce the spread")
            raise SolverError(f"no sample where every auxiliary block is defined in {tries} draws (the last: "
                              f"{undefined}); reduce the spread")
        return L.state(values)

    def local_solve(inst: Any, init: dict, max_iter: int = 200, rel_tol: float = 1e-12) -> Any:
        g = graph(inst)
        if g.layout.V.d > 1:
            raise ProblemDefinitionError(f"the derived local solver is for vector liftings; this lifting has width "
                                         f"{g.layout.V.d}: the module gives local_solve")
        dense = g.layout.n_tangent <= DENSE_TANGENT and g.all_affine
        res = gauss_newton(lambda values: g.linearize(values, dense), g.layout.retract, g.layout.values(held(init)),
                           max_iter=max_iter, rel_tol=rel_tol)
        res.state = g.layout.state(cast(list, res.state))  # gauss_newton's state is the list of values
        return res

    def recover(inst: Any, Theta: np.ndarray) -> dict:
        return graph(inst).layout.recover(Theta)  # ``Layout.raw`` shapes Θ or x

    return Parts(build, lift, cost, sample, local_solve, recover)
