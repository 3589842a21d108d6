"""The soundness audit's cases, one parametrised test per kind so that the count is visible.

- ``test_cli_refuses``: bad input at the command line is one line ``autotight: error: …``, exit 2, and writes
  nothing; a count or size that cannot fit is refused within ``FAST_S`` seconds;
- ``test_api_refuses``: the same input in Python raises an ``AutotightError`` subclass;
- ``test_check_module_fails``: a module with one broken part fails ``check-module`` (exit 1) with a FAIL
  line naming the check, instead of a traceback or a PASS;
- the rest: failed or ill-conditioned solves are never "not tight" with exit 0, outputs never replace a
  file, report folders of unrelated files are refused.

Every case runs in-process (``autotight.cli.main``) on rotation averaging with M = 2 or 3.
"""

from __future__ import annotations

import copy
import json
import os
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import autotight as at
from autotight.cli import main
from autotight.errors import AutotightError

P = "rotation_averaging"
SMALL = ["-p", "M=2"]
#: a refusal must come within this many seconds (sizes and counts are estimated, never run)
FAST_S = 5.0

HEAD = """
from problems.rotation_averaging import *  # noqa: F401,F403
import problems.rotation_averaging as ra
import numpy as np
from autotight.problem import LocalResult, Meta
NAME = "ra_broken"
"""

#: rotation averaging with one part changed: name → the module's extra text
BROKEN = {
    "constant_sampler": "def sample(inst, rng, nominal, spread):\n    return dict(nominal)\n",
    "fixed_sampler": "def sample(inst, rng, nominal, spread):\n"
                     "    return ra.sample(inst, np.random.default_rng(7), nominal, spread)\n",
    "lazy_local": "def local_solve(inst, init, **kw):\n"
                  "    return LocalResult(dict(init), ra.cost(inst, init), 0, True)\n",
    "errors_array": "def errors(inst, state):\n    return {'a': np.ones(2)}\n",
    "errors_text": "def errors(inst, state):\n    return {'a': 'x'}\n",
    "marginal_text": "def marginal_log_svr(inst, X, cliques):\n    return 'x'\n",
    "random_state_int": "def random_state(inst, rng):\n    return 5\n",
    "sigmas_text": "META = Meta(sigmas='abc')\n",
    "sigmas_int": "META = Meta(sigmas=5)\n",
    "sigmas_negative": "META = Meta(sigmas=[0.1, -1.0])\n",
    "claim_text": "META = Meta(paper_claim='the paper')\n",
    "claim_by_sigma_key": "META = Meta(paper_claim={'by_sigma': {'x': 'text'}})\n",
    "claim_by_sigma_list": "META = Meta(paper_claim={'by_sigma': [1]})\n",
    "carry_bogus": "META = Meta(carry_to={'K': 200})\n",
    "groups_int": "META = Meta(default_groups=5)\n",
    "carry_unknown_param": "META = Meta(carry_to={'params': {'bogus': 3}})\n",
    "check_params_bad": "META = Meta(check_params={'M': -1})\n",
    "weight_nan": "def generate(params, rng):\n    inst = ra.generate(params, rng)\n"
                  "    inst.measurements['W'][0] *= np.nan\n    return inst\n",
    "weight_1e30": "def generate(params, rng):\n    inst = ra.generate(params, rng)\n"
                   "    inst.measurements['W'][0] *= 1e30\n    return inst\n",
}


