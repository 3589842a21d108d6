"""Bad input through the command line: one line ``autotight: error: …``, exit 2, nothing written.

Every case runs the CLI in a process of its own.  Most cases share one driver subprocess that
imports autotight once and forks a child per case (each child runs ``autotight.cli.main`` with
its own stderr, working folder and exit status, like ``python -m autotight.cli``); the cases that
time hangs, kill processes or need a real entry point run ``python -m autotight.cli`` directly.
For every error case: exit status 2, exactly one stderr line starting ``autotight: error:``, no
traceback, no new file under ``--out``, and files that were there are byte-identical.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from autotight.report.spec import make_spec
from autotight.report.store import CSV_NAME, load_trials
from autotight.report.sweep import run_sweep
from autotight.problem import load
from trials_equal import assert_same_trials

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
SMALL = ["-p", "M=2"]
REPORT = ["report", "rotation_averaging", "-p", "M=2", "--sigmas", "0.1", "--trials", "1", "--sets", "primary",
          "--jobs", "1", "--no-progress"]
#: a hang case must end (with its error) within this many seconds
HANG_S = 10.0

# -- broken problem modules: rotation_averaging.py with one part replaced --------------------------------
#: each variant renames the original function to _orig_NAME and appends this replacement
VARIANTS = {
    "generate_returns_dict": ("generate", "def generate(params, rng):\n    return {'M': params['M']}\n"),
    "local_solve_returns_none": ("local_solve", "def local_solve(inst, init, **options):\n    return None\n"),
    "generate_raises_keyerror": ("generate", "def generate(params, rng):\n"
                                             "    p = {k: v for k, v in params.items() if k != 'M'}\n"
                                             "    return _orig_generate(p, rng)\n"),
    "errors_returns_str": ("errors", "def errors(inst, state):\n    return 'about one degree'\n"),
    "recover_raises_typeerror": ("recover", "def recover(inst, Theta):\n    raise TypeError('Theta must be 2-D')\n"),
    "sample_raises_runtimeerror": ("sample", "def sample(inst, rng, nominal, spread):\n"
                                             "    raise RuntimeError('no valid sample')\n"),
    "lift_wrong_length": ("lift", "def lift(inst, state):\n    return _orig_lift(inst, state)[:-3]\n"),
    # item 3: data and costs
    "weights_nan": ("generate", "def generate(params, rng):\n    inst = _orig_generate(params, rng)\n"
                                "    inst.measurements['W'][0, 0, 0] = np.nan\n    return inst\n"),
    "q_inf": ("build", "def build(inst):\n    model = _orig_build(inst)\n    f = model.factors[-1]\n"
                       "    f.cost = f.cost * np.inf\n    return model\n"),
    "local_cost_nan": ("local_solve", "def local_solve(inst, init, **options):\n"
                                      "    r = _orig_local_solve(inst, init, **options)\n    r.cost = float('nan')\n"
                                      "    return r\n"),
    "local_cost_wrong": ("local_solve", "def local_solve(inst, init, **options):\n"
                                        "    r = _orig_local_solve(inst, init, **options)\n"
                                        "    r.cost = 2 * r.cost + 1.0\n    return r\n"),
}


def broken_module(folder: Path, variant: str) -> Path:
    """problems/rotation_averaging.py with the part of ``variant`` replaced (importable by path): the original
    kept as ``_orig_PART``, the replacement defined after it."""
    part, body = VARIANTS[variant]
    src = (ROOT / "problems" / "rotation_averaging.py").read_text(encoding="utf-8")
    src = src.replace("from ._", "from problems._")  # relative imports of the package's helpers
    # the part is a function of the module or one of the names derive() returns
    assert re.search(rf"^(def {part}\(|(\w+, )*{part}(, \w+)* = )", src, flags=re.M), (variant, part)
    path = folder / f"ra_{variant}.py"
    path.write_text(src + f"\n\n_orig_{part} = {part}\n\n" + body, encoding="utf-8")
    return path


# -- the driver: one subprocess, one forked child per case -------------------------------------------------
DRIVER = r"""
import json, os, sys, time, traceback
import numpy, scipy, pandas, matplotlib, cvxpy  # imported once, before forking
try:
    import distributed  # the dask extra, when installed
