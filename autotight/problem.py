"""Problem modules: the contract, how modules are found, and the checked boundary into their code.

The full contract, with shapes, tolerances and an example, is in ``docs/problem_contract.md``;
``autotight check-module PATH`` (``autotight.checks.check_problem``) verifies a module against it.

A problem module (``problems/<name>.py`` or any ``.py`` file) **must** define

- ``PARAMS: dict[str, Param]``: size and noise parameters (may be empty);
- ``generate(params, rng) -> Instance``: measurements and ground truth ``truth`` (a state);
- ``build(instance) -> Model``: variables, factors (cost + primary constraints, ``roles``), paper families;
- ``lift(instance, state) -> Θ``: (N,) for d = 1 or (d, N), blocks in the order of build's ``Variables``;
- ``sample(instance, rng, nominal, spread) -> state``: a feasible state near ``nominal``: its lifting
  satisfies every primary constraint to 1e-8 relative (``discovery.samples.relative_violation``);
- ``local_solve(instance, init, **options) -> LocalResult``: a local minimiser from ``init``;
- ``recover(instance, Θ) -> state``: a state from the (d, N) factor of the SDP solution (h block = I_d).

and **may** define (the default is used otherwise)

- ``NAME`` (the file name), ``DESCRIPTION`` (the docstring's first line);
- ``cost(instance, state) -> float``: the original cost.  Default ⟨Q, ΘᵀΘ⟩ + ``cost_offset`` from
  build's model; write it anyway: an independent ``cost`` is what lets the check catch a wrong ``lift``;
- ``random_state(instance, rng) -> state``: default ``sample(instance, rng, truth, META.random_spread)``;
- ``errors(instance, state) -> dict[str, float]``: default ``default_errors`` (rotation-like entries →
  angle in degrees, poses → angle and translation, other arrays → RMS norm of the difference);
- ``marginal_log_svr(instance, X, cliques) -> float``: log SVR of the module's own reduced X (reported beside
  the plain log SVR);
- ``META = Meta(...)``: the tools' policy for the problem, apart from its mathematics (``autotight.meta``):
  report's noise levels, the paper's claim, discovery's groups and carry hint, check-module's parameters,
  the sampling spreads; ``autotight.module_parts`` validates each field where it is read;
- ``TRANSPORTS: dict[str, Callable]``: per factor type, ``transport(data) -> M`` (n × n, n the factor's
  local columns, h first): a factor's columns θ satisfy the relations of measurement ``data`` exactly
  when Mθ satisfies those of the reference measurement (``autotight.discovery.transport``);
- ``DATA_NAMES: dict[str, Sequence[str]]``: per factor type, the names of its ``Factor.data`` entries
  (printed closed forms, ``autotight.closed_form``; default δ1, δ2, …).

A module on the factor-graph layer (``autotight.graph``, ``docs/factor_graph.md``) writes ``PARAMS``,
``generate``, ``VARIABLES`` and ``factors`` and derives the other required parts with one call.  Modules are
found by name among the entry points of group ``autotight.problems`` (the shipped ones are autotight's own,
``available``; other packages add theirs, ``registered``), or by path.

A state is a ``dict[str, np.ndarray]`` in the problem's own terms.  h² = 1 (d = 1) or Θ_hh = I_d
is added to the primary constraints for you (``Model.homogenisation``); ``lift`` fills h in when it
uses ``Variables.assemble``.  ``sample`` stays required: the local solver's manifold is not part of
the contract, so no retraction can be derived in general; ``perturb_state`` is one for states made
of independent rotations, poses and free vectors.

Every call into module code goes through ``Problem``: an exception raised there, or a result of the
wrong type or shape, becomes ``ProblemModuleError`` naming the module, the part and the exception,
raised ``from`` the original.  autotight's own errors (``AutotightError``) pass through unchanged.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import math
import sys
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

import numpy as np

from .errors import AutotightError, ParameterError, ProblemDefinitionError, ProblemModuleError
from .lie import rotation_error_deg
from .meta import LOOSE_NAMES, Meta
from .model import Model, Variables

State = dict[str, np.ndarray]

#: Parts every module must define.
REQUIRED = ("PARAMS", "generate", "build", "lift", "sample", "local_solve", "recover")
#: Parts with a default (``Problem`` derives them when absent).
OPTIONAL = ("NAME", "DESCRIPTION", "cost", "random_state", "errors", "marginal_log_svr", "META", "TRANSPORTS",
            "DATA_NAMES")
FUNCTIONS = ("generate", "build", "lift", "sample", "cost", "local_solve", "recover", "random_state", "errors",
             "marginal_log_svr")
#: Relative tolerance on the primary constraints at sampled states (see ``relative_violation``).
SAMPLE_TOL = 1e-8
#: The entry-point group an installed package registers problems under: ``name = "pkg.module"``.
ENTRY_POINT_GROUP = "autotight.problems"


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
            elif isinstance(value, str) and kind is tuple:  # "1,2,3"; as a record prints it, "[1, 2]" or "()"
                v = tuple(float(s) for s in value.strip().strip("[]()").split(",") if s.strip())
            elif kind is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            elif kind in (int, float) and isinstance(value, (bool, np.bool_)):
                raise ValueError  # True is not the number 1 here
            else:
                v = kind(value)
        except (TypeError, ValueError):
            raise ParameterError(f"parameter {name}={value!r}: expected {kind.__name__}") from None
        if kind is tuple and not all(math.isfinite(x) for x in v if isinstance(x, (int, float))):
            raise ParameterError(f"parameter {name}={value!r}: entries must be finite")
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


def _first_line(e: BaseException) -> str:
    s = str(e).strip()
    return s.splitlines()[0] if s else ""


def _kind(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return f"an array of shape {v.shape}"
    return type(v).__name__


class Problem:
    """A validated problem module; call its parts as methods (each call is checked, see module doc)."""

    def __init__(self, module: ModuleType):
        label = getattr(module, "NAME", module.__name__)
        missing = [p for p in REQUIRED if not hasattr(module, p)]
        if missing:
            raise ProblemDefinitionError(
                f"problem module {label!r} lacks required part(s): {', '.join(missing)}")
        for p in FUNCTIONS:
            if hasattr(module, p) and not callable(getattr(module, p)):
                raise ProblemDefinitionError(f"problem module {label!r}: {p} must be a function")
        if not isinstance(module.PARAMS, dict) or not all(isinstance(v, Param) for v in module.PARAMS.values()):
            raise ProblemDefinitionError(f"problem module {label!r}: PARAMS must be a dict of Param")
        self.module = module
        self.path: str | None = getattr(module, "__file__", None)
        stem = Path(self.path).stem if self.path else module.__name__.rsplit(".", 1)[-1]
        self.name: str = str(getattr(module, "NAME", stem))
        doc = (module.__doc__ or "").strip()
        self.description: str = str(getattr(module, "DESCRIPTION", doc.splitlines()[0] if doc else ""))
        self.params: dict[str, Param] = dict(module.PARAMS)
        loose = [n for n in LOOSE_NAMES if hasattr(module, n)]
        if loose:
            hint = ", ".join(f"{LOOSE_NAMES[n]}=…" for n in loose)
            raise ProblemDefinitionError(f"{self.where()}: {', '.join(loose)} is tool policy: declare it as "
                                         f"META = Meta({hint}) (from autotight.problem import Meta)")
        meta = getattr(module, "META", Meta())
        if not isinstance(meta, Meta):
            raise ProblemDefinitionError(f"{self.where()}: META must be a Meta (from autotight.problem import Meta), "
                                         f"got {_kind(meta)}")
        #: the tools' policy for this problem (``autotight.meta``)
        self.meta: Meta = meta
        self.spread = self._positive("spread", meta.spread)
        self.random_spread = self._positive("random_spread", meta.random_spread)
        #: parts this module leaves to the defaults
        self.derived: tuple[str, ...] = tuple(p for p in ("cost", "random_state", "errors") if not hasattr(module, p))
        self._models: dict[int, tuple[weakref.ref, Model]] = {}

    def __repr__(self) -> str:
        return f"Problem({self.name!r})"

    def _positive(self, field: str, v: Any) -> float:
        if isinstance(v, bool) or not isinstance(v, Real) or not math.isfinite(v) or v <= 0:
            raise ProblemDefinitionError(f"{self.where()}: META.{field} must be a positive number, got {v!r}")
        return float(v)

    # ------------------------------------------------------------------ the boundary into module code
    def where(self) -> str:
        """'problem module 'x' (path)', the prefix of every message about this module."""
        return f"problem module {self.name!r}" + (f" ({self.path})" if self.path else "")

    def fail(self, part: str, what: str) -> ProblemModuleError:
        return ProblemModuleError(f"{self.where()}: {part} {what}")

    def call(self, part: str, *args: Any, **kwargs: Any) -> Any:
        """Call the module's ``part``; a non-autotight exception becomes ProblemModuleError (from it)."""
        fn: Callable = getattr(self.module, part)
        try:
            return fn(*args, **kwargs)
        except AutotightError:
            raise
        except Exception as e:
            msg = _first_line(e)
            raise self.fail(part, f"raised {type(e).__name__}" + (f": {msg}" if msg else "")) from e

    def _state(self, part: str, v: Any) -> State:
        if not isinstance(v, Mapping):
            raise self.fail(part, f"returned {_kind(v)}, expected a state (dict of arrays)")
        return v  # type: ignore[return-value]

    def _float(self, part: str, v: Any) -> float:
        if isinstance(v, np.ndarray) and v.size == 1:
            v = v.reshape(()).item()
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (Real, np.number)):
            raise self.fail(part, f"returned {_kind(v)}, expected a float")
        return float(v)

    def transport_types(self) -> tuple[str, ...]:
        """The factor types with a declared ``TRANSPORTS`` entry."""
        ts = getattr(self.module, "TRANSPORTS", {})
        if not isinstance(ts, Mapping) or not all(callable(f) for f in ts.values()):
            raise ProblemDefinitionError(f"{self.where()}: TRANSPORTS must be a dict of functions")
        return tuple(sorted(ts))

    def transport(self, factor_type: str, data: np.ndarray, n: int) -> np.ndarray:
        """The module's ``TRANSPORTS[factor_type](data)``, checked: a finite (n, n) array."""
        if factor_type not in self.transport_types():
            raise self.fail("TRANSPORTS", f"has no entry for factor type {factor_type!r}")
        part = f"TRANSPORTS[{factor_type!r}]"
        try:
            M = np.asarray(self.module.TRANSPORTS[factor_type](np.asarray(data, dtype=float)), dtype=float)
        except AutotightError:
            raise
        except Exception as e:
            msg = _first_line(e)
            raise self.fail(part, f"raised {type(e).__name__}" + (f": {msg}" if msg else "")) from e
        if M.shape != (n, n) or not np.all(np.isfinite(M)):
            raise self.fail(part, f"returned {_kind(M)}" + ("" if M.shape != (n, n) else " with non-finite entries")
                            + f", expected a finite ({n}, {n}) array")
        return M

    def _model(self, instance: Instance) -> Model | None:
        hit = self._models.get(id(instance))
        return hit[1] if hit is not None and hit[0]() is instance else None

    # ------------------------------------------------------------------ the parts
    def parse_params(self, given: dict[str, Any] | None = None) -> dict[str, Any]:
        """Defaults overridden by ``given``, each validated; unknown names are refused."""
        if given is not None and not isinstance(given, Mapping):
            raise ParameterError(f"parameters must be a dict {{name: value}}, got {_kind(given)} {given!r}")
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
        inst = self.call("generate", full, rng)
        if not isinstance(inst, Instance):
            raise self.fail("generate", f"returned {_kind(inst)}, expected autotight.problem.Instance")
        if not isinstance(inst.truth, Mapping):
            raise self.fail("generate", f"returned an Instance whose truth is {_kind(inst.truth)}, expected a state")
        inst.seed = None if isinstance(seed, np.random.Generator) else int(seed)
        return inst

    def build(self, instance: Instance) -> Model:
        model = self.call("build", instance)
        if not isinstance(model, Model):
            raise self.fail("build", f"returned {_kind(model)}, expected autotight.model.Model")
        self._models = {k: v for k, v in self._models.items() if v[0]() is not None}
        self._models[id(instance)] = (weakref.ref(instance), model)
        return model

    def variables(self, instance: Instance) -> Variables | None:
        """build's Variables for this instance if it was built already (else None)."""
        m = self._model(instance)
        return None if m is None else m.variables

    def lift(self, instance: Instance, state: State) -> np.ndarray:
        """Θ as the module returns it: (N,) or (1, N) for d = 1, (d, N) for d > 1 (checked against build)."""
        raw = self.call("lift", instance, state)
        try:
            T = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):
            raise self.fail("lift", f"returned {_kind(raw)}, expected an array (N,) or (d, N)") from None
        if T.ndim not in (1, 2):
            raise self.fail("lift", f"returned an array of shape {T.shape}, expected (N,) or (d, N)")
        V = self.variables(instance)
        if V is not None:
            ok = T.shape == (V.d, V.N) or (V.d == 1 and T.shape == (V.N,))
            if not ok:
                want = f"({V.N},) or (1, {V.N})" if V.d == 1 else f"({V.d}, {V.N})"
                raise self.fail("lift", f"returned an array of shape {T.shape}, expected {want} "
                                        f"(build's Variables: d = {V.d}, N = {V.N})")
        return T

    def sample(self, instance: Instance, rng: np.random.Generator, nominal: State | None = None,
               spread: float | None = None) -> State:
        """A feasible state near ``nominal`` (default the truth) with ``spread`` (default ``META.spread``)."""
        s = self.spread if spread is None else float(spread)
        return self._state("sample", self.call("sample", instance, rng,
                                               instance.truth if nominal is None else nominal, s))

    def cost(self, instance: Instance, state: State) -> float:
        """The module's cost, else ⟨Q, ΘᵀΘ⟩ + cost_offset of build's model."""
        if "cost" in self.derived:
            return self.lifted_cost(instance, state)
        return self._float("cost", self.call("cost", instance, state))

    def lifted_cost(self, instance: Instance, state: State, model: Model | None = None) -> float:
        """⟨Q, ΘᵀΘ⟩ + cost_offset at Θ = lift(state)."""
        model = model or self._model(instance) or self.build(instance)
        T = np.atleast_2d(self.lift(instance, state))
        return float(np.einsum("dn,dn->", T, (model.Q @ T.T).T)) + float(model.cost_offset)

    def local_solve(self, instance: Instance, init: State, **options: Any) -> LocalResult:
        res = self.call("local_solve", instance, init, **options)
        if not isinstance(res, LocalResult):
            raise self.fail("local_solve", f"returned {_kind(res)}, expected autotight.problem.LocalResult")
        self._state("local_solve", res.state)
        res.cost = self._float("local_solve", res.cost)
        return res

    def recover(self, instance: Instance, Theta: np.ndarray) -> State:
        """A state from Θ, passed to the module as a (d, N) array whose h block is I_d."""
        T = np.asarray(Theta, dtype=float)
        return self._state("recover", self.call("recover", instance, T[None, :] if T.ndim == 1 else T))

    def random_state(self, instance: Instance, rng: np.random.Generator) -> State:
        """The module's random start, else ``sample(instance, rng, truth, META.random_spread)``."""
        if "random_state" in self.derived:
            return self.sample(instance, rng, instance.truth, self.random_spread)
        return self._state("random_state", self.call("random_state", instance, rng))

    def errors(self, instance: Instance, state: State) -> dict[str, float]:
        """The module's errors, else ``default_errors(state, truth)``."""
        if "errors" in self.derived:
            return default_errors(state, instance.truth)
        out = self.call("errors", instance, state)
        if not isinstance(out, Mapping):
            raise self.fail("errors", f"returned {_kind(out)}, expected dict[str, float]")
        values = {}
        for k, v in out.items():
            try:
                values[str(k)] = self._float("errors", v)
            except ProblemModuleError:
                raise self.fail("errors", f"returned {_kind(v)} for {k!r}, expected dict[str, float]") from None
        return values

    def marginal_log_svr(self, instance: Instance, X: Any, cliques: Any = None) -> float:
        """The module's optional ``marginal_log_svr(instance, X, cliques)``: log SVR of its own reduced X."""
        return self._float("marginal_log_svr", self.call("marginal_log_svr", instance, X, cliques))


