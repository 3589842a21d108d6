"""Tests for ``autotight report``: files, rows, resume, backends, mismatch refusal, HTML, errors."""

from __future__ import annotations

import base64
import json
import shlex
import shutil
import signal
import subprocess
import sys
import time
import types
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from autotight.cli import main
from autotight.errors import AutotightError
from autotight.problem import load
from autotight.report import trial as trial_mod
from autotight.report.render import render
from autotight.report.spec import ReportError, make_spec, parse_sigmas, trial_seeds
from autotight.report.store import CSV_NAME, Store, load_trials
from autotight.report.sweep import run_sweep
from autotight.report.trial import TIME_COLUMNS, columns, is_trapped, run_trial
from autotight.api import solve
from trials_equal import LOG_SVR_FLOOR, assert_same_trials, deterministic
from autotight.sdp import SolverConfig

PROBLEM = "rotation_averaging"
SIGMAS = (0.01, 0.3)
TRIALS = 3
FILES = ("trials.csv", "meta.json", "trapped.png", "log_svr.png", "tight.png", "times.png", "report.md",
         "report.html")


def _spec(**kw):
    args = dict(params={"M": 3}, sigmas=",".join(map(str, SIGMAS)), trials=TRIALS, sets="primary")
    args.update(kw)
    return make_spec(load(PROBLEM), PROBLEM, **args)