except ImportError:
    pass
import autotight.cli, autotight.report.render, autotight.report.sweep, autotight.discovery.engine
import problems.rotation_averaging
cases, parallel = json.load(open(sys.argv[1])), int(sys.argv[3])
results, running = {}, {}


def start(case):
    err_path = sys.argv[2] + "." + case["id"] + ".err"
    sys.stdout.flush(); sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        rc = 1
        try:
            os.chdir(case["cwd"])
            os.dup2(os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 2)
            os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
            try:
                rc = autotight.cli.main(case["argv"])
            except SystemExit as e:
                rc = e.code if isinstance(e.code, int) else 1
            except BaseException:
                traceback.print_exc()
            sys.stdout.flush(); sys.stderr.flush()
        finally:
            os._exit(rc)
    running[pid] = (case, err_path, time.time())


def reap():
    for pid, (case, err_path, t0) in list(running.items()):
        done, status = os.waitpid(pid, os.WNOHANG)
        rc = os.waitstatus_to_exitcode(status) if done else None
        if not done and time.time() - t0 > case.get("timeout", 60):
            os.kill(pid, 9); os.waitpid(pid, 0); rc = "timeout"
        if rc is not None:
            del running[pid]
            results[case["id"]] = {"rc": rc, "stderr": open(err_path).read(), "seconds": time.time() - t0}


for case in cases:
    while len(running) >= parallel:
        reap(); time.sleep(0.01)
    start(case)
while running:
    reap(); time.sleep(0.01)
json.dump(results, open(sys.argv[2], "w"))
"""


def _files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path → bytes); {} when it does not exist."""
    if not folder.exists():
        return {}
    if folder.is_file():
        return {"": folder.read_bytes()}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _uninstalled_cvxpy_solver() -> str:
    import cvxpy

    return next(s for s in ("MOSEK", "GUROBI", "COPT", "XPRESS", "NOPE") if s not in cvxpy.installed_solvers())


MODULE_CASES = [("generate_returns_dict", "generate", "dict"), ("local_solve_returns_none", "local_solve", "None"),
                ("generate_raises_keyerror", "generate", "KeyError"), ("errors_returns_str", "errors", "str"),
                ("recover_raises_typeerror", "recover", "TypeError"),
                ("sample_raises_runtimeerror", "sample", "RuntimeError"), ("lift_wrong_length", "lift", "lift")]
DATA_CASES = [("weights_nan", ("measurement 'W'", "NaN")), ("q_inf", ("cost matrix Q", "inf")),
              ("local_cost_nan", ("local solve", "nan")), ("local_cost_wrong", ("differs from", "lift"))]
OPTION_CASES = [("--min-gap", "-1"), ("--min-gap", "nan"), ("--gap-tol", "inf"), ("--gap-tol", "-1e-5"),
                ("--heldout", "-2"), ("--heldout", "inf")]
BAD_SETS = {"list": ([1, 2], "JSON object"),
            "no_pairs": ({"format": "autotight.discovered/1", "problem": "rotation_averaging"}, "pairs"),
            "no_problem": ({"format": "autotight.discovered/1", "pairs": []}, "problem"),
            "unknown_option": ({"format": "autotight.discovered/1", "problem": "rotation_averaging", "pairs": [],
                                "learn_options": {"sample_factor": 2.0, "warp_speed": 9}}, "warp_speed")}