# ----------------------------------------------------------------------------- defaults for states


def _rotations(a: np.ndarray, tol: float = 1e-6) -> bool:
    """A (…, k, k) stack of rotations, k ∈ {2, 3}."""
    if a.ndim < 2 or a.shape[-1] != a.shape[-2] or a.shape[-1] not in (2, 3):
        return False
    M = a.reshape(-1, a.shape[-1], a.shape[-1])
    return bool(np.allclose(np.einsum("sji,sjk->sik", M, M), np.eye(M.shape[-1]), atol=tol)
                and np.all(np.linalg.det(M) > 0))


def _poses(a: np.ndarray) -> bool:
    """A (…, k+1, k+1) stack of homogeneous poses [[C, r], [0, 1]], k ∈ {2, 3}."""
    if a.ndim < 2 or a.shape[-1] != a.shape[-2] or a.shape[-1] not in (3, 4):
        return False
    k = a.shape[-1] - 1
    last = np.zeros(k + 1)
    last[-1] = 1.0
    return bool(np.allclose(a[..., k, :], last) and _rotations(a[..., :k, :k]))


def _rms(diff: np.ndarray) -> float:
    """RMS over the leading axis of the norm over the rest; the plain norm for a vector or scalar."""
    if diff.ndim <= 1:
        return float(np.linalg.norm(diff))
    return float(np.sqrt(np.mean(np.sum(diff.reshape(diff.shape[0], -1) ** 2, axis=1))))