@pytest.fixture(scope="module")
def mods(tmp_path_factory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("mods")
    out = {}
    for name, body in BROKEN.items():
        p = folder / f"ra_{name}.py"
        p.write_text(textwrap.dedent(HEAD) + body, encoding="utf-8")
        out[name] = str(p)
    return out


#: a well-formed set file for rotation averaging (one polynomial template), mutated by the set cases
BASE_SET = {
    "format": "autotight.constraint_set/2", "problem": P, "params": {"M": 2, "sigma": 0.1, "anisotropy": 1.0},
    "seed": 0, "learn_options": {}, "groups": "factors", "info": {}, "d": 1,
    "pairs": [{"factor_type": "rotation_meas", "identity": "q0"}],
    "templates": [{"kind": "polynomial", "factor_type": "rotation_meas", "identities": ["q0"],
                   "roles": ["h", "c1", "c2", "c3", "phi"], "block_sizes": [1, 3, 3, 3, 3], "n_data": 2,
                   "degree": 0, "support": [0], "W": [[1.0]]}],
    "fallback": {},
}


def _mutated(change) -> dict:
    obj = copy.deepcopy(BASE_SET)
    change(obj)
    return obj


#: set-file mutations: name → (change, words of the error)
SETS = {
    "pairs_empty_templates_kept": (lambda o: o.update(pairs=[]), "does not list"),
    "nan_in_W": (lambda o: o["templates"][0].update(W=[[float("nan")]]), "finite"),
    "kind_bogus": (lambda o: o["templates"][0].update(kind="bogus"), "kind"),
    "degree_7": (lambda o: o["templates"][0].update(degree=7), "degree"),
    "seed_text": (lambda o: o.update(seed="abc"), "'seed'"),
    "heldout_tol_one": (lambda o: o.update(learn_options={"heldout_tol": 1.0}), "heldout_tol"),
    "heldout_tol_huge": (lambda o: o.update(learn_options={"heldout_tol": 1e300}), "heldout_tol"),
    "templates_object": (lambda o: o.update(templates={"a": 1}), "'templates'"),
    "info_list": (lambda o: o.update(info=[]), "'info'"),
    "template_number": (lambda o: o.update(templates=[5]), "template 0"),
    "support_out_of_range": (lambda o: o["templates"][0].update(support=[10 ** 6]), "support"),
    "fallback_list": (lambda o: o.update(fallback=[]), "'fallback'"),
}


def _set_file(tmp_path: Path, name: str) -> str:
    change, _ = SETS[name]
    p = tmp_path / f"{name}.json"
    p.write_text(json.dumps(_mutated(change)), encoding="utf-8")
    return str(p)


def _report(out: Path, *extra: str) -> list[str]:
    return ["report", P, *SMALL, "--trials", "1", "--sigmas", "0.1", "--out", str(out), "--no-progress", "-j", "1",
            *extra]


def _cli_cases(tmp: Path, mods: dict[str, str]) -> dict[str, tuple[list[str], str, Path | None]]:
    """id → (argv, a word of the one-line error, a folder that must stay untouched or None)."""
    r = tmp / "reports"
    return {
        "duplicate_param": (["solve", P, "-p", "M=3", "-p", "M=4"], "given twice", None),
        "skip_invalid_without_file": (["solve", P, *SMALL, "--skip-invalid"], "--skip-invalid", None),
        "empty_solver": (["solve", P, *SMALL, "--solver", ""], "--solver", None),
        "samples_zero": (["check-module", P, "--samples", "0"], "--samples", None),
        "samples_negative": (["check-module", P, "--samples", "-1"], "--samples", None),
        "samples_huge": (["check-module", P, *SMALL, "--samples", "100000000"], "would take", None),
        "random_starts_huge": (["solve", P, *SMALL, "--random-starts", "1000000"], "would take", None),
        "check_instances_huge": (["check", P, *SMALL, "--instances", "100000000"], "would take", None),
        "check_instances_zero": (["check", P, *SMALL, "--instances", "0"], "--instances", None),
        "check_size_huge": (["check", P, "-p", "M=100000000", "--instances", "1"], "memory", None),
        "certify_size_huge": (["certify", P, "-p", "M=100000000"], "memory", None),
        "discover_train_huge": (["discover", P, *SMALL, "--train", "100000000", "--no-progress"], "would take", None),
        "discover_train_zero": (["discover", P, *SMALL, "--train", "0", "--no-progress"], "--train", None),
        "report_jobs_zero": (_report(r / "j0", "--jobs", "0"), "--jobs", r / "j0"),
        "report_limit_negative": (_report(r / "l", "--limit", "-1"), "--limit", r / "l"),
        "discovered_without_set": (_report(r / "d", "--discovered", str(tmp / "x.json")), "--discovered", r / "d"),
        "anisotropy_1e6": (["solve", P, "-p", "M=3", "-p", "anisotropy=1e6"], "condition number", None),
        "weight_1e30_solve": (["solve", mods["weight_1e30"], *SMALL], "condition number", None),
        "weight_1e30_certify": (["certify", mods["weight_1e30"], *SMALL], "condition number", None),
        "weight_nan_certify": (["certify", mods["weight_nan"], *SMALL], "NaN", None),
        "errors_array_solve": (["solve", mods["errors_array"], *SMALL], "errors returned", None),
        "marginal_text_solve": (["solve", mods["marginal_text"], *SMALL], "marginal_log_svr", None),
        "carry_bogus_discover": (["discover", mods["carry_bogus"], *SMALL, "--heldout", "1", "--no-progress"],
                                 "META.carry_to", None),
        "groups_int_discover": (["discover", mods["groups_int"], *SMALL, "--heldout", "1", "--no-progress"],
                                "META.default_groups", None),
        "sigmas_text_report": (["report", mods["sigmas_text"], *SMALL, "--trials", "1", "--out", str(r / "s1"),
                                "--no-progress", "-j", "1"], "META.sigmas", r / "s1"),
        "sigmas_int_report": (["report", mods["sigmas_int"], *SMALL, "--trials", "1", "--out", str(r / "s2"),
                               "--no-progress", "-j", "1"], "META.sigmas", r / "s2"),
        "claim_text_report": (["report", mods["claim_text"], *SMALL, "--trials", "1", "--sigmas", "0.1", "--out",
                               str(r / "c1"), "--no-progress", "-j", "1"], "META.paper_claim", r / "c1"),
        "claim_key_report": (["report", mods["claim_by_sigma_key"], *SMALL, "--trials", "1", "--sigmas", "0.1",
                              "--out", str(r / "c2"), "--no-progress", "-j", "1"], "META.paper_claim", r / "c2"),
        **{f"set_{name}": (["solve", P, *SMALL, "--set", str(tmp / f"{name}.json")], words, None)
           for name, (_, words) in SETS.items()},
    }


CLI_IDS = sorted(_cli_cases(Path("/nonexistent"), {k: "" for k in BROKEN}))


@pytest.mark.parametrize("case", CLI_IDS)
def test_cli_refuses(case, mods, tmp_path, capsys):
    argv, word, folder = _cli_cases(tmp_path, mods)[case]
    if case.startswith("set_"):
        _set_file(tmp_path, case.removeprefix("set_"))
    t0 = time.perf_counter()
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse's own refusals
        rc = e.code
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err.strip()
    assert rc == 2, (rc, err)
    assert "Traceback" not in err and len(err.splitlines()) == 1 and err.startswith("autotight: error:"), err
    assert word in err, err
    if "huge" in case:  # a count or size that cannot fit: estimated, never started
        assert seconds < FAST_S, seconds
    if folder is not None:
        assert not folder.exists()  # nothing written


def test_the_base_set_file_is_accepted(tmp_path):
    """The set cases above differ from an accepted file by one field each."""
    from autotight.set_file import check_set_file

    p = tmp_path / "base.json"
    p.write_text(json.dumps(BASE_SET), encoding="utf-8")
    assert check_set_file(p)["pairs"] == BASE_SET["pairs"]
    assert at.ConstraintSet.load(p).pairs == [("rotation_meas", "q0")]


def _api_cases(tmp: Path):
    from autotight.tightness import Criteria

    (tmp / "file").write_text("x")
    return {
        "params_string": lambda: at.solve(P, "M=3"),
        "solver_unknown": lambda: at.solve(P, {"M": 2}, solver="bogus"),
        "solver_wrong_type": lambda: at.solve(P, {"M": 2}, solver=5),
        "n_random_string": lambda: at.solve(P, {"M": 2}, n_random="2"),
        "n_random_negative": lambda: at.solve(P, {"M": 2}, n_random=-3),
        "n_random_huge": lambda: at.solve(P, {"M": 2}, n_random=10 ** 8),
        "bool_as_int": lambda: at.solve(P, {"M": True}),
        "criteria_accept": lambda: Criteria(accept="bogus"),
        "criteria_nan": lambda: Criteria(gap_tol=float("nan")),
        "criteria_wrong_type": lambda: at.solve(P, {"M": 2}, criteria="cost"),
        "discover_unknown_option": lambda: at.discover(P, {"M": 2}, bogus=1),
        "discover_max_rounds_zero": lambda: at.discover(P, {"M": 2}, max_rounds=0),
        "discover_heldout_negative": lambda: at.discover(P, {"M": 2}, n_heldout=-1),
        "discover_train_huge": lambda: at.discover(P, {"M": 2}, n_train=10 ** 8),
        "certify_params_string": lambda: at.certify(P, "M=3"),
        "certify_size_huge": lambda: at.certify(P, {"M": 100000000}),
        "solve_size_huge": lambda: at.solve(P, {"M": 100000000}),
        "check_instances_string": lambda: at.check_sufficient(P, "primary", instances="2"),
        "save_to_folder": lambda: at.ConstraintSet.load(_base(tmp)).save(tmp),
        "save_inside_a_file": lambda: at.ConstraintSet.load(_base(tmp)).save(tmp / "file" / "x.json"),
        "load_bad_set": lambda: at.ConstraintSet.load(_set_file(tmp, "nan_in_W")),
    }


def _base(tmp: Path) -> Path:
    p = tmp / "base.json"
    p.write_text(json.dumps(BASE_SET), encoding="utf-8")
    return p


API_IDS = ["params_string", "solver_unknown", "solver_wrong_type", "n_random_string", "n_random_negative",
           "n_random_huge", "bool_as_int", "criteria_accept", "criteria_nan", "criteria_wrong_type",
           "discover_unknown_option", "discover_max_rounds_zero", "discover_heldout_negative", "discover_train_huge",
           "certify_params_string", "certify_size_huge", "solve_size_huge", "check_instances_string",
           "save_to_folder", "save_inside_a_file", "load_bad_set"]


@pytest.mark.parametrize("case", API_IDS)
def test_api_refuses(case, tmp_path):
    fn = _api_cases(tmp_path)[case]
    t0 = time.perf_counter()
    with pytest.raises(AutotightError) as e:
        fn()
    assert time.perf_counter() - t0 < FAST_S
    assert str(e.value) and "\n" not in str(e.value).strip()


def test_api_takes_a_solver_name():
    """solver="ipm" is the IPM, as ``--solver ipm``."""
    out = at.solve(P, {"M": 2}, 1, solver="ipm")
    assert out.sdp.solver.startswith("autotight-ipm") or "ipm" in out.sdp.solver
    assert out.sdp.usable and abs(out.sdp.primal_cost - out.upper) <= 1e-5 * abs(out.upper)


#: module → (the FAIL line's check, a word of it)
CHECK_MODULE = {
    "constant_sampler": ("sample-spread", "span only 0"),
    "fixed_sampler": ("sample-spread", "span only 1"),
    "lazy_local": ("local-descent-perturbed", "does not descend"),
    "errors_array": ("errors", "errors returned"),
    "errors_text": ("errors", "errors returned"),
    "marginal_text": ("marginal_log_svr", "returned str"),
    "random_state_int": ("random-state", "random_state returned"),
    "sigmas_text": ("META.sigmas", "non-empty list"),
    "sigmas_int": ("META.sigmas", "non-empty list"),
    "sigmas_negative": ("META.sigmas", "> 0"),
    "claim_text": ("META.paper_claim", "must be a dict"),
    "claim_by_sigma_key": ("META.paper_claim", "by_sigma"),
    "claim_by_sigma_list": ("META.paper_claim", "by_sigma"),
    "carry_bogus": ("META.carry_to", "must be"),
    "groups_int": ("META.default_groups", "factors"),
    "carry_unknown_param": ("META.carry_to", "is invalid"),
    "check_params_bad": ("META.check_params", "M=-1"),
    "weight_nan": ("data", "NaN"),
    "weight_1e30": ("data", "condition number"),
}


@pytest.mark.parametrize("name", sorted(CHECK_MODULE))
def test_check_module_fails(name, mods, capsys):
    check, word = CHECK_MODULE[name]
    argv = ["check-module", mods[name]] + ([] if name == "check_params_bad" else SMALL)
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 1 and "Traceback" not in out + err, (rc, out, err)
    fails = [ln for ln in out.splitlines() if ln.startswith(f"FAIL {check}")]
    assert fails and any(word in ln for ln in fails), out


def test_a_shipped_module_passes_the_new_checks(capsys):
    """The new checks read the truth's variety dimension and the spread of real samples."""
    rc = main(["check-module", P, *SMALL, "--json"])
    rec = json.loads(capsys.readouterr().out)
    assert rc == 0 and rec["ok"], rec["failures"]
    m = rec["measurements"]
    assert m["variety_dimension"] == 3 and m["sample_spread_rank"] >= 3  # SO(3): φ_m follow from C
    assert m["cost_from_random_start"] < m["cost_random_start"]


def test_check_without_set_runs(capsys):
    """``autotight check PROBLEM`` without --set: the default set, no crash."""
    rc = main(["check", P, *SMALL, "--instances", "1"])
    out = capsys.readouterr().out
    assert rc in (0, 1) and "set primary" in out


# -- ill-conditioned and failed solves: never "not tight" with exit 0 ---------------------------------------
def _res(P_: float, D: float, status: str = "Solved", svr: float = 10.0, scale: float = 1.0):
    from autotight.sdp.result import SDPResult

    X = np.diag([1.0, 10.0 ** -svr])
    return SDPResult(status=status, solver="test", d=1, X=X, y=np.zeros(1), primal_cost=P_, dual_cost=D,
                     solve_time_s=0.0, cost_scale=scale)


@pytest.mark.parametrize("accept", ["rank", "cost"])
def test_a_tolerance_above_the_cost_decides_nothing(accept):
    """s = 1e12 makes tol = 1e-9·s = 1e3 exceed U = 3.49; the solve's value P = −727 lies below U by less than
    tol: neither the closed bracket nor a gap is evidence (anisotropy 1e6, M = 3 before it was refused)."""
    from autotight.tightness import Criteria, judge

    v = judge(_res(-727.0, -727.0, "AlmostSolved", svr=0.6, scale=1e12), 3.49, Criteria(accept=accept))
    assert v.outcome == "undecided" and not v.tight and "exceeds the cost" in v.reason, v


@pytest.mark.parametrize("case", ["tolerance_above_cost", "almost_solved_low_rank", "unusable"])
def test_a_verdict_without_evidence_is_undecided(case):
    from autotight.tightness import Criteria, judge

    c = Criteria()
    if case == "tolerance_above_cost":  # s = 1e12: tol = 1e-9·s = 1e3 > U = 3.49 (anisotropy 1e6, M = 3)
        v = judge(_res(336.9, 3.49, "AlmostSolved", svr=0.6, scale=1e12), 3.49, c)
        assert "exceeds the cost" in v.reason
    elif case == "almost_solved_low_rank":  # a bracket inside tolerance, X of rank 2, solver stopped early
        v = judge(_res(21.5858, 21.5138, "AlmostSolved", svr=3.7, scale=3.5e8), 21.5273, c)
    else:
        from autotight.sdp.result import SDPResult

        v = judge(SDPResult(status="NumericalError", solver="test", d=1, X=None, y=None, primal_cost=float("nan"),
                            dual_cost=float("nan"), solve_time_s=0.0), 1.0, c)
    assert v.outcome == "undecided" and not v.tight, v


def test_a_failed_solve_exits_2(monkeypatch, capsys):
    """An SDP that returns no usable X is a one-line error, never NOT TIGHT with exit 0."""
    from autotight import pipeline
    from autotight.sdp.result import SDPResult

    def failed(model, cons, config, scale=None, stop=None, settled=None):
        return SDPResult(status="NumericalError", solver="test", d=1, X=None, y=None, primal_cost=float("nan"),
                         dual_cost=float("nan"), solve_time_s=0.0)

    monkeypatch.setattr(pipeline.sdp, "solve_model", failed)
    rc = main(["solve", P, *SMALL])
    cap = capsys.readouterr()
    assert rc == 2 and "SDP solve failed" in cap.err and "NOT TIGHT" not in cap.out


# -- outputs ---------------------------------------------------------------------------------------------
def test_save_never_replaces_a_file(tmp_path):
    """A set saved over an existing file keeps that file and lands beside it, with a warning saying where."""
    cs = at.ConstraintSet.load(_base(tmp_path))
    target = tmp_path / "set.json"
    target.write_text("mine")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        written = cs.save(target)
    assert target.read_text() == "mine" and written == tmp_path / "set.1.json" and written.is_file()
    assert any(str(written) in str(w.message) for w in caught)
    assert at.ConstraintSet.load(written).pairs == cs.pairs
    assert cs.save(target, replace=True) == target and json.loads(target.read_text())["pairs"]


def test_discover_out_that_appears_during_the_run_is_kept(tmp_path, monkeypatch, capsys):
    """discover --out X: a file that appears at X while discovery runs is kept; the set goes beside it."""
    import autotight.cli.discover as dcli

    out = tmp_path / "set.json"
    real = dcli.discover

    def racing(*a, **k):
        res = real(*a, **k)
        out.write_text("someone else's")
        return res

    monkeypatch.setattr(dcli, "discover", racing)
    rc = main(["discover", P, *SMALL, "--heldout", "1", "--no-progress", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0 and out.read_text() == "someone else's"
    beside = tmp_path / "set.1.json"
    assert beside.is_file() and f"saved to {beside}" in cap.out and "is kept" in cap.err


def test_outputs_get_the_users_umask(tmp_path):
    from autotight.io import atomic_write_text

    old = os.umask(0o027)
    try:
        p = atomic_write_text(tmp_path / "a.txt", "x", replace=False)
    finally:
        os.umask(old)
    assert (p.stat().st_mode & 0o777) == 0o640


def test_report_refuses_a_folder_of_unrelated_files(tmp_path, capsys):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("keep me")
    rc = main(_report(folder))
    err = capsys.readouterr().err
    assert rc == 2 and "files no report wrote" in err
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]


def test_report_jobs_are_capped_and_bad_csv_bytes_are_repaired(tmp_path, capsys):
    """--jobs 1000 runs with at most the cores and trials (a note says so); a trials.csv with bytes that are
    not UTF-8 drops the damaged line and recomputes that trial."""
    out = tmp_path / "r"
    assert main(_report(out, "--jobs", "1000")) == 0
    assert "capped" in capsys.readouterr().err
    with open(out / "trials.csv", "ab") as f:
        f.write(b"\xff\xfe\x00damaged\n")
    assert main([*_report(out)[:-2], "--trials", "2", "-j", "1"]) == 0
    text = (out / "trials.csv").read_bytes()
    assert b"\xff" not in text and text.count(b"\n") == 3  # header and two trials