def _cases(base: Path) -> list[dict]:
    """Every batched case: id, argv, cwd, words its error line must hold, the --out to watch.
    Pure: the files the cases use are made by ``_setup(base)``."""
    mods, files, sweeps = base / "modules", base / "files", base / "sweeps"
    cases: list[dict] = []

    def add(id_: str, argv: list, *words: str, out: Path | None = None, cwd: Path = base, **kw) -> None:
        cases.append({"id": id_, "argv": [str(a) for a in argv], "words": list(words),
                      "out": None if out is None else str(out), "cwd": str(cwd), **kw})

    def mod(variant: str) -> Path:
        return mods / f"ra_{variant}.py"

    # item 1: errors inside a user's problem module (the module, the part and the exception are named)
    for variant, part, exc in MODULE_CASES:
        add(f"module_{variant}_solve", ["solve", mod(variant), *SMALL], part, exc)
    add("module_generate_returns_dict_report", ["report", mod("generate_returns_dict"), *REPORT[2:],
                                                "--out", sweeps / "m1"], "generate", out=sweeps / "m1")
    add("module_sample_raises_discover", ["discover", mod("sample_raises_runtimeerror"), *SMALL, "--heldout", "1",
                                          "--no-progress", "--out", files / "m2.json"],
        "sample", "RuntimeError", out=files / "m2.json")
    add("module_path_not_py", ["solve", mods / "rotation.txt", *SMALL], "rotation.txt")

    # item 2: output paths, checked before the work; nothing overwritten without being asked
    afile = files / "a_file"
    add("discover_out_proc", ["discover", "rotation_averaging", *SMALL, "--out", "/proc/x.json"], "/proc",
        out=Path("/proc/x.json"), timeout=HANG_S)
    add("discover_out_inside_file", ["discover", "rotation_averaging", *SMALL, "--out", afile / "x.json"],
        "is a file", out=afile)
    add("discover_out_is_folder", ["discover", "rotation_averaging", *SMALL, "--out", files], "folder", out=files)
    add("discover_out_exists", ["discover", "rotation_averaging", *SMALL, "--out", files / "existing.json"],
        "--force", out=files / "existing.json")
    add("report_out_is_file", [*REPORT, "--out", afile], "is a file", out=afile)
    add("report_out_inside_file", [*REPORT, "--out", afile / "sub"], "is a file", out=afile)
    add("report_other_sweep", [*REPORT, "--out", sweeps / "other"], "different sweep", out=sweeps / "other")
    add("report_foreign_report_md", [*REPORT, "--out", sweeps / "notes"], "report.md", out=sweeps / "notes")

    # ... and `report` without --out, run in a repository root, writes out/PROBLEM, never reports/PROBLEM
    add("report_default_out", REPORT, out=base / "repo" / "reports", cwd=base / "repo", ok=True)

    # item 3: failed solves are failures
    add("solve_solver_nope", ["solve", "rotation_averaging", *SMALL, "--solver", "cvxpy:NOPE"], "NOPE")
    other = _uninstalled_cvxpy_solver()
    add("solve_solver_uninstalled", ["solve", "rotation_averaging", *SMALL, "--solver", f"cvxpy:{other}"], other)
    add("report_solver_nope", [*REPORT, "--solver", "cvxpy:NOPE", "--out", sweeps / "s1"], "NOPE",
        out=sweeps / "s1")
    for variant, words in DATA_CASES:
        add(f"{variant}_solve", ["solve", mod(variant), *SMALL], *words)
    add("local_cost_wrong_discover", ["discover", mod("local_cost_wrong"), *SMALL, "--no-progress",
                                      "--out", files / "d3.json"], "differs from", out=files / "d3.json")
    add("weights_nan_report_all_failed", ["report", mod("weights_nan"), *REPORT[2:], "--out", sweeps / "f1"],
        "every trial failed", "measurement 'W'", out=sweeps / "f1")

    # item 4: limits and validation
    for opt, value in OPTION_CASES:
        add(f"discover_{opt[2:]}_{value}", ["discover", "rotation_averaging", *SMALL, opt, value,
                                            "--out", files / "v.json"], opt, out=files / "v.json")
    add("solve_random_starts_negative", ["solve", "rotation_averaging", *SMALL, "--random-starts", "-3"],
        "--random-starts")
    add("report_redo_bogus", [*REPORT, "--redo", "bogus", "--out", sweeps / "r1"], "bogus", out=sweeps / "r1")
    add("report_out_empty", [*REPORT, "--out", ""], "--out")
    add("discover_out_empty", ["discover", "rotation_averaging", *SMALL, "--out", ""], "--out")
    add("solve_set_paper_without_paper", ["solve", "rotation_averaging", *SMALL, "--set", "paper"],
        "no paper families")
    for name, (_, word) in BAD_SETS.items():
        add(f"report_discovered_{name}", [*REPORT[:-5], "--sets", "primary,discovered", "--jobs", "1",
                                          "--no-progress", "--discovered", files / f"set_{name}.json",
                                          "--out", sweeps / f"d_{name}"], word, out=sweeps / f"d_{name}")
    add("solve_set_file_list", ["solve", "rotation_averaging", *SMALL, "--set", files / "set_list.json"],
        "JSON object")
    add("report_meta_not_object", [*REPORT, "--out", sweeps / "badmeta"], "meta.json", out=sweeps / "badmeta")
    add("solve_anisotropy_huge", ["solve", "rotation_averaging", *SMALL, "-p", "anisotropy=1e12"], "anisotropy")
    # sizes that cannot fit: an estimate, fast
    add("solve_M_huge", ["solve", "rotation_averaging", "-p", "M=100000000"], "GB", timeout=HANG_S)
    add("report_M_huge", ["report", "rotation_averaging", "-p", "M=100000000", "--out", sweeps / "t0"], "GB",
        out=sweeps / "t0", timeout=HANG_S)
    add("report_trials_huge", [*REPORT[:6], "--trials", "100000000", "--out", sweeps / "t1"], "would take",
        out=sweeps / "t1", timeout=HANG_S)
    add("solve_random_starts_huge", ["solve", "rotation_averaging", *SMALL, "--random-starts", "100000000"],
        "would take", timeout=HANG_S)
    add("discover_heldout_huge", ["discover", "rotation_averaging", *SMALL, "--heldout", "100000000"],
        "would take", timeout=HANG_S)

    # item 5: an unreachable scheduler fails fast and leaves no folder; a folder in use is refused
    add("report_scheduler_unreachable", [*REPORT, "--scheduler", "tcp://127.0.0.1:9", "--out", sweeps / "sched"],
        "scheduler", out=sweeps / "sched", timeout=HANG_S)
    add("report_folder_locked", [*REPORT, "--trials", "2", "--out", sweeps / "busy"], "another autotight report",
        out=sweeps / "busy")
    return cases


