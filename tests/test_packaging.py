"""Packaging: declared dependencies match the imports, optional extras fail clearly, one version.

- Every hard dependency in pyproject.toml is imported by the library, and every third-party
  package the library or the shipped problems import is declared (a hard dependency or an extra),
  unless the import is an optional accelerator guarded by ``except ImportError``.
- No dependency or extra is GPL-licensed (cvxopt is not declared anywhere).
- Without the `report` and `dask` extras (their imports blocked in a fresh interpreter), the core
  library imports, `solve` runs, every CLI verb is still listed, and `autotight report` fails
  with one line that names the extra.
- The version comes from ``autotight.__version__`` only; ``io.versions()`` reports it.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import scipy

import autotight
from autotight.io import versions

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: distribution name → the modules it provides, where they differ
MODULES = {"dask": ("dask", "distributed"), "scikit-learn": ("sklearn",)}


def _dist(req: str) -> str:
    return re.match(r"[A-Za-z0-9_.\-]+", req).group(0).lower()


def _modules(reqs: list[str]) -> set[str]:
    return {m for r in reqs for m in MODULES.get(_dist(r), (_dist(r).replace("-", "_"),))}


def _third_party_imports(folder: str) -> dict[str, list[tuple[str, bool]]]:
    """module → [(file, guarded by `except ImportError`)] for the non-stdlib, non-local imports."""
    out: dict[str, list[tuple[str, bool]]] = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        guarded: set[int] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Try) and any(
                    h.type is not None and "ImportError" in ast.unparse(h.type) for h in node.handlers):
                guarded |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top in sys.stdlib_module_names or top in ("autotight", "problems", "__future__"):
                    continue
                out.setdefault(top, []).append((str(path.relative_to(ROOT)), id(node) in guarded))
    return out


def test_hard_dependencies_are_imported_and_imports_are_declared():
    hard = _modules(PYPROJECT["project"]["dependencies"])
    extras = {m for reqs in PYPROJECT["project"]["optional-dependencies"].values() for m in _modules(reqs)}
    used = _third_party_imports("autotight")
    unused = sorted(hard - set(used))
    assert not unused, f"hard dependencies that autotight/ never imports: {unused}"
    for folder, imports in (("autotight", used), ("problems", _third_party_imports("problems"))):
        undeclared = {m: files for m, files in imports.items()
                      if m not in hard | extras and not all(g for _, g in files)}
        assert not undeclared, f"{folder}/ imports packages that pyproject.toml does not declare: {undeclared}"
        if folder == "problems":  # the shipped problems need nothing beyond the hard dependencies
            assert set(imports) <= hard, f"problems/ imports optional packages: {sorted(set(imports) - hard)}"


def test_no_gpl_dependency_and_a_licence():
    reqs = PYPROJECT["project"]["dependencies"] + [
        r for reqs in PYPROJECT["project"]["optional-dependencies"].values() for r in reqs]
    assert "cvxopt" not in {_dist(r) for r in reqs}
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    assert (ROOT / "LICENSE").read_text().startswith("BSD 3-Clause License")
    assert (ROOT / "autotight" / "py.typed").exists()


def test_one_version_source():
    assert "version" not in PYPROJECT["project"] and "version" in PYPROJECT["project"]["dynamic"]
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "autotight._version.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", autotight.__version__)
    v = versions()
    assert v["autotight"] == autotight.__version__ and v["numpy"] == np.__version__ and v["scipy"] == scipy.__version__


_WITHOUT_EXTRAS = r"""
import importlib.abc, sys
BLOCKED = {"pandas", "matplotlib", "joblib", "dask", "distributed", "sklearn", "cvxopt"}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
sys.meta_path.insert(0, Block())
for m in list(sys.modules):
    if m.split(".")[0] in BLOCKED:
        del sys.modules[m]
"""


def _run_without_extras(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS + code], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


def test_core_works_without_the_optional_extras():
    out = _run_without_extras(r"""
import autotight, autotight.cli, autotight.discovery, autotight.sdp
from autotight.problem import available, load
for name in available():
    load(name)
verbs = set(autotight.cli.build_parser()._subparsers._group_actions[0].choices)
assert {"list", "solve", "discover", "report"} <= verbs, verbs
assert autotight.cli.main(["solve", "rotation_averaging", "-p", "M=3", "--json"]) == 0
print("REPORT", autotight.cli.main(["report", "rotation_averaging", "--trials", "1"]))
""")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "REPORT 2"
    err = [ln for ln in out.stderr.splitlines() if ln.startswith("autotight: error:")]
    assert len(err) == 1 and "autotight[report]" in err[0] and "matplotlib" in err[0] and "pandas" in err[0], \
        out.stderr


def test_every_shipped_problem_module_is_registered_as_an_entry_point():
    declared = PYPROJECT["project"]["entry-points"]["autotight.problems"]
    files = {p.stem for p in (ROOT / "problems").glob("*.py") if not p.stem.startswith("_")}
    assert declared == {name: f"problems.{name}" for name in sorted(files)}
    from autotight.problem import available

    assert available() == sorted(files)  # the installed metadata is the declared one (reinstall after editing)


def test_jsonable_keeps_every_value_and_names_non_finite_floats():
    """Arrays become nested lists of Python numbers (finite float, int and bool arrays in one step), and a
    non-finite float, alone or in an array, becomes its string."""
    import json

    from autotight.io import jsonable

    out = jsonable({"a": np.arange(6.0).reshape(2, 3) / 3, "i": np.arange(3, dtype=np.int32), "b": np.array([True]),
                    "bad": np.array([1.0, np.nan, -np.inf]), "x": np.float32(0.5), "n": np.int64(7)})
    assert out == {"a": (np.arange(6.0).reshape(2, 3) / 3).tolist(), "i": [0, 1, 2], "b": [True],
                   "bad": [1.0, "nan", "-inf"], "x": 0.5, "n": 7}
    assert type(out["a"][0][1]) is float and type(out["i"][0]) is int and type(out["b"][0]) is bool
    json.dumps(out, allow_nan=False)
