"""The public Python API: ``load_problem``, ``solve``, ``discover``, ``certify`` (``check_problem`` is
in ``autotight.checks``, ``check_sufficient`` in ``autotight.check``).

Each function validates its input at the boundary and returns a result with plain attributes;
the CLI, the report sweep and discovery all run through the same per-instance pipeline
(``autotight.pipeline``).  Seeds follow one scheme (``autotight.pipeline`` docstring).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from types import ModuleType
from typing import Any

import numpy as np

from .constraint_set import ConstraintsLike
from .errors import ParameterError
from .limits import check_count, check_random_starts, check_size, count_arg
from .pipeline import SolveResult, solve_instance
from .problem import Problem, load
from .sdp.config import SolverConfig
from .tightness import Criteria


def load_problem(name_or_path: str | ModuleType | Problem) -> Problem:
    """A problem by name (``autotight list``), by path to a ``.py`` module, or from a module object."""
    return load(name_or_path)


def _problem(problem: str | ModuleType | Problem) -> Problem:
    return problem if isinstance(problem, Problem) else load(problem)


def _seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def _params(params: Any) -> dict[str, Any] | None:
    """``params`` as a dict (None: the defaults); a string such as "M=3" is refused."""
    if params is None:
        return None
    if not isinstance(params, Mapping):
        raise ParameterError(f"params must be a dict {{name: value}} (e.g. {{'M': 3}}), got "
                             f"{type(params).__name__} {params!r}")
    return dict(params)


def solver_config(solver: Any) -> SolverConfig:
    """``solver``: None (the default ``SolverConfig``), a backend name ("clarabel", "ipm", "cvxpy:SCS", …) or
    a ``SolverConfig``; anything else is a ParameterError."""
    if solver is None:
        return SolverConfig()
    if isinstance(solver, str):
        return SolverConfig(backend=solver)  # an unknown or missing backend: SolverConfigError
    if isinstance(solver, SolverConfig):
        return solver
    raise ParameterError(f"solver must be a backend name or a SolverConfig, got {type(solver).__name__}")


def _criteria(criteria: Any) -> Criteria:
    if not isinstance(criteria, Criteria):
        raise ParameterError(f"criteria must be a Criteria (e.g. Criteria(accept='cost')), got "
                             f"{type(criteria).__name__}")
    return criteria


def solve(problem: str | ModuleType | Problem, params: dict[str, Any] | None = None, seed: int = 0, *,
          constraints: ConstraintsLike = None, solver: Any = None, criteria: Criteria = Criteria(),
          n_random: int = 1) -> SolveResult:
    """Generate the instance ``(params, seed)``, solve its SDP with ``constraints`` and judge tightness.

    constraints: "paper" (the default when the problem has paper families), "primary", a
    ``ConstraintSet`` (e.g. ``ConstraintSet.load(path)``, applied to this instance whatever its size)
    or a list of ``Constraint``.  solver: a ``SolverConfig``.  n_random: random-start local solves.
    """
    prob = _problem(problem)
    config, criteria = solver_config(solver), _criteria(criteria)
    full = prob.parse_params(_params(params))
    check_size(prob, full, config)
    n_random = check_random_starts(prob, full, n_random)
    inst = prob.generate(full, _seed(seed))
    return solve_instance(prob, inst, constraints, config=config, criteria=criteria, n_random=n_random)


def discover(problem: str | ModuleType | Problem, params: dict[str, Any] | None = None, seed: int = 0, *,
             solver: Any = None, **options: Any):
    """Learn a constraint set on ``problem`` at ``params`` (over every point of ``over=…``) and validate it on
    fresh held-out instances, taking every failing one in, until a held-out batch passes.

    Returns a ``DiscoveryResult`` (``autotight.discovery.result``; fields in docs/discovery.md): its
    ``constraint_set`` is what ``solve(constraints=…)`` takes, ``save(path)`` writes it, ``validated`` says
    whether a fresh held-out batch passed.  ``options`` are those of ``autotight.discovery.engine.discover``
    (over, n_train, n_heldout, min_fraction, max_rounds, max_solves, carry_to, groups, learn_options,
    criteria, n_random, compare, jobs, scheduler, progress).  solver: a ``SolverConfig`` (None: Clarabel, or
    the backend a problem's ``META.carry_to`` hint names).
    """
    from .discovery.engine import discover as _discover

    prob = _problem(problem)
    params = _params(params)
    solver = None if solver is None else solver_config(solver)
    known = set(inspect.signature(_discover).parameters) - {"problem", "params", "seed", "solver"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ParameterError(f"discover: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    if "criteria" in options:
        _criteria(options["criteria"])
    full = prob.parse_params(params)
    check_size(prob, full, solver)
    for name, per in (("n_heldout", 3), ("n_train", 3)):
        if options.get(name) is not None:
            options[name] = count_arg(options[name], name)
            check_count(prob, full, f"{name} {options[name]}", options[name], per_item=per, what="instances")
    if "n_random" in options:
        options["n_random"] = count_arg(options["n_random"], "n_random")
    return _discover(prob, params, _seed(seed), solver=solver, **options)


def certify(problem: str | ModuleType | Problem, params: dict[str, Any] | None = None, seed: int = 0, *,
            constraints: ConstraintsLike = None, start: Any = "truth", solver: Any = None):
    """Certify a local solution of the instance ``(params, seed)`` without solving the full SDP.

    Runs the local solver from ``start`` ("truth"; "random": the first random start of ``solve``; or a
    state dict), lifts its solution and looks for dual multipliers that prove it globally optimal for
    the relaxation with ``constraints`` (as in ``solve``; method: ``autotight.certify``).  Returns a
    ``Certificate`` (``certified``, ``bound``, ``rel_bound``, ``time_s``, …), decided with the same
    relative gap as the full SDP's verdict.  solver: None, or a ``SolverConfig`` whose ``max_iter``
    caps the Newton steps of the certificate's barrier method (no SDP is solved).
    """
    from .certifier import certify_instance
    from .limits import check_certify_size
    from .validate import check_data

    prob = _problem(problem)
    full = prob.parse_params(_params(params))
    check_certify_size(prob, full)
    solver = None if solver is None else solver_config(solver)
    inst = prob.generate(full, _seed(seed))
    model = prob.build(inst)
    check_data(prob, inst, model)  # NaN/inf data, weights beyond the solver's reach
    max_iter = 50 if solver is None else int(getattr(solver, "max_iter", 50))
    return certify_instance(prob, inst, constraints, start=start, max_iter=max_iter, model=model).certificate