def _small_sweep(out: Path, M: int) -> None:
    run_sweep(make_spec(load("rotation_averaging"), "rotation_averaging", {"M": M}, sigmas="0.1", trials=1,
                        sets="primary"), out, progress=False)


def _setup(base: Path) -> None:
    """The files the cases of ``_cases(base)`` use."""
    mods, files, sweeps = base / "modules", base / "files", base / "sweeps"
    for f in (mods, files, sweeps):
        f.mkdir()
    for variant in VARIANTS:
        broken_module(mods, variant)
    (mods / "rotation.txt").write_text((ROOT / "problems" / "rotation_averaging.py").read_text(encoding="utf-8"))
    (files / "a_file").write_text("not a folder\n")
    (files / "existing.json").write_text('{"keep": "me"}\n')
    for name, (obj, _) in BAD_SETS.items():
        (files / f"set_{name}.json").write_text(json.dumps(obj))
    _small_sweep(sweeps / "other", M=3)
    _small_sweep(sweeps / "busy", M=2)
    (sweeps / "notes").mkdir()
    (sweeps / "notes" / "report.md").write_text("# My notes\n\nnot a report\n")
    committed = base / "repo" / "reports" / "rotation_averaging"
    committed.mkdir(parents=True)
    for name in ("report.md", "meta.json", "trials.csv"):
        src = ROOT / "reports" / "rotation_averaging" / name
        (committed / name).write_bytes(src.read_bytes() if src.exists() else b"committed\n")
    (sweeps / "badmeta").mkdir()
    (sweeps / "badmeta" / "meta.json").write_text("[1, 2, 3]\n")


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """(cases by id, results by id, files under each --out before the run)."""
    import fcntl

    base = tmp_path_factory.mktemp("bad")
    _setup(base)
    cases = _cases(base)
    before = {c["id"]: _files(Path(c["out"])) if c["out"] else {} for c in cases}
    spec_file, results_file = base / "cases.json", base / "results.json"
    spec_file.write_text(json.dumps(cases))
    fd = os.open(base / "sweeps" / "busy" / ".lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # as a run writing that folder does
    try:
        proc = subprocess.run([sys.executable, "-c", DRIVER, str(spec_file), str(results_file), "3"], env=ENV,
                              capture_output=True, text=True, timeout=600)
    finally:
        os.close(fd)
    assert proc.returncode == 0, proc.stderr
    results = json.loads(results_file.read_text())
    print("seconds per case:", {k: round(v["seconds"], 2) for k, v in results.items()})
    return {c["id"]: c for c in cases}, results, before


def _assert_one_line_error(rc, stderr: str, words=()) -> str:
    lines = stderr.strip().splitlines()
    assert rc == 2, (rc, stderr)
    assert "Traceback" not in stderr, stderr
    assert len(lines) == 1 and lines[0].startswith("autotight: error:"), stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.mark.parametrize("case_id", [c["id"] for c in _cases(Path("BASE")) if not c.get("ok")])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(batch, case_id):
    if case_id == "report_scheduler_unreachable":
        pytest.importorskip("distributed")  # the dask extra; without it --scheduler says so (also exit 2)
    cases, results, before = batch
    case, res = cases[case_id], results[case_id]
    _assert_one_line_error(res["rc"], res["stderr"], case["words"])
    if case.get("timeout"):
        assert res["seconds"] < case["timeout"], res["seconds"]
    if case["out"]:
        assert _files(Path(case["out"])) == before[case_id]  # nothing new, nothing changed


# -- through the real entry point: `python -m autotight.cli` ------------------------------------------------
def _cli(args: list, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "autotight.cli", *map(str, args)], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=timeout)


