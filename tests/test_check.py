"""`autotight check` and `autotight.testing.assert_sufficient`: exit codes, counting, seeds, messages."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from autotight import evaluate
from autotight.check import PointResult, check_sufficient, instance_seed
from autotight.cli import main
from autotight.errors import ParameterError
from autotight.report.spec import trial_seeds
from autotight.testing import assert_sufficient


def test_paper_suffices_on_fresh_instances(capsys):
    """`autotight check pose_averaging --set paper --instances 6` exits 0 with every instance tight."""
    assert main(["check", "pose_averaging", "--set", "paper", "--instances", "6"]) == 0
    out = capsys.readouterr().out
    assert "PASSED" in out
    row = next(line for line in out.splitlines() if line.startswith("(params above)")).split()
    assert row[2:7] == ["167", "6", "0", "0", "1.00"]  # constraints, tight, undecided, not tight, fraction


def test_primary_fails_and_lists_the_seeds(capsys):
    """Acceptance: `--set primary --instances 5` exits 1 and names every failing seed."""
    assert main(["check", "pose_averaging", "--set", "primary", "--instances", "5"]) == 1
    out = capsys.readouterr().out
    assert "FAILED" in out
    for t in range(5):
        assert str(instance_seed(0, 0, t)) in out
    assert f"--seed {instance_seed(0, 0, 0)} --set primary" in out  # the re-run line


def test_json_is_one_object_with_the_same_counts(capsys):
    assert main(["check", "pose_averaging", "-p", "M=4", "--sigmas", "0.01,0.1", "--set", "primary",
                 "--instances", "2", "--json", "--seed", "3"]) == 1
    rec = json.loads(capsys.readouterr().out)
    assert rec["passed"] is False and rec["seed"] == 3 and rec["over"] == {"sigma": [0.01, 0.1]}
    assert [p["not_tight"] for p in rec["points"]] == [2, 2]
    assert [f["seed"] for f in rec["points"][1]["failing"]] == [instance_seed(3, 1, t) for t in range(2)]
    assert rec["points"][0]["n_constraints"] == [1 + 6 + 4 * 12]  # h² = 1, orthonormality, 12 per measurement


@pytest.mark.parametrize("argv, match", [
    (["--instances", "0"], "instances"),
    (["--min-fraction", "1.5"], "min_fraction"),
    (["-p", "sigma=0.1", "--sigmas", "0.1,1"], "both fixed"),
    (["--range", "Q=1,2"], "unknown parameter 'Q'"),
    (["--sigmas", "0.1,0.1"], "duplicate"),
    (["--sigmas", "-1"], "sigma"),
    (["--set", "/nonexistent/set.json"], "no such file"),
])
def test_bad_input_exits_2(argv, match, capsys):
    try:
        code = main(["check", "pose_averaging", "--instances", "1", *_with_m(argv)])
    except SystemExit as e:  # refused by the option's type (argparse)
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("autotight: error:") and match in err


def _with_m(argv: list[str]) -> list[str]:
    return argv if "-p" in argv else ["-p", "M=2", *argv]


def test_fraction_leaves_out_undecided():
    p = PointResult({}, {}, 0.6, seeds=[1, 2, 3, 4], outcomes=["tight", "undecided", "not tight", "tight"],
                    log_svr=[9, 4, 1, 9], reasons=["", "", "", ""])
    assert p.n_decided == 3 and p.fraction == pytest.approx(2 / 3) and p.passed
    p.min_fraction = 0.7
    assert not p.passed
    assert [s for s, _, _ in p.with_outcome("not tight")] == [3]
    none = PointResult({}, {}, 0.0, seeds=[1], outcomes=["undecided"], log_svr=[4], reasons=[""])
    assert np.isnan(none.fraction) and not none.passed  # no decided instance: no evidence


def test_undecided_is_reported_separately_and_never_fails(monkeypatch):
    """check_sufficient counts the pipeline's outcomes: undecided seeds are listed, not counted as failures."""
    undecided = {instance_seed(0, 0, 1), instance_seed(0, 1, 0)}

    def fake(problem, inst, constraints, **kw):
        out = "undecided" if inst.seed in undecided else "tight"
        return SimpleNamespace(outcome=out, log_svr=3.0 if out == "undecided" else 9.0, attempts=[{}, {}],
                               verdict=SimpleNamespace(reason=f"bracket {out}", rel_gap=0.0), n_constraints=7,
                               sdp=SimpleNamespace(status="Solved"))

    monkeypatch.setattr(evaluate, "solve_instance", fake)  # the loop check runs (autotight.evaluate)
    rep = check_sufficient("pose_averaging", "paper", [0.01, 0.1], instances=3, params={"M": 2})
    assert rep.passed and rep.n_solves == 12  # every attempt counts
    assert [p.count("undecided") for p in rep.points] == [1, 1] and rep.failing_seeds == []
    assert "(undecided: " in rep.table()


def test_check_uses_the_report_seeds():
    for i, t in [(0, 0), (2, 5)]:
        assert instance_seed(7, i, t) == trial_seeds(7, i, t)[0]


def test_assert_sufficient_passes_and_fails_with_the_seeds():
    rep = assert_sufficient("pose_averaging", "paper", sigmas=[0.01, 0.316], instances=2, params={"M": 4})
    assert all(p.count("tight") == 2 for p in rep.points)
    with pytest.raises(AssertionError) as e:
        assert_sufficient("pose_averaging", "primary", sigmas=[0.1], instances=2, params={"M": 4})
    msg = str(e.value)
    for t in range(2):
        assert f"seed {instance_seed(0, 0, t)}: not tight, log SVR" in msg
    assert "0 tight, 0 undecided, 2 not tight of 2" in msg


def test_a_list_of_constraints_is_refused():
    with pytest.raises(ParameterError, match="one instance"):
        check_sufficient("pose_averaging", [], instances=1)


def test_check_takes_the_solver_and_accept_rule_and_records_them(capsys):
    """`check --solver ipm --accept certified`: every solve goes to our IPM, the certificate decides,
    and the JSON says which solver and rule were used (rotation averaging M = 5, primary: tight and
    certified on both instances)."""
    argv = ["check", "rotation_averaging", "-p", "M=5", "--set", "primary", "--instances", "2", "--sigmas", "0.1",
            "--json"]
    assert main([*argv, "--solver", "ipm", "--accept", "certified"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert (rec["solver"], rec["accept"]) == ("ipm", "certified")
    assert rec["points"][0]["tight"] == 2 and set(rec["points"][0]["statuses"]) <= {"Solved", "AlmostSolved"}
