"""`autotight certify` and `autotight.certify`: exit codes, JSON, agreement with the full SDP's verdict."""

import json

import numpy as np
import pytest

import autotight as at
from autotight.cli import main


def _run(capsys, *argv):
    code = main(["certify", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_certified_exit_0_and_json(capsys):
    code, out, _ = _run(capsys, "pose_averaging", "-p", "M=5", "--seed", "1", "--json")
    assert code == 0
    rec = json.loads(out)
    for key in ("problem", "params", "seed", "constraint_set", "n_constraints", "start", "local", "certified",
                "bound", "rel_bound", "lambda_min", "lambda_lower", "time_s", "method", "state", "versions"):
        assert key in rec, key
    assert rec["certified"] is True and rec["constraint_set"] == "paper" and rec["seed"] == 1
    assert rec["start"] == "truth" and rec["rel_bound"] <= 1e-5 and rec["time_s"] > 0
    assert abs(rec["local"]["cost"] - rec["cost"]) <= 1e-9 * max(1.0, rec["cost"])


def test_cli_not_certified_exit_1(capsys):
    """Primary constraints only: the relaxation is not tight, so nothing can be certified."""
    code, out, _ = _run(capsys, "pose_averaging", "-p", "M=10", "--set", "primary")
    assert code == 1
    assert "NOT CERTIFIED" in out


@pytest.mark.parametrize("argv", [["no_such_problem"], ["pose_averaging", "--from", "/no/such/file.json"],
                                  ["pose_averaging", "-p", "M=zero"], ["pose_averaging", "--set", "/no/set.json"]])
def test_cli_bad_input_exit_2(capsys, argv):
    code, out, err = _run(capsys, *argv)
    assert code == 2 and out == "" and err.startswith("autotight: error:")


def test_cli_from_file_certifies_the_solve_estimate(tmp_path, capsys):
    """--from FILE takes the estimate of `autotight solve --json`."""
    assert main(["solve", "pose_averaging", "-p", "M=5", "--seed", "2", "--json"]) == 0
    path = tmp_path / "solve.json"
    path.write_text(capsys.readouterr().out)
    code, out, _ = _run(capsys, "pose_averaging", "-p", "M=5", "--seed", "2", "--from", str(path), "--json")
    rec = json.loads(out)
    assert code == 0 and rec["start"] == "given" and rec["certified"]


def test_api_start_state_and_errors():
    prob = at.load_problem("pose_averaging")
    inst = prob.generate({"M": 5}, 0)
    cert = at.certify(prob, {"M": 5}, 0, start={k: np.asarray(v) for k, v in inst.truth.items()})
    assert cert.certified and cert.rel_bound <= 1e-5
    with pytest.raises(at.AutotightError):
        at.certify(prob, {"M": 5}, 0, start="somewhere")
    with pytest.raises(at.AutotightError):
        at.certify(prob, {"M": 5}, 0, start={"nothing": [1.0]})


@pytest.mark.parametrize("name,params,seed,cons", [
    ("pose_averaging", {"M": 10}, 0, "paper"),
    ("pose_averaging", {"M": 10}, 3, "paper"),
    ("pose_averaging", {"M": 10}, 0, "primary"),
    ("rotation_averaging", {"M": 10}, 1, "primary"),
    ("discrete_trajectory", {"K": 6}, 4, "paper"),
])
def test_agrees_with_full_sdp(name, params, seed, cons):
    """certify (no SDP) and autotight.solve (full SDP, bracket test) reach the same verdict."""
    full = at.solve(name, params, seed, constraints=cons)
    cert = at.certify(name, params, seed, constraints=cons)
    assert full.outcome in ("tight", "not tight")
    assert cert.certified == (full.outcome == "tight"), (full.outcome, cert)
    if cert.certified:  # the certified point's cost is the SDP's value, to the certified bound
        assert abs(cert.cost - full.sdp.primal_cost) <= 1e-4 * abs(cert.cost)


def test_solve_verify_certificate_skips_the_sdp_only_when_certified(capsys):
    """`solve --verify certificate`: a certified local solution ends the command without an SDP (its
    bound ≤ tolerance and the local cost in the record); a non-tight set falls through to the SDP."""
    assert main(["solve", "pose_averaging", "-p", "M=5", "--seed", "1", "--verify", "certificate", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["verify"] == "certificate" and rec["certified"] is True and "sdp_cost" not in rec
    assert rec["certificate"]["rel_bound"] <= 1e-5 and rec["certificate"]["argument"]
    assert abs(rec["certificate"]["cost"] - rec["local_cost"]) <= 1e-9 * max(1.0, rec["local_cost"])
    main(["solve", "pose_averaging", "-p", "M=10", "--set", "primary", "--verify", "certificate", "--json"])
    rec = json.loads(capsys.readouterr().out)
    assert "sdp_cost" in rec and rec["outcome"] != "tight"