def _render(out: Path) -> dict[str, Path]:
    return render(out, Store(out).meta())


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted sweep on two loky workers (joblib backend)."""
    out = tmp_path_factory.mktemp("ref") / "report"
    s = run_sweep(_spec(), out, jobs=2, progress=False)
    assert (s.total, s.done_before, s.computed, s.failed) == (6, 0, 6, 0)
    _render(out)
    return out


def test_tiny_sweep_writes_every_file_and_expected_rows(reference):
    for name in FILES:
        assert (reference / name).is_file() and (reference / name).stat().st_size > 0, name
    df = load_trials(reference)
    assert list(df.columns) == columns(["rotation_deg"])
    assert len(df) == len(SIGMAS) * TRIALS
    keys = list(zip(df["sigma_index"], df["trial"], df["constraint_set"]))
    assert keys == [(i, t, s) for i in range(2) for t in range(TRIALS) for s in ("primary",)]
    assert sorted(df["sigma"].unique()) == list(SIGMAS)
    for _, r in df.iterrows():
        assert r["seed"] == trial_seeds(0, r["sigma_index"], r["trial"])[0]
    prob = load(PROBLEM)
    n_primary = len(prob.build(prob.generate({"M": 3}, 0)).primary())
    assert n_primary == 1 + 6 + 9 * 3
    assert (df["n_constraints"] == n_primary).all()
    assert (df["status"] == "Solved").all()
    assert (df["log_svr"] > 5).all() and df["tight"].all()  # rotation averaging is tight with primary only
    assert np.isfinite(df[["sdp_cost", "local_cost_truth", "local_cost_random", "global_cost"]]).all().all()
    # every row is tight, so the global cost (the lowest local or tight SDP cost) is certified: the SDP
    # cost and the best local cost agree with it (global ≤ local_cost_truth alone holds by construction)
    best_local = np.minimum(df["local_cost_truth"], df["local_cost_random"])
    assert np.allclose(df["global_cost"], best_local, rtol=1e-5) and np.allclose(df["sdp_cost"], best_local, rtol=1e-5)
    assert (df["err_sdp_rotation_deg"] < 45).all()
    assert df["trapped"].dtype == bool
    meta = json.loads((reference / "meta.json").read_text())
    assert meta["problem"] == PROBLEM and meta["params"] == {"M": 3, "anisotropy": 1.0}
    assert meta["sigmas"] == list(SIGMAS) and meta["trials"] == TRIALS and meta["seed"] == 0
    assert meta["sets"] == ["primary"] and meta["columns"] == list(df.columns)
    assert meta["versions"]["numpy"] == np.__version__
    assert meta["runs"][0]["backend"] == "joblib" and meta["runs"][0]["jobs"] == 2


def test_a_row_equals_a_direct_solve_of_its_instance(reference):
    df = load_trials(reference)
    r = df[(df["sigma_index"] == 1) & (df["trial"] == 2) & (df["constraint_set"] == "primary")].iloc[0]
    prob = load(PROBLEM)
    assert trial_seeds(0, 1, 2)[0] == int(r["seed"])  # the trial's generators are those of its instance seed
    out = solve(prob, {"M": 3, "sigma": 0.3}, int(r["seed"]), constraints="primary", solver=SolverConfig(threads=1))
    assert min(r["log_svr"], LOG_SVR_FLOOR) == pytest.approx(min(out.sdp.log_svr, LOG_SVR_FLOOR), rel=1e-9)
    assert r["sdp_cost"] == pytest.approx(out.sdp.primal_cost, rel=1e-9)
    assert r["local_cost_truth"] == pytest.approx(out.local.from_truth.cost, rel=1e-12)
    assert r["local_cost_random"] == pytest.approx(out.local.from_random[0].cost, rel=1e-12)
    assert r["err_sdp_rotation_deg"] == pytest.approx(out.errors_sdp["rotation_deg"], rel=1e-6)


def test_report_md_tables_agree_with_the_csv(reference):
    df = load_trials(reference)
    md = (reference / "report.md").read_text()
    assert "| primary | 34 |" in md
    for i, s in enumerate(SIGMAS):
        at = df[df["sigma_index"] == i]
        tp = at[at["constraint_set"] == "primary"]["tight"].mean()
        trapped = at.drop_duplicates("trial")["trapped"].mean()
        assert f"| {s:.3g} | {TRIALS} | {tp:.2f} | {trapped:.2f} |" in md
        med = np.median(at[at["constraint_set"] == "primary"]["log_svr"])
        assert f"| {s:.3g} | {med:.1f} |" in md
    assert "--sigmas 0.01,0.3 --trials 3 --sets primary --seed 0" in md
    for fig in ("trapped.png", "log_svr.png", "tight.png", "times.png"):
        assert f"]({fig})" in md


class _Checker(HTMLParser):
    VOID = {"meta", "img", "br", "hr", "link", "input"}

    def __init__(self):
        super().__init__()
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.images: list[str] = []
        self.doctype = False

    def handle_decl(self, decl):
        self.doctype |= decl.lower() == "doctype html"

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack.pop() != tag:
            self.errors.append(f"unexpected </{tag}>")


def test_html_is_valid_and_embeds_every_figure(reference):
    page = (reference / "report.html").read_text()
    c = _Checker()
    c.feed(page)
    c.close()
    assert c.doctype and c.errors == [] and c.stack == []
    assert "<title>Tightness report: rotation_averaging</title>" in page
    assert len(c.images) == 4
    pngs = {(reference / f).read_bytes() for f in ("trapped.png", "log_svr.png", "tight.png", "times.png")}
    for src in c.images:
        assert src.startswith("data:image/png;base64,")
        data = base64.b64decode(src.split(",", 1)[1])
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and data in pngs
        width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
        assert width >= 600 and height >= 400
    assert "src=" not in page.replace('src="data:image/png;base64,', "")  # nothing loaded from outside


def test_complete_sweep_rerun_computes_nothing(reference):
    before = (reference / CSV_NAME).read_bytes()
    s = run_sweep(_spec(), reference, jobs=1, progress=False)
    assert (s.done_before, s.computed, s.complete) == (6, 0, True)
    assert (reference / CSV_NAME).read_bytes() == before


def test_stopped_sweep_resumes_only_missing_trials_and_equals_uninterrupted(reference, tmp_path):
    out = tmp_path / "r"
    s1 = run_sweep(_spec(), out, jobs=1, limit=2, progress=False)
    assert (s1.computed, s1.complete) == (2, False)
    first = load_trials(out)
    # trial-major: trial 0 at every σ first
    assert len(first) == 2 and set(zip(first["sigma_index"], first["trial"])) == {(0, 0), (1, 0)}
    with open(out / CSV_NAME, "a") as f:  # a torn write from a crash: half a line, no newline
        f.write("rotation_averaging,0,0.01,2,1234,prim")
    s2 = run_sweep(_spec(), out, jobs=1, progress=False)
    assert (s2.done_before, s2.computed, s2.complete) == (2, 4, True)
    final = load_trials(out)
    assert_same_trials(final, load_trials(reference))
    # the trials from the first run were kept, not recomputed (their timings are unchanged)
    kept = final[final["trial"] == 0].reset_index(drop=True)
    pd.testing.assert_frame_equal(kept, first.reset_index(drop=True))


def test_more_trials_extends_the_sweep(reference, tmp_path):
    out = tmp_path / "r"
    shutil.copytree(reference, out)
    s = run_sweep(_spec(trials=4), out, jobs=1, progress=False)
    assert (s.total, s.done_before, s.computed) == (8, 6, 2)
    df = load_trials(out)
    assert len(df) == 8 and sorted(set(df["trial"])) == [0, 1, 2, 3]


def test_redo_recomputes_only_the_trials_with_those_statuses(reference, tmp_path):
    """A saved trial whose solve 'stalled' is dropped and computed again by ``redo``; the others are kept."""
    out = tmp_path / "r"
    shutil.copytree(reference, out)
    df = load_trials(out)
    hit = (df["sigma_index"] == 1) & (df["trial"] == 1) & (df["constraint_set"] == "primary")
    df.loc[hit, "status"] = "InsufficientProgress"
    df.loc[hit, "log_svr"] = -1.0
    df.to_csv(out / CSV_NAME, index=False)
    notes: list[str] = []
    s = run_sweep(_spec(), out, jobs=1, redo=["InsufficientProgress", "NumericalError"], progress=False,
                  log=notes.append)
    assert (s.done_before, s.computed, s.complete) == (5, 1, True)
    assert any("re-running 1 saved trial" in n for n in notes)
    final = load_trials(out)
    assert_same_trials(final, load_trials(reference))  # the redone trial is correct again
    meta = json.loads((out / "meta.json").read_text())
    assert meta["runs"][-1]["redone_trials"] == 1
    s2 = run_sweep(_spec(), out, jobs=1, redo=["InsufficientProgress"], progress=False)
    assert s2.computed == 0  # nothing stalled any more


def test_changed_package_versions_are_noted_on_resume(reference, tmp_path, monkeypatch):
    out = tmp_path / "r"
    shutil.copytree(reference, out)
    monkeypatch.setattr("autotight.report.store.versions", lambda: {"numpy": "0.0.1"})
    notes: list[str] = []
    s = run_sweep(_spec(), out, jobs=1, progress=False, log=notes.append)
    assert s.computed == 0 and len(notes) == 1 and f"numpy {np.__version__} → 0.0.1" in notes[0]
    runs = json.loads((out / "meta.json").read_text())["runs"]
    assert [r["versions"]["numpy"] for r in runs[-2:]] == [np.__version__, "0.0.1"]


def _drop_columns(out: Path, drop: tuple[str, ...]) -> pd.DataFrame:
    """Make ``out`` look like a folder written before ``drop`` were columns; returns the full rows."""
    full = pd.read_csv(out / CSV_NAME, keep_default_na=False)
    full.drop(columns=list(drop)).to_csv(out / CSV_NAME, index=False)
    meta = json.loads((out / "meta.json").read_text())
    meta["columns"] = [c for c in meta["columns"] if c not in drop]
    (out / "meta.json").write_text(json.dumps(meta))
    return full


def test_a_folder_written_before_new_columns_resumes_with_them_empty(reference, tmp_path):
    """The bracket's lower end and accuracy were added after reports were committed: such a folder
    resumes (nothing recomputed), its CSV gains the columns with empty cells and every other cell kept,
    and it renders; a folder of another sweep is refused and left untouched."""
    drop = ("sdp_lower_bound", "sdp_accuracy", "sdp_tolerance")
    out = tmp_path / "old"
    shutil.copytree(reference, out)
    full = _drop_columns(out, drop)
    notes: list[str] = []
    s = run_sweep(_spec(), out, jobs=1, progress=False, log=notes.append)
    assert s.computed == 0 and any("sdp_lower_bound, sdp_accuracy, sdp_tolerance" in n for n in notes), notes
    now = pd.read_csv(out / CSV_NAME, keep_default_na=False)
    assert list(now.columns) == list(full.columns)
    assert (now[list(drop)] == "").all().all()
    keep = [c for c in full.columns if c not in drop]
    assert now[keep].astype(str).equals(full[keep].astype(str))
    assert json.loads((out / "meta.json").read_text())["runs"][-1]["added_columns"] == list(drop)
    assert "Bracket against the best feasible cost" not in _render(out)["report.md"].read_text()
    other = tmp_path / "other"
    shutil.copytree(reference, other)
    _drop_columns(other, drop)
    before = (other / CSV_NAME).read_bytes()
    with pytest.raises(ReportError, match="seed"):
        run_sweep(_spec(seed=1), other, jobs=1, progress=False)
    assert (other / CSV_NAME).read_bytes() == before


def test_the_bracket_table_counts_inverted_brackets(reference):
    """The report's bracket table: a solve whose P and D both exceed U by more than roundoff is
    counted, beyond its accuracy only when the excess exceeds it, and so is one whose corrected lower
    end L exceeds U; on the reference no L exceeds U.  A polished dual (sdp_dual_raw set) below U is
    not counted with P, and its solver's own dual cost above U is counted apart."""
    from autotight.report.render import bracket_table

    df = load_trials(reference)
    table = bracket_table(df, SIGMAS, ["primary"])
    assert table.header[6:8] == ["solver's D above U", "L above U"]
    assert [r[7] for r in table.rows] == ["0", "0"]  # every corrected bracket [L, P] holds U
    bad = df.copy()
    U = bad.loc[0, "upper_bound"]
    bad.loc[0, ["sdp_cost", "sdp_dual_cost", "sdp_dual_raw", "sdp_lower_bound", "sdp_accuracy"]] = \
        [U * (1 + 1e-6), U * (1 + 2e-6), np.nan, U * (1 + 5e-7), U * 5e-7]
    row = bracket_table(bad, SIGMAS, ["primary"]).rows[0]
    assert row[3] == "1" and row[5] == "1" and row[6] == "1" and row[7] == "1"
    assert float(row[4]) == pytest.approx(1e-6, rel=1e-3)
    bad.loc[0, "sdp_accuracy"] = U * 2e-6  # the same excess within the solve's accuracy
    assert bracket_table(bad, SIGMAS, ["primary"]).rows[0][5] == "0"
    bad.loc[0, ["sdp_dual_cost", "sdp_dual_raw", "sdp_lower_bound"]] = [U * (1 - 1e-10), U * (1 + 3e-6), U * (1 - 1e-8)]
    row = bracket_table(bad, SIGMAS, ["primary"]).rows[0]
    assert row[3] == "0" and row[6] == "1" and row[7] == "0"