def default_errors(state: State, truth: State) -> dict[str, float]:
    """Errors of ``state`` against ``truth``, one per numeric entry of the truth also in the state.

    Rotation stacks (…, k, k): ``<key>_deg``, the largest angle of C Ctrueᵀ (degrees).  Pose stacks
    (…, k+1, k+1): ``<key>_rotation_deg`` and ``<key>_translation`` (RMS).  Other arrays:
    ``<key>_err``, the RMS over the leading axis of the norm of the difference.
    """
    out: dict[str, float] = {}
    for key, t in truth.items():
        if key not in state:
            continue
        try:
            t, s = np.asarray(t, dtype=float), np.asarray(state[key], dtype=float)
        except (TypeError, ValueError):
            continue
        if s.shape != t.shape:
            continue
        if _rotations(t):
            out[f"{key}_deg"] = rotation_error_deg(s, t)
        elif _poses(t):
            k = t.shape[-1] - 1
            S, Tt = s.reshape(-1, k + 1, k + 1), t.reshape(-1, k + 1, k + 1)
            out[f"{key}_rotation_deg"] = rotation_error_deg(S[:, :k, :k], Tt[:, :k, :k])
            out[f"{key}_translation"] = _rms(S[:, :k, k] - Tt[:, :k, k])
        else:
            out[f"{key}_err"] = _rms(s - t)
    return out


