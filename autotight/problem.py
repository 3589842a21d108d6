"""Problem modules: what they must define, how they are found, and their parameters.

A problem module (``problems/<name>.py`` or any ``.py`` file) defines:

- ``NAME``, ``DESCRIPTION``: strings;
- ``PARAMS``: ``dict[str, Param]`` of size and noise parameters;
- ``generate(params, rng) -> Instance``: measurements and ground truth;
- ``build(instance) -> Model``: variables, factors (cost + primary constraints), paper families;
- ``lift(instance, state) -> Θ``: (N,) or (d, N);
- ``sample(instance, rng, nominal, spread) -> state``: a feasible state near ``nominal``;
- ``cost(instance, state) -> float``: the original (unlifted) cost;
- ``local_solve(instance, init) -> LocalResult``;
- ``recover(instance, Theta) -> state``: a state from a rank-d factor of the SDP solution;
- ``random_state(instance, rng) -> state``: a random start for the local solver;
- ``errors(instance, state) -> dict[str, float]``: estimation errors against ``instance.truth``.

A state is a ``dict[str, np.ndarray]`` in the problem's own terms (for example ``{"C": …}``).
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import pkgutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from .errors import ParameterError, ProblemDefinitionError
from .model import Model

State = dict[str, np.ndarray]

REQUIRED = ("NAME", "DESCRIPTION", "PARAMS", "generate", "build", "lift", "sample", "cost",
            "local_solve", "recover", "random_state", "errors")


@dataclass(frozen=True)
class Param:
    """A problem parameter: default value (its type is the parameter's type) and bounds."""

    default: Any
    help: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[Any, ...] | None = None

    def parse(self, name: str, value: Any) -> Any:
        kind = type(self.default)
        try:
            if isinstance(value, str) and kind is bool:
                if value.lower() not in ("1", "0", "true", "false", "yes", "no"):
                    raise ValueError
                v: Any = value.lower() in ("1", "true", "yes")
            elif isinstance(value, str) and kind is tuple:
                v = tuple(float(s) for s in value.split(",") if s.strip())
            elif kind is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            else:
                v = kind(value)
        except (TypeError, ValueError):
            raise ParameterError(f"parameter {name}={value!r}: expected {kind.__name__}") from None
        if kind in (int, float):
            if not math.isfinite(v):
                raise ParameterError(f"parameter {name}={value!r}: must be finite")
            if self.low is not None and (v < self.low or (self.low_open and v == self.low)):
                raise ParameterError(f"parameter {name}={v}: must be {'>' if self.low_open else '≥'} {self.low}")
            if self.high is not None and v > self.high:
                raise ParameterError(f"parameter {name}={v}: must be ≤ {self.high}")
        if self.choices is not None and v not in self.choices:
            raise ParameterError(f"parameter {name}={v!r}: must be one of {list(self.choices)}")
        return v


@dataclass
class Instance:
    """One problem instance: parameters, measurements and ground truth (all JSON-able arrays)."""

    problem: str
    params: dict[str, Any]
    measurements: dict[str, Any]
    truth: State
    seed: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class LocalResult:
    """Outcome of a local solve: the state, its cost, and how the solver ended."""

    state: State
    cost: float
    iterations: int
    converged: bool
    time_s: float = 0.0
    message: str = ""


class Problem:
    """A validated problem module; call its parts as methods."""

    def __init__(self, module: ModuleType):
        missing = [p for p in REQUIRED if not hasattr(module, p)]
        if missing:
            raise ProblemDefinitionError(
                f"problem module {module.__name__!r} lacks required part(s): {', '.join(missing)}")
        for p in REQUIRED[3:]:
            if not callable(getattr(module, p)):
                raise ProblemDefinitionError(f"problem module {module.__name__!r}: {p} must be a function")
        if not isinstance(module.PARAMS, dict) or not all(isinstance(v, Param) for v in module.PARAMS.values()):
            raise ProblemDefinitionError(f"problem module {module.__name__!r}: PARAMS must be a dict of Param")
        self.module = module
        self.name: str = module.NAME
        self.description: str = module.DESCRIPTION
        self.params: dict[str, Param] = dict(module.PARAMS)

    def __repr__(self) -> str:
        return f"Problem({self.name!r})"

    def parse_params(self, given: dict[str, Any] | None = None) -> dict[str, Any]:
        """Defaults overridden by ``given``, each validated; unknown names are refused."""
        given = dict(given or {})
        unknown = [k for k in given if k not in self.params]
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {unknown} for {self.name}; known: {', '.join(self.params)}")
        return {k: p.parse(k, given.get(k, p.default)) for k, p in self.params.items()}

    def generate(self, params: dict[str, Any] | None = None, seed: int | np.random.Generator = 0) -> Instance:
        """A fresh instance.  ``seed`` is an int (recorded) or a Generator."""
        full = self.parse_params(params)
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        inst = self.module.generate(full, rng)
        inst.seed = None if isinstance(seed, np.random.Generator) else int(seed)
        return inst

    def build(self, instance: Instance) -> Model:
        model = self.module.build(instance)
        if not isinstance(model, Model):
            raise ProblemDefinitionError(f"{self.name}.build must return a Model, got {type(model).__name__}")
        return model

    def lift(self, instance: Instance, state: State) -> np.ndarray:
        return np.asarray(self.module.lift(instance, state), dtype=float)

    def sample(self, instance: Instance, rng: np.random.Generator, nominal: State | None = None,
               spread: float = 0.5) -> State:
        return self.module.sample(instance, rng, instance.truth if nominal is None else nominal, spread)

    def cost(self, instance: Instance, state: State) -> float:
        return float(self.module.cost(instance, state))

    def local_solve(self, instance: Instance, init: State, **options: Any) -> LocalResult:
        return self.module.local_solve(instance, init, **options)

    def recover(self, instance: Instance, Theta: np.ndarray) -> State:
        return self.module.recover(instance, Theta)

    def random_state(self, instance: Instance, rng: np.random.Generator) -> State:
        return self.module.random_state(instance, rng)

    def errors(self, instance: Instance, state: State) -> dict[str, float]:
        return {k: float(v) for k, v in self.module.errors(instance, state).items()}


def available() -> list[str]:
    """Names of the modules in the ``problems`` package."""
    import problems

    return sorted(m.name for m in pkgutil.iter_modules(problems.__path__) if not m.name.startswith("_"))


def load(name_or_path: str | ModuleType) -> Problem:
    """A problem by name (``problems.<name>``), by ``.py`` path, or from a module object."""
    if isinstance(name_or_path, ModuleType):
        return Problem(name_or_path)
    if isinstance(name_or_path, Problem):
        return name_or_path
    s = str(name_or_path)
    if s.endswith(".py") or "/" in s:
        path = Path(s)
        if not path.is_file():
            raise ProblemDefinitionError(f"no problem file {s}")
        mod_name = f"autotight_user_problem_{path.stem}"
        spec = importlib.util.spec_from_file_location(mod_name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except Exception as e:  # report, do not crash with a traceback
            raise ProblemDefinitionError(f"cannot import problem file {s}: {type(e).__name__}: {e}") from e
        return Problem(module)
    known = available()
    if s not in known:
        raise ProblemDefinitionError(f"unknown problem {s!r}; known problems: {', '.join(known)}")
    return Problem(importlib.import_module(f"problems.{s}"))


def parse_assignments(items: list[str] | None) -> dict[str, str]:
    """["M=10", "sigma=0.1"] → {"M": "10", "sigma": "0.1"}."""
    out: dict[str, str] = {}
    for it in items or []:
        if "=" not in it:
            raise ParameterError(f"parameter {it!r} is not NAME=VALUE")
        k, v = it.split("=", 1)
        out[k.strip()] = v.strip()
    return out