def test_entry_point_sizes_that_cannot_fit_fail_fast_with_an_estimate(tmp_path):
    t0 = time.time()
    proc = _cli(["solve", "rotation_averaging", "-p", "M=100000000"], cwd=tmp_path)
    line = _assert_one_line_error(proc.returncode, proc.stderr, ["N ≈ 3e+08", "GB of memory"])
    assert time.time() - t0 < HANG_S, line
    assert list(tmp_path.iterdir()) == []


def test_report_without_out_writes_out_problem_and_never_the_committed_reports(batch):
    """Run in a folder shaped like the repository root: reports/PROBLEM stays byte-identical."""
    cases, results, before = batch
    case, res = cases["report_default_out"], results["report_default_out"]
    assert res["rc"] == 0, res["stderr"]
    assert before["report_default_out"] and _files(Path(case["out"])) == before["report_default_out"]
    out = Path(case["cwd"]) / "out" / "rotation_averaging"
    assert len(load_trials(out)) == 1 and (out / "report.md").read_text().startswith("# Tightness report")


def test_a_full_disk_on_the_first_write_does_not_poison_the_folder(tmp_path, capsys, monkeypatch):
    """meta.json's write fails with ENOSPC: one line, exit 2, no folder left; the rerun then works."""
    import errno

    from autotight.cli import main
    from autotight.report import store

    def full(path, obj):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    out = tmp_path / "r"
    monkeypatch.setattr(store, "write_json", full)
    rc = main([*REPORT, "--out", str(out)])
    _assert_one_line_error(rc, capsys.readouterr().err, ["disk is full"])
    assert not out.exists()
    monkeypatch.undo()
    assert main([*REPORT, "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["computed"] == 1 and len(load_trials(out)) == 1


def test_discover_out_existing_is_replaced_only_with_force(tmp_path):
    target = tmp_path / "set.json"
    target.write_text("{}\n")
    proc = _cli(["discover", "rotation_averaging", *SMALL, "--heldout", "1", "--no-progress", "--out", target,
                 "--force"])
    assert proc.returncode == 0, proc.stderr
    assert json.loads(target.read_text())["format"] == "autotight.constraint_set/2"


# -- processes: killed parents, resume --------------------------------------------------------------------
KILL_SPEC = {"params": {"M": 2}, "sigmas": "0.01,0.3", "trials": 8, "sets": "primary"}
KILL_TOTAL = 16


def _kill_args(out: Path, jobs: int) -> list:
    return ["report", "rotation_averaging", "-p", "M=2", "--sigmas", "0.01,0.3", "--sets", "primary", "--trials",
            "8", "--jobs", str(jobs), "--out", out, "--no-progress"]


def _children(pid: int) -> set[int]:
    """Every live descendant of ``pid`` (zombies excluded)."""
    parents: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if fields[0] != "Z":
                parents[int(d.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {c for c, p in parents.items() if p in frontier} - found
        found |= frontier
    return found


def _alive(pids: set[int]) -> set[int]:
    out = set()
    for p in pids:
        try:
            if (Path("/proc") / str(p) / "stat").read_text().split(") ", 1)[1][0] != "Z":
                out.add(p)
        except (OSError, IndexError):
            pass
    return out


def _start(out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "autotight.cli", *map(str, _kill_args(out, 2))], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _kill_mid_sweep(runs: dict[Path, int]) -> dict[Path, set[int]]:
    """Start `report --jobs 2` into each folder at once; when a folder has 2 saved trials, send its run
    the signal ``runs[folder]``.  The pids of each run's worker processes."""
    procs = {out: _start(out) for out in runs}
    workers: dict[Path, set[int]] = {out: set() for out in runs}
    deadline = time.time() + 90
    while procs and time.time() < deadline:
        for out, proc in list(procs.items()):
            workers[out] |= _children(proc.pid)
            csv = out / CSV_NAME
            if proc.poll() is not None or (csv.exists() and csv.read_text().count("\n") >= 1 + 2):
                workers[out] |= _children(proc.pid)
                proc.send_signal(runs[out])
                proc.wait(timeout=10)
                del procs[out]
        time.sleep(0.02)
    assert not procs, "the sweeps did not save 2 trials in time"
    assert all(workers.values()), f"no worker processes seen: {workers}"
    return workers


def _assert_workers_exit(workers: set[int]) -> None:
    t0 = time.time()
    while _alive(workers) and time.time() - t0 < HANG_S:
        time.sleep(0.05)
    assert not _alive(workers), f"workers {sorted(_alive(workers))} still running {time.time() - t0:.1f} s later"


def test_killed_parent_workers_exit_and_the_resumed_sweep_equals_the_uninterrupted_run(tmp_path):
    """SIGTERM and SIGKILL to the parent of `report --jobs 2`: its workers end within HANG_S; the
    sweep resumed after SIGKILL equals an uninterrupted one (deterministic columns)."""
    term, kill = tmp_path / "term", tmp_path / "kill"
    workers = _kill_mid_sweep({term: signal.SIGTERM, kill: signal.SIGKILL})
    _assert_workers_exit(workers[term] | workers[kill])
    spec = make_spec(load("rotation_averaging"), "rotation_averaging", **KILL_SPEC)
    for out in (term, kill):
        saved = load_trials(out)
        assert 2 <= len(saved) < KILL_TOTAL and set(saved["status"]) == {"Solved"}
    done = len(load_trials(kill))
    s = run_sweep(spec, kill, jobs=1, progress=False)
    assert (s.done_before, s.done_before + s.computed) == (done, KILL_TOTAL)
    ref = tmp_path / "ref"
    run_sweep(spec, ref, jobs=1, progress=False)
    assert_same_trials(load_trials(kill), load_trials(ref))