def _exp(v: np.ndarray, k: int) -> np.ndarray:
    if k == 2:
        c, s = np.cos(v[0]), np.sin(v[0])
        return np.array([[c, -s], [s, c]])
    th = float(np.linalg.norm(v))
    P = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    if th < 1e-8:
        return np.eye(3) + P + 0.5 * P @ P
    return np.eye(3) + np.sin(th) / th * P + (1 - np.cos(th)) / th**2 * P @ P


def perturb_state(state: State, rng: np.random.Generator, spread: float) -> State:
    """A retraction of ``state`` by N(0, spread² I) steps, entry by entry.

    Rotations C ← exp(spread·ν^∧) C; poses: their rotation likewise and r ← r + spread·n; any other
    float array x ← x + spread·n.  A valid ``sample`` only when the state's entries are independent
    (no entry is a function of another) and ``lift`` computes every other block from them.
    """
    out: State = {}
    for key, v in state.items():
        a = np.asarray(v, dtype=float)
        if _rotations(a):
            k = a.shape[-1]
            dof = 1 if k == 2 else 3
            M = a.reshape(-1, k, k)
            out[key] = np.array([_exp(spread * rng.standard_normal(dof), k) @ C for C in M]).reshape(a.shape)
        elif _poses(a):
            k = a.shape[-1] - 1
            M = a.reshape(-1, k + 1, k + 1).copy()
            for T in M:
                T[:k, :k] = _exp(spread * rng.standard_normal(1 if k == 2 else 3), k) @ T[:k, :k]
                T[:k, k] += spread * rng.standard_normal(k)
            out[key] = M.reshape(a.shape)
        else:
            out[key] = a + spread * rng.standard_normal(a.shape)
    return out


