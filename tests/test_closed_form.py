"""Closed forms of discovered families, and sets exported as standalone code."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from autotight.closed_form.family import closed_form
from autotight.closed_form.formula import data_names, formula
from autotight.closed_form.samples import collect
from autotight.closed_form.table import family_table, learned_transport
from autotight.constraint_set import ConstraintSet
from autotight.discovery.discovered import DiscoveredSet
from autotight.discovery.templates import TemplateSet, factor_columns
from autotight.export import python_source
from autotight.model import Constraint
from autotight.problem import load

ROOT = Path(__file__).resolve().parents[1]
POSE = ROOT / "reports" / "pose_averaging" / "discovered.json"
DISCRETE = ROOT / "reports" / "discrete_trajectory" / "discovered.json"
POSE_RANGE = ROOT / "reports" / "sets" / "pose_averaging_range.json"


def test_pose_averaging_family_is_the_papers_r2():
    """The discovered pair of pose averaging has an exact closed form, equal to R2 modulo the primary
    constraints on 100 fresh factors, and it holds on feasible states of fresh instances."""
    ds = DiscoveredSet.load(POSE)
    tab = family_table(load(ds.problem), ds)
    (row,) = tab.rows
    assert row.exact and row.degree is not None
    assert row.paper == "R2" and row.relation == "= R2"
    assert row.residual <= 1e-10 and row.violation <= 1e-10
    r2 = dict((n, c) for n, c, _ in tab.paper["pose_meas"])["R2"]
    assert row.closed_form == r2  # equal families print equally
    assert "C̃" in tab.paper["pose_meas"][0][1] and "r̃" in row.closed_form


def _exported(ds: DiscoveredSet, tmp_path: Path, name: str):
    src = python_source(load(ds.problem), ds, name)
    assert "autotight" not in "\n".join(line for line in src.splitlines() if "import" in line)
    path = tmp_path / f"{name}.py"
    path.write_text(src, encoding="utf-8")
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _exported_matrices(mod, ds: DiscoveredSet, model) -> list[sp.csr_array]:
    factors = {}
    for t, tpl in ds.templates.templates.items():
        _, cols, D = factor_columns(model, tpl)
        factors[t] = (cols, D)
    N = model.variables.N
    return [sp.csr_array(sp.coo_array((v, (r, c)), shape=(N, N))) for _, r, c, v in mod.constraint_matrices(factors, N)]


@pytest.mark.parametrize("path", [POSE, DISCRETE], ids=["pose", "discrete"])
def test_exported_python_reproduces_the_sets_matrices(path, tmp_path):
    """On 5 instances the exported NumPy function gives the matrices `solve --set` builds, to 1e-12."""
    ds = DiscoveredSet.load(path)
    prob = load(ds.problem)
    mod = _exported(ds, tmp_path, "exported_set")
    for seed in range(5):
        inst = prob.generate(ds.params, seed)
        model = prob.build(inst)
        ours = ConstraintSet(ds).apply(prob, inst, model, np.random.default_rng(seed))
        theirs = _exported_matrices(mod, ds, model)
        assert len(theirs) == len(ours) > 0
        for a, b in zip(ours, theirs):
            scale = abs(sp.csr_array(a.A)).max()
            assert abs(sp.csr_array(a.A) - b).max() <= 1e-12 * scale


def test_exported_python_reproduces_a_transport_template(tmp_path):
    """A transport template (pose averaging's range set, carried from one learned factor) exported as code:
    the module's M(data) becomes an exact polynomial, and the matrices equal autotight's to 1e-12."""
    ds = DiscoveredSet.load(POSE_RANGE)
    prob = load(ds.problem)
    idents = sorted(i for _, i in ds.pairs)
    ds.templates = TemplateSet({"pose_meas": learned_transport(prob, ds, "pose_meas", idents)}, {})
    mod = _exported(ds, tmp_path, "exported_transport")
    for seed in range(5):
        inst = prob.generate(ds.params, seed)
        model = prob.build(inst)
        ours = ConstraintSet(ds).apply(prob, inst, model, np.random.default_rng(seed))
        theirs = _exported_matrices(mod, ds, model)
        assert not mod.constraint_matrices.skipped
        assert len(theirs) == len(ours) > 0
        for a, b in zip(ours, theirs):
            scale = abs(sp.csr_array(a.A)).max()
            assert abs(sp.csr_array(a.A) - b).max() <= 1e-12 * scale


@pytest.mark.parametrize("path", [POSE, pytest.param(DISCRETE, marks=pytest.mark.slow)], ids=["pose", "discrete"])
def test_exported_constraints_keep_the_sdp_tight(path, tmp_path):
    """The primary constraints plus the exported ones give a tight SDP on 5 instances."""
    from autotight.api import solve

    ds = DiscoveredSet.load(path)
    prob = load(ds.problem)
    mod = _exported(ds, tmp_path, "exported_set_sdp")
    for seed in range(5):
        inst = prob.generate(ds.params, seed)
        model = prob.build(inst)
        cons = [Constraint(A, 0.0, name=f"exported:{k}") for k, A in enumerate(_exported_matrices(mod, ds, model))]
        out = solve(prob, ds.params, seed, constraints=cons)
        assert out.verdict.tight, (seed, out.verdict.reason)


@pytest.fixture(scope="module")
def pose_samples():
    ds = DiscoveredSet.load(POSE)
    prob = load(ds.problem)
    return prob, ds, collect(prob, ds.params, "pose_meas", 240, 0)


def test_equal_families_print_equally(pose_samples):
    """R2 scaled by 3 plus a random combination of the primary constraints has R2's closed form."""
    prob, ds, fs = pose_samples
    rng = np.random.default_rng(3)
    R2 = fs.paper["R2"][:, 0, :]
    # rows of reducers span the primary constraints on each factor (G_P⁻¹ G)
    mixed = 3.0 * R2 + np.einsum("sr,srm->sm", rng.standard_normal((R2.shape[0], fs.reducers.shape[1])),
                                 fs.reducers)
    a, b = closed_form("R2", fs, R2), closed_form("mixed", fs, mixed)
    assert a.exact and b.exact
    names = data_names(prob, "pose_meas", fs.D.shape[1])
    assert formula(a, fs.roles, fs.block_sizes, names) == formula(b, fs.roles, fs.block_sizes, names)
    # a family outside the paper's span has another closed form
    c = closed_form("R1[1]", fs, fs.paper["R1"][:, 0, :])
    assert formula(c, fs.roles, fs.block_sizes, names) != formula(a, fs.roles, fs.block_sizes, names)


@pytest.mark.parametrize("name", ["landmark_slam_d3_vector_s1.json",
                                  pytest.param("pose_graph_d2_vector_s1.json", marks=pytest.mark.slow)])
def test_landmark_closed_forms_hold_on_fresh_data(name):
    """Landmark sets: every family has an exact closed form that holds on feasible states of 100 fresh factors
    to 1e-10 relative; no paper family exists, so each is new."""
    ds = DiscoveredSet.load(ROOT / "reports" / "landmark_liftings" / "sets" / name)
    tab = family_table(load(ds.problem), ds)
    assert len(tab.rows) == len(ds.pairs) > 0
    for r in tab.rows:
        assert r.exact and r.violation <= 1e-10, r
        assert r.paper == "new" and r.closed_form.endswith("= 0") and r.latex


def test_a_set_without_pairs_says_so(tmp_path):
    ds = DiscoveredSet("rotation_averaging", {"M": 3}, 0, [])
    tab = family_table(load("rotation_averaging"), ds)
    assert tab.rows == [] and "primary constraints alone" in tab.notes[0]


def test_export_cli(tmp_path, capsys):
    from autotight.cli import main

    out = tmp_path / "set.json"
    assert main(["export", str(POSE), "--to", "json-sparse", "--seed", "1", "--out", str(out)]) == 0
    rec = json.loads(out.read_text(encoding="utf-8"))
    t = rec["templates"]["pose_meas"]
    assert t["kind"] == "polynomial" and t["W_triplets"]
    learned = [c for c in rec["instance"]["constraints"] if "r[2]·rho[2]" in c["name"]]
    assert len(learned) == 10 and all(c["b"] == 0 for c in learned)
    assert main(["export", str(POSE_RANGE), "--to", "python"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("autotight: error:") and "no template" in err and "\n" not in err


@pytest.mark.slow
def test_discrete_range_set_families():
    """The discrete-trajectory range set (saved without templates): through a transport from one learned
    factor, c1[2]·rho[2], c2[2]·rho[2] and r[2]·rho[2] are R1[1], R1[2] and R2 exactly; the c3 families have no
    closed form of degree ≤ 2 and lie outside the paper's span."""
    ds = DiscoveredSet.load(ROOT / "reports" / "sets" / "discrete_trajectory_range.json")
    rows = {r.identity: r for r in family_table(load(ds.problem), ds).rows}
    assert rows["c1[2]·rho[2]"].relation == "= R1[1]" and rows["c2[2]·rho[2]"].relation == "= R1[2]"
    assert rows["r[2]·rho[2]"].relation == "= R2"
    for i in ("c1[2]·rho[2]", "c2[2]·rho[2]", "r[2]·rho[2]"):
        assert rows[i].exact and rows[i].residual <= 1e-10 and rows[i].violation <= 1e-10
    for i in ("c3[0]·rho[0]", "c3[1]·rho[1]", "c3[2]·rho[2]"):
        assert rows[i].closed_form.startswith("no closed form") and rows[i].paper == "new"


def test_discover_prints_the_table_and_writes_latex(tmp_path, capsys):
    """`discover --latex FILE`: the closed-form table after discover's own, and a LaTeX document (rotation
    averaging: tight with the primary constraints alone, so the table says there is no learned family)."""
    from autotight.cli import main

    tex = tmp_path / "families.tex"
    assert main(["discover", "rotation_averaging", "-p", "M=3", "--no-progress", "--heldout", "1",
                 "--latex", str(tex)]) == 0
    out = capsys.readouterr().out
    assert "discovered family | closed form | paper family | relation" in out
    doc = tex.read_text(encoding="utf-8")
    assert doc.startswith(r"\documentclass") and doc.rstrip().endswith(r"\end{document}")
    assert "primary constraints alone" in doc
    assert main(["discover", "rotation_averaging", "--latex", str(tex)]) == 2  # exists: refused before the work
