"""What a noise sweep is: problem, fixed parameters, noise levels, trials, constraint sets, seeds."""

from __future__ import annotations

from pathlib import Path
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from ..errors import ParameterError
from ..problem import Problem, load
from ..sdp.config import SolverConfig
from ..tightness import Criteria

SETS = ("primary", "paper", "discovered")
DEFAULT_SIGMAS = tuple(float(s) for s in np.logspace(-3, 0, 7))
from ..pipeline import TRAP_RTOL  # noqa: E402  (re-exported: a sweep's default trap tolerance)


class ReportError(ParameterError):
    """Bad report input: noise levels, trials, sets, or an output folder holding another sweep."""


@dataclass(frozen=True)
class SweepSpec:
    """One sweep.  ``params`` are the fixed problem parameters (all but ``sigma``, parsed).

    Trial ``(i, t)`` solves a fresh instance at ``sigmas[i]``; its seeds come from
    ``SeedSequence((seed, i, t))`` only, so results never depend on the backend or worker.
    """

    problem: str
    params: dict[str, Any]
    sigmas: tuple[float, ...]
    trials: int
    sets: tuple[str, ...]
    seed: int = 0
    trap_rtol: float = TRAP_RTOL
    criteria: Criteria = field(default_factory=Criteria)
    solver: str = "clarabel"
    decompose: bool = False
    """Solve on the SDP layer's own clique cover (``--decompose``; ``SolverConfig.decompose``)."""
    discovered: str | None = None
    """A discovered-set JSON file, or None (run discovery when ``sets`` asks for it)."""
    files: tuple[tuple[str, str], ...] = ()
    """Saved constraint sets given as ``file:PATH`` in ``--sets``: (set name = the file's stem, PATH)."""
    source: str = ""
    """What ``autotight.problem.load`` takes (a name or a .py path); defaults to ``problem``."""

    def load(self) -> Problem:
        return load(self.source or self.problem)

    def identity(self) -> dict[str, Any]:
        """What must match for results to be mixed in one folder (``trials`` may grow or shrink)."""
        return {"problem": self.problem, "params": dict(self.params), "sigmas": list(self.sigmas),
                "sets": list(self.sets), "seed": self.seed, "trap_rtol": self.trap_rtol,
                "criteria": asdict(self.criteria), "solver": self.solver, "decompose": self.decompose}

    def tasks(self) -> list[tuple[int, int]]:
        """Every (σ index, trial), trial-major: a partial sweep (--limit, an interruption) covers every σ evenly."""
        return [(i, t) for t in range(self.trials) for i in range(len(self.sigmas))]

    def command(self) -> str:
        """The ``autotight report`` command that reproduces this sweep (non-default values only, exact σ)."""
        problem = self.load()
        defaults = problem.parse_params()
        parts = ["autotight report", self.source or self.problem]
        parts += [f"--param {k}={_fmt(v)}" for k, v in self.params.items() if v != defaults.get(k)]
        if self.sigmas != default_sigmas(problem):
            parts.append(f"--sigmas {_fmt(self.sigmas)}")
        paths = dict(self.files)
        sets = [f"file:{paths[s]}" if s in paths else s for s in self.sets]
        parts += [f"--trials {self.trials}", f"--sets {','.join(sets)}", f"--seed {self.seed}"]
        if self.discovered:
            parts.append(f"--discovered {self.discovered}")
        if self.solver != "clarabel":
            parts.append(f"--solver {self.solver}")
        if self.decompose:
            parts.append("--decompose")
        if self.criteria.accept != Criteria().accept:
            parts.append(f"--accept {self.criteria.accept}")
        return " ".join(parts)

    def solver_config(self) -> "SolverConfig":
        """The ``SolverConfig`` of every solve of the sweep (one solver thread per worker)."""
        return SolverConfig(backend=self.solver, decompose=True if self.decompose else None, threads=1)


def _fmt(v: Any) -> str:
    """A parameter value as the command line takes it; floats exactly (repr round-trips)."""
    if isinstance(v, tuple):
        return ",".join(repr(float(x)) for x in v)
    return repr(v) if isinstance(v, float) else str(v)


def trial_seeds(seed: int, sigma_index: int, trial: int) -> tuple[int, np.random.Generator, np.random.Generator]:
    """(instance seed s, rng for the random starts, rng for re-instantiating learned constraints).

    s comes from ``SeedSequence((seed, σ index, trial))``; the generators are those of s in the
    one seed scheme of ``autotight.pipeline.seeds`` (the same as ``autotight solve --seed s``).
    """
    from ..pipeline import seeds

    s = int(np.random.SeedSequence([seed, sigma_index, trial]).generate_state(1, np.uint32)[0])
    return s, seeds(s).local(), seeds(s).constraints()