# ----------------------------------------------------------------------------- finding modules


#: The distribution whose entry points are the shipped problems.
SHIPPED_BY = "autotight"


def _entry_points() -> tuple[dict[str, importlib.metadata.EntryPoint], dict[str, importlib.metadata.EntryPoint]]:
    """(shipped, others): the entry points of ``ENTRY_POINT_GROUP`` by name, those of this distribution and those
    of other installed packages (a name both use is the shipped one's)."""
    shipped: dict[str, importlib.metadata.EntryPoint] = {}
    others: dict[str, importlib.metadata.EntryPoint] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        (shipped if dist is not None and dist.name == SHIPPED_BY else others)[ep.name] = ep
    return shipped, {k: v for k, v in others.items() if k not in shipped}


def available() -> list[str]:
    """Names of the shipped problems (the entry points autotight itself installs)."""
    return sorted(_entry_points()[0])


def registered() -> dict[str, importlib.metadata.EntryPoint]:
    """Problems that other installed packages register under the entry-point group ``ENTRY_POINT_GROUP``, by
    name (a name also shipped is left out: the shipped module wins)."""
    return _entry_points()[1]


def _all_entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    shipped, others = _entry_points()
    return {**others, **shipped}


def registered_name(prob: Problem) -> str | None:
    """The name ``load`` finds ``prob`` by among the entry points (its module is the one an entry point names),
    else None (a module loaded from a path or built in Python)."""
    mod = getattr(prob.module, "__name__", None)
    ep = _all_entry_points().get(prob.name)
    return prob.name if ep is not None and not ep.attr and ep.module == mod else None