def test_dask_local_cluster_gives_the_same_results_as_joblib(reference, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        s = run_sweep(_spec(), tmp_path / "d", scheduler=cluster.scheduler_address, progress=False)
    assert (s.computed, s.complete) == (6, True)
    meta = json.loads((tmp_path / "d" / "meta.json").read_text())
    assert meta["runs"][0]["backend"] == "dask"
    assert_same_trials(load_trials(tmp_path / "d"), load_trials(reference))


@pytest.mark.parametrize("change, setting", [({"params": {"M": 4}}, "params"), ({"sigmas": "0.01,0.1"}, "sigmas"),
                                             ({"seed": 1}, "seed"),
                                             ({"solver": "ipm"}, "solver")])
def test_a_different_sweep_in_the_same_folder_is_refused(reference, change, setting):
    before = (reference / CSV_NAME).read_bytes()
    with pytest.raises(ReportError, match=f"holds a different sweep \\({setting}:"):
        run_sweep(_spec(**change), reference, jobs=1, progress=False)
    assert (reference / CSV_NAME).read_bytes() == before


def test_cli_refuses_a_mismatch_with_one_line(reference, capsys):
    rc = main(["report", PROBLEM, "-p", "M=5", "--sigmas", "0.01,0.3", "--trials", "3", "--jobs", "1",
               "--out", str(reference), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert err.startswith("autotight: error:") and '"M": 3' in err and '"M": 5' in err


def test_the_recorded_command_reproduces_the_same_sweep(reference, capsys):
    command = Store(reference).meta()["runs"][0]["command"]
    assert command.startswith("autotight report rotation_averaging --param M=3 --sigmas 0.01,0.3 ")
    rc = main(["report", *shlex.split(command)[2:], "--jobs", "1", "--no-progress", "--json"])
    assert rc == 0, capsys.readouterr().err
    rec = json.loads(capsys.readouterr().out)
    assert (rec["done_before"], rec["computed"], rec["complete"]) == (6, 0, True)


def test_cli_runs_a_sweep_and_prints_json(tmp_path, capsys):
    out = tmp_path / "c"
    rc = main(["report", PROBLEM, "-p", "M=2", "--sigmas", "0.1,0.01", "--trials", "1", "--sets", "primary",
               "--jobs", "1", "--out", str(out), "--no-progress", "--json"])
    assert rc == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["sigmas"] == [0.01, 0.1] and rec["computed"] == 2 and rec["complete"] is True
    assert set(rec["files"]) == {"trapped.png", "log_svr.png", "tight.png", "times.png", "report.md", "report.html"}
    assert len(load_trials(out)) == 2


def test_a_sweep_with_our_ipm_records_it_and_agrees_with_clarabel(reference, tmp_path, capsys):
    """--solver ipm: recorded in the settings and the command; the same verdicts and costs to the
    IPM's accuracy (1e-7 relative) as the Clarabel reference sweep."""
    out = tmp_path / "ipm"
    rc = main(["report", PROBLEM, "-p", "M=3", "--sigmas", "0.01,0.3", "--trials", "3", "--sets", "primary",
               "--jobs", "1", "--out", str(out), "--no-progress", "--solver", "ipm"])
    assert rc == 0, capsys.readouterr().err
    meta = Store(out).meta()
    assert meta["solver"] == "ipm" and meta["runs"][0]["command"].endswith(f"--solver ipm --out {out}")
    a, b = deterministic(load_trials(reference)), deterministic(load_trials(out))
    # the property, not the IPM's exact stopping status (which varies with the machine's BLAS): where both
    # solvers decided, they agree; where both returned a usable X, the costs agree to the IPM's accuracy
    decided = (a["outcome"] != "undecided") & (b["outcome"] != "undecided")
    assert decided.any() and list(a["outcome"][decided]) == list(b["outcome"][decided])
    usable = a["status"].isin(["Solved", "AlmostSolved"]) & b["status"].isin(["Solved", "AlmostSolved"])
    assert usable.all() and np.allclose(a["sdp_cost"], b["sdp_cost"], rtol=1e-6)


def test_decompose_is_a_sweep_setting_and_agrees_with_clarabel_chordal(reference, tmp_path, capsys):
    """--decompose: Clarabel on our clique cover; in the settings (a resume without it is refused) and
    the command, with the reference sweep's verdicts and costs (1e-6 relative)."""
    out = tmp_path / "dec"
    args = ["report", PROBLEM, "-p", "M=3", "--sigmas", "0.01,0.3", "--trials", "3", "--sets", "primary",
            "--jobs", "1", "--out", str(out), "--no-progress"]
    assert main([*args, "--decompose"]) == 0, capsys.readouterr().err
    meta = Store(out).meta()
    assert meta["decompose"] is True and meta["runs"][0]["command"].endswith(f"--decompose --out {out}")
    a, b = deterministic(load_trials(reference)), deterministic(load_trials(out))
    assert list(a["tight"]) == list(b["tight"])
    assert np.allclose(a["sdp_cost"], b["sdp_cost"], rtol=1e-6)
    capsys.readouterr()
    assert main(args) == 2 and "decompose" in capsys.readouterr().err
    assert main([*args, "--decompose", "--accept", "cost"]) == 2 and "criteria" in capsys.readouterr().err


def test_accept_is_a_sweep_setting_recorded_in_the_command(tmp_path, capsys):
    out = tmp_path / "acc"
    assert main(["report", PROBLEM, "-p", "M=3", "--sigmas", "0.1", "--trials", "1", "--sets", "primary",
                 "--jobs", "1", "--out", str(out), "--no-progress", "--accept", "certified"]) == 0
    meta = Store(out).meta()
    assert meta["criteria"]["accept"] == "certified"
    assert meta["runs"][0]["command"].endswith(f"--accept certified --out {out}")
    assert load_trials(out)["tight"].tolist() == [True]


def test_a_module_with_marginal_log_svr_gets_its_column():
    """Continuous time reports log SVR on the marginalised X beside the solved X's (``log_svr_marginal``)."""
    cont, rot = load("continuous_trajectory"), load(PROBLEM)
    assert "log_svr_marginal" in columns(["e"], trial_mod.has_marginal(cont))
    assert "log_svr_marginal" not in columns(["e"], trial_mod.has_marginal(rot))


@pytest.mark.parametrize("args, words", [
    (["--param", "sigma=0.1"], "sigma is swept"),
    (["--sigmas", "0,0.1"], "must be finite and > 0"),
    (["--sigmas", "0.1,abc"], "comma-separated numbers"),
    (["--sigmas", "0.1,0.1"], "duplicate"),
    (["--sets", "primary,bogus"], "subset of primary,paper,discovered"),
    (["--trials", "0"], "at least 1 trial"),
    (["--jobs", "0"], "at least 1 worker"),
    (["--param", "M=0"], "M=0"),
    (["--sets", "primary,discovered", "--discovered", "missing.json"], "no discovered-set file"),
    (["--solver", "gurobi"], "unknown solver 'gurobi'"),
])
def test_bad_input_gives_one_line_errors(tmp_path, capsys, args, words):
    rc = main(["report", PROBLEM, "--out", str(tmp_path / "x"), "--no-progress", *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("autotight: error:") and words in err, err
    assert not (tmp_path / "x" / CSV_NAME).exists()


class _FakeSet:
    """Stands in for autotight.discovery.DiscoveredSet: re-instantiates n copies of primary constraints."""

    problem = PROBLEM

    def __init__(self, n: int):
        self.n = n

    @classmethod
    def load(cls, path):
        return cls(json.loads(Path(path).read_text())["n"])

    def save(self, path, model=None, constraints=None, extra=None):
        Path(path).write_text(json.dumps({"n": self.n}))

    def instantiate(self, problem, inst, rng, model=None):
        return (model or problem.build(inst)).primary()[1:1 + self.n]


def _fake_file(n: int) -> dict:
    """A file that passes the checks of a saved set (format, problem, pairs), read by _FakeSet."""
    return {"format": "autotight.discovered/1", "problem": PROBLEM, "pairs": [], "n": n}


@pytest.fixture
def fake_discovery(monkeypatch):
    calls = []

    def discover(problem, params, seed=0, **kw):
        calls.append((problem.name, params["sigma"], seed))
        return types.SimpleNamespace(discovered=_FakeSet(2), save=_FakeSet(2).save, summary=lambda: {})

    import autotight.api

    monkeypatch.setitem(sys.modules, "autotight.discovery", types.SimpleNamespace(DiscoveredSet=_FakeSet))
    monkeypatch.setattr(autotight.api, "discover", discover)  # the report runs discovery through the public API
    return calls


def test_discovered_set_from_a_file_is_instantiated_per_trial(tmp_path, fake_discovery):
    path = tmp_path / "set.json"
    path.write_text(json.dumps(_fake_file(3)))
    out = tmp_path / "d"
    s = run_sweep(_spec(sets="primary,discovered", trials=1, discovered=str(path)), out, progress=False)
    assert s.computed == 2 and fake_discovery == []
    df = load_trials(out)
    assert list(df["constraint_set"]) == ["primary", "discovered"] * 2
    assert list(df["n_constraints"]) == [34, 37] * 2
    meta = json.loads((out / "meta.json").read_text())
    assert meta["discovered"]["file"] == "set.json" and len(meta["discovered"]["sha256"]) == 64
    with pytest.raises(ReportError, match="holds a different sweep \\(sets:"):
        run_sweep(_spec(trials=1), out, progress=False)
    path.write_text(json.dumps(_fake_file(4)))  # another set: refused on resume
    with pytest.raises(ReportError, match="discovered"):
        run_sweep(_spec(sets="primary,discovered", trials=1, discovered=str(path)), out, progress=False)


def test_discovery_runs_once_and_its_set_is_saved_for_resume(tmp_path, fake_discovery):
    out = tmp_path / "d"
    spec = _spec(sets="discovered", trials=2)
    run_sweep(spec, out, limit=1, progress=False)
    s = run_sweep(spec, out, progress=False)
    assert (s.done_before, s.computed) == (1, 3)
    assert fake_discovery == [(PROBLEM, 0.1, 0)]  # at the problem's default σ, once
    assert json.loads((out / "discovered.json").read_text()) == {"n": 2}
    assert list(load_trials(out)["n_constraints"]) == [36] * 4


def test_trial_seeds_depend_only_on_base_seed_sigma_index_and_trial():
    seeds = {trial_seeds(0, i, t)[0] for i in range(3) for t in range(3)}
    assert len(seeds) == 9
    a, b = trial_seeds(7, 2, 5), trial_seeds(7, 2, 5)
    assert a[0] == b[0] and a[1].random() == b[1].random() and a[2].random() == b[2].random()
    assert trial_seeds(8, 2, 5)[0] != a[0]


def test_is_trapped_uses_the_stated_relative_tolerance():
    assert not is_trapped(100.0 * (1 + 5e-5), 100.0, 1e-4)
    assert is_trapped(100.0 * (1 + 2e-4), 100.0, 1e-4)
    assert is_trapped(float("inf"), 1.0, 1e-4)
    assert not is_trapped(1e-14, 0.0, 1e-4)  # a zero global cost: the slack is rtol × floor (1e-9)
    assert is_trapped(1e-12, 0.0, 1e-4)


def test_sigmas_default_sorted_and_validated():
    prob = load(PROBLEM)
    assert parse_sigmas(prob, None) == pytest.approx(tuple(np.logspace(-3, 0, 7)))
    assert parse_sigmas(prob, "1,0.001,0.1") == (0.001, 0.1, 1.0)
    with pytest.raises(ReportError):
        parse_sigmas(prob, "")


def test_a_failing_trial_is_recorded_and_reported(tmp_path, monkeypatch):
    real = trial_mod._solve

    def flaky(problem, spec, i, t, discovered):
        if (i, t) == (1, 0):
            raise AutotightError("boom\nsecond line")
        return real(problem, spec, i, t, discovered)

    monkeypatch.setattr(trial_mod, "_solve", flaky)
    out = tmp_path / "f"
    s = run_sweep(_spec(trials=1), out, jobs=1, progress=False)
    assert (s.computed, s.failed) == (2, 1)
    df = load_trials(out)
    bad = df[df["sigma_index"] == 1]
    assert list(bad["status"]) == ["Error: AutotightError: boom"] and bad["log_svr"].isna().all()
    assert (df[df["sigma_index"] == 0]["status"] == "Solved").all()
    _render(out)
    md = (out / "report.md").read_text()
    assert "## Solver statuses" in md and "| primary | 1 | 1 |" in md


def test_run_trial_is_reproducible():
    spec = _spec(trials=1)
    a, b = run_trial(spec, 1, 0), run_trial(spec, 1, 0)
    assert a.key == (1, 0) and [r["constraint_set"] for r in a.rows] == ["primary"]
    for ra, rb in zip(a.rows, b.rows):
        assert {k: v for k, v in ra.items() if k not in TIME_COLUMNS} == \
               {k: v for k, v in rb.items() if k not in TIME_COLUMNS}


def test_ctrl_c_keeps_finished_trials_and_the_rerun_resumes(tmp_path):
    out = tmp_path / "k"
    cmd = [sys.executable, "-m", "autotight.cli", "report", PROBLEM, "-p", "M=3", "--sigmas", "0.01,0.3",
           "--sets", "primary", "--trials", "40", "--jobs", "1", "--out", str(out), "--no-progress"]
    # a shell that runs pytest in the background passes SIGINT on as ignored; give the CLI the
    # disposition of an interactive terminal so that the signal is Ctrl-C
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    csv, deadline = out / CSV_NAME, time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        if csv.exists() and csv.read_text().count("\n") >= 1 + 3:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "re-run the same command to resume" in err
    saved = load_trials(out)
    done = len(saved)
    assert 3 <= done < 80
    s = run_sweep(_spec(trials=40), out, jobs=1, limit=1, progress=False)
    assert (s.done_before, s.computed) == (done, 1)
    again = load_trials(out)
    pd.testing.assert_frame_equal(again.iloc[: len(saved)].reset_index(drop=True), saved)


def test_two_saved_sets_in_one_sweep_are_named_by_their_files(tmp_path):
    """--sets primary,file:A.json,file:B.json: each saved set is its own set, named by its file's stem,
    recorded with its hash, and the command reproduces it; a third set with a clashing name is refused.
    The saved set: the committed one learned at M = 5 (one pair, with its template)."""
    saved = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "scale_set_pose_M5.json"
    a, b = tmp_path / "single.json", tmp_path / "again.json"
    shutil.copyfile(saved, a)
    shutil.copyfile(saved, b)
    spec = make_spec(load("pose_averaging"), "pose_averaging", {"M": 3}, sigmas="0.1", trials=1,
                     sets=f"primary,file:{a},file:{b}")
    assert spec.sets == ("primary", "single", "again")
    assert f"--sets primary,file:{a},file:{b}" in spec.command()
    out = tmp_path / "r"
    run_sweep(spec, out, jobs=1, progress=False)
    df = load_trials(out)
    assert list(df["constraint_set"]) == ["primary", "single", "again"]
    n = df.set_index("constraint_set")["n_constraints"]
    assert n["single"] == n["again"] > n["primary"]
    meta = json.loads((out / "meta.json").read_text())
    assert set(meta["files"]) == {"single", "again"} and len(meta["files"]["single"]["sha256"]) == 64
    # report.md: each set's constraints beyond h² and the primary ones, and its pairs (read from the
    # file only while its hash is the sweep's)
    k = len(json.loads(a.read_text())["pairs"])
    pairs = f"{k} pair{'s' if k != 1 else ''}"
    render(out, meta)
    md = (out / "report.md").read_text()
    assert f"| primary | {n['primary']} | 0 | – |" in md
    assert f"| single | {n['single']} | {n['single'] - n['primary']} | {pairs} |" in md
    assert f"| again | {n['again']} | {n['again'] - n['primary']} | {pairs} |" in md
    b.write_text(b.read_text().replace('"pairs"', '"pairs_"', 1))
    render(out, meta)
    md = (out / "report.md").read_text()
    assert f"| single | {n['single']} | {n['single'] - n['primary']} | {pairs} |" in md
    assert f"| again | {n['again']} | {n['again'] - n['primary']} | – |" in md
    with pytest.raises(ReportError, match="saved set"):
        make_spec(load("pose_averaging"), "pose_averaging", {"M": 3}, sets=f"primary,file:{tmp_path}/paper.json")


def test_against_the_paper_table_reads_our_fractions_and_the_module_claim():
    """The "Against the paper" rows: our tight and trapped fractions and the median log SVR on the
    marginalised X for the claim's set, beside the claim's text for that σ (or its default)."""
    from autotight.report.render import paper_table, tables

    df = pd.DataFrame({"sigma_index": [0, 0, 1, 1], "trial": [0, 1, 0, 1], "constraint_set": ["paper"] * 4,
                       "tight": [True, False, True, True], "trapped": [False, False, True, False],
                       "log_svr": [9.0, 1.0, 8.0, 6.0], "log_svr_marginal": [7.0, 0.5, 6.5, 5.5],
                       "status": ["Solved"] * 4, "n_constraints": [10] * 4})
    claim = {"source": "Fig. 11", "set": "paper", "by_sigma": {0.001: "lower"}, "default": "above 5"}
    t = paper_table(df, [0.001, 0.1], claim)
    assert t.header[2] == "median log SVR (marginalised X)"
    assert t.rows == [["0.001", "0.50", "3.8", "0.00", "lower"], ["0.1", "1.00", "6.0", "0.50", "above 5"]]
    assert paper_table(df, [0.001, 0.1], dict(claim, set="other")) is None
    svr = next(x for x in tables(df.assign(**{c: 0.0 for c in ("sdp_time_s", "local_truth_time_s",
                                                                "local_random_time_s")},
                                           outcome="tight", rank_tight=True, cost_tight=True, certified=True,
                                           undecided=False, sdp_beats_local=False),
                                 [0.001, 0.1], ["paper"]) if x.title == "Median log SVR")
    assert svr.header == ["σ", "paper", "paper (marginalised X)"] and svr.rows[0] == ["0.001", "5.0", "3.8"]


def test_the_tight_rule_follows_the_acceptance():
    from autotight.report.render import tight_rule

    crit = {"min_log_svr": 5.0, "gap_tol": 1e-5}
    head, caption, figure = tight_rule(crit | {"accept": "cost"})
    assert "certificate" in head and "log SVR" not in head and "rank is not required" in caption
    assert "certified" in figure and "rank d" not in figure
    head, caption, figure = tight_rule(crit | {"accept": "rank"})
    assert head.startswith("log SVR > 5 and the cost bracket within 1e-05") and "rank-d threshold" in caption
    assert figure.startswith("Fraction of SDP solves judged tight (rank d")
    assert "certified" in tight_rule(crit | {"accept": "certified"})[1]