def default_sigmas(problem: Problem) -> tuple[float, ...]:
    """The module's ``META.sigmas`` if it defines them, else 7 log-spaced levels over 1e-3 … 1."""
    import autotight.module_parts as module_parts

    return module_parts.sigmas(problem, DEFAULT_SIGMAS)


def parse_sigmas(problem: Problem, text: str | Sequence[float] | None) -> tuple[float, ...]:
    """Noise levels from "0.001,0.01,0.1" (or a sequence), validated by the problem's sigma range; sorted."""
    if text is None:
        values = list(default_sigmas(problem))
    elif isinstance(text, str):
        try:
            values = [float(s) for s in text.split(",") if s.strip()]
        except ValueError:
            raise ReportError(f"--sigmas {text!r}: expected comma-separated numbers, e.g. 0.001,0.01,0.1") from None
    else:
        values = [float(s) for s in text]
    if not values:
        raise ReportError("no noise levels given; e.g. --sigmas 0.001,0.01,0.1")
    if any(not np.isfinite(s) or s <= 0 for s in values):
        raise ReportError(f"noise levels must be finite and > 0 (the σ axis is logarithmic), got {values}")
    if len(set(values)) != len(values):
        raise ReportError(f"duplicate noise levels in {values}")
    sigma = require_sigma(problem)
    return tuple(sorted(float(sigma.parse("sigma", s)) for s in values))


def require_sigma(problem: Problem):
    if "sigma" not in problem.params:
        raise ReportError(f"problem {problem.name} has no 'sigma' parameter to sweep")
    return problem.params["sigma"]


def parse_sets(text: str | Sequence[str], files: Sequence[str] = ()) -> tuple[str, ...]:
    """The set names of ``--sets``: a subset of ``SETS`` and the names of saved sets ``files``."""
    names = [s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip()]
    bad = [s for s in names if s not in SETS and s not in files]
    if bad or not names:
        raise ReportError(f"--sets {','.join(names) or text!r}: use a comma-separated subset of {','.join(SETS)}")
    if len(set(names)) != len(names):
        raise ReportError(f"--sets lists a constraint set twice: {','.join(names)}")
    return tuple(names)


def file_sets(sets: str | Sequence[str]) -> tuple[list[str], tuple[tuple[str, str], ...]]:
    """``file:PATH`` entries of ``--sets``: each a saved constraint set named by its file's stem (e.g.
    ``file:reports/pose_averaging/range_set.json`` → "range_set"); the names must be distinct and
    must not be primary, paper or discovered."""
    names: list[str] = []
    files: list[tuple[str, str]] = []
    for x in (sets.split(",") if isinstance(sets, str) else sets):
        x = x.strip()
        if x.startswith("file:"):
            path = x[5:]
            name = Path(path).stem
            if not path or name in SETS or name in dict(files):
                raise ReportError(f"--sets {x}: a saved set needs a file whose name is not primary, paper, "
                                  "discovered or another set's")
            files.append((name, path))
            x = name
        if x:
            names.append(x)
    return names, tuple(files)


def make_spec(problem: Problem, source: str, params: dict[str, Any] | None = None, *,
              sigmas: str | Sequence[float] | None = None, trials: int = 100,
              sets: str | Sequence[str] | None = None, seed: int = 0, discovered: str | None = None,
              **kw: Any) -> SweepSpec:
    """A validated sweep; ``sets`` defaults to primary plus paper when the problem has paper families."""
    import autotight.module_parts as module_parts

    params = dict(params or {})
    require_sigma(problem)
    module_parts.paper_claim(problem)  # a malformed claim is refused before the sweep, not after it
    if "sigma" in params:
        raise ReportError("sigma is swept by the report; give the noise levels with --sigmas")
    if trials < 1:
        raise ReportError(f"--trials {trials}: need at least 1 trial per noise level")
    if seed < 0:
        raise ReportError(f"--seed {seed}: must be ≥ 0")
    if "solver" in kw:
        from ..sdp import SolverConfigError, check_solver

        try:
            check_solver(kw["solver"])
        except SolverConfigError as e:
            raise ReportError(str(e)) from None
    full = problem.parse_params(params)
    full.pop("sigma")
    paper = has_paper(problem, full)
    if sets is None:
        sets = ("primary", "paper") if paper else ("primary",)
    sets, files = file_sets(sets)
    sets = parse_sets(sets, [n for n, _ in files])
    if "paper" in sets and not paper:
        raise ReportError(f"--sets paper: problem {problem.name} has no paper families")
    return SweepSpec(problem.name, full, parse_sigmas(problem, sigmas), int(trials), sets, int(seed),
                     discovered=discovered, files=files, source=str(source), **kw)


def has_paper(problem: Problem, params: dict[str, Any]) -> bool:
    """Whether the problem's model has hand-derived (paper) constraint families."""
    inst = problem.generate(params, 0)
    return bool(problem.build(inst).paper)