def _module_file(ep: importlib.metadata.EntryPoint) -> Path | None:
    """The file of the module an entry point names (``pkg.mod``, without an attribute), found without importing
    it; None when it names an attribute or has no file."""
    if ep.attr:
        return None
    try:
        spec = importlib.util.find_spec(ep.module)  # imports the parent package of a dotted name
    except Exception:  # noqa: BLE001 - a package that does not import: not this file
        return None
    return Path(spec.origin).resolve() if spec is not None and spec.origin else None


def _load_entry_point(ep: importlib.metadata.EntryPoint) -> Problem:
    """The problem an entry point names: a module (``pkg.mod``) or a module attribute (``pkg:mod``)."""
    try:
        obj = ep.load()
    except Exception as e:
        raise _import_failed(f"cannot import problem {ep.name!r} (entry point {ep.value!r})", e) from e
    if isinstance(obj, Problem):
        return obj
    if isinstance(obj, ModuleType):
        prob = Problem(obj)
        if not hasattr(obj, "NAME"):
            prob.name = ep.name  # the name it is registered and found by
        return prob
    raise ProblemDefinitionError(f"entry point {ep.name!r} = {ep.value!r} of group {ENTRY_POINT_GROUP!r} names "
                                 f"{_kind(obj)}, expected a problem module")


def _import_failed(what: str, e: Exception) -> ProblemModuleError:
    msg = _first_line(e)
    return ProblemModuleError(f"{what}: {type(e).__name__}" + (f": {msg}" if msg else ""))


def _load_file(path: Path) -> Problem:
    if not path.exists():
        raise ProblemDefinitionError(f"no problem file {path}")
    if path.is_dir():
        raise ProblemDefinitionError(f"problem path {path} is a directory, not a .py file")
    if path.suffix != ".py":
        raise ProblemDefinitionError(f"problem path {path} is not a .py file")
    for ep in _all_entry_points().values():
        if _module_file(ep) == path.resolve():
            return _load_entry_point(ep)  # a registered module: imported in its package (relative imports work)
    mod_name = f"autotight_user_problem_{path.stem}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise ProblemDefinitionError(f"cannot load problem file {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as e:
        sys.modules.pop(mod_name, None)
        hint = " (a file is loaded on its own: import its package's helpers absolutely)" \
            if isinstance(e, ImportError) and "relative import" in str(e) else ""
        raise _import_failed(f"cannot import problem file {path}{hint}", e) from e
    return Problem(module)


def load(name_or_path: str | Path | ModuleType | Problem) -> Problem:
    """A problem by name (an entry point of ``ENTRY_POINT_GROUP``; a shipped name wins), by ``.py`` path, or from a
    module object."""
    if isinstance(name_or_path, Problem):
        return name_or_path
    if isinstance(name_or_path, ModuleType):
        return Problem(name_or_path)
    s = str(name_or_path)
    if isinstance(name_or_path, Path) or s.endswith(".py") or "/" in s or "\\" in s:
        return _load_file(Path(s))
    shipped, others = _entry_points()
    ep = shipped.get(s) or others.get(s)
    if ep is None:
        if not shipped:
            raise ProblemDefinitionError(f"unknown problem {s!r}: no problems are registered under the entry-point "
                                         f"group {ENTRY_POINT_GROUP!r}; install autotight (pip install -e .)")
        raise ProblemDefinitionError(f"unknown problem {s!r}; known problems: "
                                     f"{', '.join(sorted(shipped) + sorted(others))}")
    return _load_entry_point(ep)


def parse_assignments(items: list[str] | None) -> dict[str, str]:
    """["M=10", "sigma=0.1"] → {"M": "10", "sigma": "0.1"}."""
    out: dict[str, str] = {}
    for it in items or []:
        if "=" not in it:
            raise ParameterError(f"parameter {it!r} is not NAME=VALUE")
        k, v = it.split("=", 1)
        if k.strip() in out:
            raise ParameterError(f"parameter {k.strip()} is given twice ({k.strip()}={out[k.strip()]} and "
                                 f"{it.strip()})")
        out[k.strip()] = v.strip()
    return out
