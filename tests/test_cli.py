"""The command line: list, solve (text and JSON), and one-line errors for bad input.

Bad input must give exactly one stderr line ``autotight: error: …``, exit status 2 and no
traceback.  Most runs are in-process through ``autotight.cli.main``; two are real subprocesses
of the installed console script.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from autotight.cli import main
from autotight.problem import REQUIRED, Instance, available, load

JSON_KEYS = ("problem", "params", "seed", "status", "tight", "log_svr", "sdp_cost", "local_cost", "solve_time_s",
             "measurements", "estimate")


def _autotight_cmd() -> list[str]:
    script = Path(sys.executable).with_name("autotight")
    return [str(script)] if script.exists() else [sys.executable, "-m", "autotight.cli"]


def _expect_error(capsys, argv: list[str], *needles: str) -> str:
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 2, (rc, out, err)
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    msg = lines[0]
    assert msg.startswith("autotight: error: "), msg
    for n in needles:
        assert n in msg, (n, msg)
    return msg


def _write(tmp_path: Path, name: str, body: str) -> str:
    p = tmp_path / f"{name}.py"
    p.write_text(textwrap.dedent(body))
    return str(p)


# ----------------------------------------------------------------------------- list


def test_list_prints_every_problem_with_its_parameters(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    names = available()
    assert "rotation_averaging" in names
    sections: dict[str, list[str]] = {}
    current = None
    for line in out.splitlines():
        m = re.match(r"^(\w+): ", line)
        if m:
            current = m.group(1)
            sections[current] = []
        elif current is not None and line.strip():
            sections[current].append(line.strip())
    assert sorted(sections) == sorted(names)
    for name in names:
        prob = load(name)
        listed = [ln.split(" = ")[0] for ln in sections[name]]
        assert listed == list(prob.params), (name, listed)
        for ln, (k, p) in zip(sections[name], prob.params.items()):
            assert repr(p.default) in ln
    # the JSON listing carries the same names, parameters and defaults
    assert main(["list", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == names
    ra = next(r for r in rows if r["name"] == "rotation_averaging")
    assert ra["params"]["M"]["default"] == 10 and ra["params"]["sigma"]["default"] == 0.1


# ----------------------------------------------------------------------------- solve


def test_solve_text_reports_sdp_local_errors_and_times(capsys):
    assert main(["solve", "rotation_averaging", "--param", "M=6", "-p", "sigma=0.1", "--seed", "4"]) == 0
    out = capsys.readouterr().out
    m_sdp = re.search(r"SDP: status (\S+)\s+cost (\S+)\s+log SVR (\S+)\s+(TIGHT|NOT TIGHT)", out)
    m_loc = re.search(r"local solver from ground truth: cost (\S+)", out)
    assert m_sdp and m_loc, out
    assert m_sdp.group(1) == "Solved" and m_sdp.group(4) == "TIGHT"
    assert float(m_sdp.group(3)) > 5
    f_sdp, f_loc = float(m_sdp.group(2)), float(m_loc.group(1))
    assert abs(f_sdp - f_loc) <= 1e-6 * f_loc
    assert "'M': 6" in out and "seed 4" in out
    assert re.search(r"errors: SDP estimate \{'rotation_deg': [0-9.e-]+\}", out)
    assert re.search(r"times: .*sdp_solve_s [0-9.]+s", out)


def _check_json_record(rec: dict, M: int, seed: int) -> None:
    for k in JSON_KEYS:
        assert k in rec, k
    assert rec["problem"] == "rotation_averaging"
    assert rec["params"] == {"M": M, "sigma": 0.1, "anisotropy": 1.0}
    assert rec["seed"] == seed
    assert rec["status"] == "Solved" and rec["tight"] is True
    assert rec["log_svr"] > 5
    assert abs(rec["sdp_cost"] - rec["local_cost"]) <= 1e-6 * rec["local_cost"]
    assert 0 < rec["solve_time_s"] < 60
    Cm = np.array(rec["measurements"]["C_meas"])
    assert Cm.shape == (M, 3, 3)
    assert np.allclose(np.einsum("mji,mjk->mik", Cm, Cm), np.eye(3), atol=1e-12)
    C = np.array(rec["estimate"]["C"])
    assert np.allclose(C.T @ C, np.eye(3), atol=1e-12) and np.linalg.det(C) == pytest.approx(1.0, abs=1e-12)
    # the JSON is self-contained: the original cost of the estimate, recomputed from the JSON
    # measurements alone, is the reported SDP cost
    ra = load("rotation_averaging")
    inst = Instance("rotation_averaging", rec["params"], {"C_meas": Cm, "W": np.array(rec["measurements"]["W"])},
                    {"C": np.array(rec["truth"]["C"])})
    assert ra.cost(inst, {"C": C}) == pytest.approx(rec["sdp_cost"], rel=1e-6)


def test_solve_json_in_process(capsys):
    assert main(["solve", "rotation_averaging", "-p", "M=7", "--seed", "2", "--json"]) == 0
    out = capsys.readouterr().out
    assert len(out.strip().splitlines()) == 1  # one JSON object
    _check_json_record(json.loads(out), M=7, seed=2)


def test_solve_json_subprocess():
    proc = subprocess.run(_autotight_cmd() + ["solve", "rotation_averaging", "--json"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    _check_json_record(json.loads(proc.stdout), M=10, seed=0)


def test_solve_decompose_uses_our_cliques_with_the_same_optimum(capsys):
    """Clarabel on our clique cover (continuous time, ϖ kept, K = 5: the model advises it, and
    --no-decompose overrides the advice); the SDP cost equals
    that of Clarabel's own chordal decomposition to 1e-5 relative (the verdict's gap tolerance; with the
    pipeline's block scaling each solve reaches the local optimum to 2–8e-6 here)."""
    argv = ["solve", "continuous_trajectory", "-p", "K=5", "-p", "marginalize=false", "--json"]
    assert main(argv) == 0  # the model's advice: our cover
    ours = json.loads(capsys.readouterr().out)
    assert main(argv + ["--no-decompose"]) == 0
    ref = json.loads(capsys.readouterr().out)
    assert ours["solver"] == "clarabel-cliques" and ref["solver"] != "clarabel-cliques", (ours["solver"], ref["solver"])
    assert ours["status"] == "Solved" and ours["tight"]
    assert abs(ours["sdp_cost"] - ref["sdp_cost"]) <= 1e-5 * abs(ref["sdp_cost"])


def test_scale_flag_reaches_the_sdp_and_keeps_the_optimum(capsys, monkeypatch):
    """--scale none solves the data as built (no D reaches the SDP layer), --scale auto (the default)
    solves for X' with D from the local solution.  At σ = 0.001 the scaled solve's bracket [D, P] is
    within 1e-8 relative of the local optimum U and at least 100× narrower than the unscaled one's."""
    from autotight import pipeline

    seen = []
    solve_model = pipeline.sdp.solve_model

    def spy(model, cons, config, scale, stop=None, settled=None):
        seen.append((config.scale, scale))
        return solve_model(model, cons, config, scale, stop=stop, settled=settled)

    monkeypatch.setattr(pipeline.sdp, "solve_model", spy)
    argv = ["solve", "rotation_averaging", "-p", "M=6", "-p", "sigma=0.001", "--json"]
    assert main(argv + ["--scale", "none"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert seen == [("none", None)] and plain["scale"] == "none"
    seen.clear()
    assert main(argv) == 0
    scaled = json.loads(capsys.readouterr().out)
    assert len(seen) == 1 and seen[0][0] == "auto" and seen[0][1] is not None
    D = seen[0][1]
    assert D.max() / D.min() > 10  # O(σ) residual blocks against O(1) rotations
    U = scaled["upper_bound"]
    assert plain["upper_bound"] == pytest.approx(U, rel=1e-12)
    width = {k: max(abs(r["sdp_cost"] - U), abs(r["sdp_dual_cost"] - U))
             for k, r in (("plain", plain), ("scaled", scaled))}
    assert width["scaled"] <= 1e-8 * U and width["scaled"] * 100 <= width["plain"], width


def test_decompose_with_cvxpy_is_a_one_line_error(capsys):
    _expect_error(capsys, ["solve", "rotation_averaging", "--solver", "cvxpy:SCS", "--decompose"],
                  "--decompose needs --solver clarabel or ipm")


def test_bad_input_subprocess_exit_code():
    proc = subprocess.run(_autotight_cmd() + ["solve", "no_such_problem"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("autotight: error: unknown problem 'no_such_problem'")


# ----------------------------------------------------------------------------- bad input


def test_unknown_problem_lists_known_ones(capsys):
    _expect_error(capsys, ["solve", "no_such_problem"], "unknown problem 'no_such_problem'", *available())


@pytest.mark.parametrize("assignment,needles", [
    ("M=0", ("parameter M=0", "≥ 1")),
    ("sigma=-1", ("parameter sigma=-1", "≥ 0")),
    ("M=abc", ("parameter M='abc'", "expected int")),
    ("M=2.5", ("parameter M='2.5'", "expected int")),
    ("sigma=nan", ("sigma", "finite")),
    ("anisotropy=0.5", ("anisotropy", "≥ 1")),
    ("foo=1", ("unknown parameter", "'foo'", "known: M, sigma, anisotropy")),
    ("=1", ("unknown parameter", "known: M, sigma, anisotropy")),
    ("M10", ("'M10' is not NAME=VALUE",)),
])
def test_bad_parameters(capsys, assignment, needles):
    _expect_error(capsys, ["solve", "rotation_averaging", "--param", assignment], *needles)


def test_module_lacking_required_parts_names_them(capsys, tmp_path):
    path = _write(tmp_path, "half_problem", """
        NAME = "half_problem"
        DESCRIPTION = "defines only some of the parts"
        PARAMS = {}

        def generate(params, rng):
            raise AssertionError("never called")

        def build(instance):
            raise AssertionError("never called")

        def cost(instance, state):
            return 0.0
        """)
    msg = _expect_error(capsys, ["solve", path], "lacks required part(s)")
    missing = msg.split("lacks required part(s): ", 1)[1].split(", ")
    expected = [p for p in REQUIRED if p not in ("NAME", "DESCRIPTION", "PARAMS", "generate", "build", "cost")]
    assert missing == expected


def test_module_with_part_that_is_not_a_function(capsys, tmp_path):
    path = _write(tmp_path, "ra_not_callable", """
        from problems.rotation_averaging import *  # noqa: F401,F403

        NAME = "ra_not_callable"
        recover = "the SDP solution"
        """)
    _expect_error(capsys, ["solve", path], "recover must be a function")


def test_module_that_does_not_import(capsys, tmp_path):
    path = _write(tmp_path, "broken_syntax", "NAME = 'broken'\ndef generate(:\n")
    _expect_error(capsys, ["solve", path], "cannot import problem file", "SyntaxError")


def test_missing_problem_file(capsys, tmp_path):
    _expect_error(capsys, ["solve", str(tmp_path / "nowhere.py")], "no problem file")


# A user's problem file: rotation averaging whose first measurement is the ground truth turned
# by 180° about the z axis, so the residual cay⁻¹(C C̃ᵀ) of the truth is at the Cayley singularity.
PI_MEASUREMENT = """
    import numpy as np
    from autotight import lie
    from problems import rotation_averaging as _ra
    from problems.rotation_averaging import *  # noqa: F401,F403

    NAME = "{name}"

    def generate(params, rng):
        inst = _ra.generate(params, rng)
        if {exact}:  # truth = I and an exactly flipped measurement: 1 + tr(C C̃ᵀ) = 0 exactly
            C = inst.truth["C"]
            inst.truth["C"] = np.eye(3)
            inst.measurements["C_meas"] = np.array([Cm @ C.T for Cm in inst.measurements["C_meas"]])
            inst.measurements["C_meas"][0] = np.diag([-1.0, -1.0, 1.0])
        else:  # a random truth: the angle is π up to rounding
            Rz = lie.rotation_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi)
            inst.measurements["C_meas"][0] = Rz @ inst.truth["C"]
        return inst
    """


@pytest.mark.parametrize("exact", [True, False], ids=["exactly-pi", "pi-up-to-rounding"])
def test_cayley_singularity_is_a_one_line_error(capsys, tmp_path, exact):
    name = f"ra_pi_{'exact' if exact else 'rounded'}"
    path = _write(tmp_path, name, PI_MEASUREMENT.format(name=name, exact=exact))
    _expect_error(capsys, ["solve", path, "-p", "M=4"], "Cayley map is singular", "≈ π")


@pytest.mark.parametrize("accept", ["rank", "cost", "certified"])
def test_solve_accept_rule_is_applied_and_recorded(capsys, accept):
    """`solve --accept`: the verdict under that rule (rotation averaging M = 5 is tight and certified
    under all three), recorded in the JSON."""
    assert main(["solve", "rotation_averaging", "-p", "M=5", "--accept", accept, "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["accept"] == accept and rec["tight"] and rec["certified"]


def test_the_parameters_a_record_prints_are_taken_back_by_param(capsys, tmp_path):
    """Every parameter of a discovery record's point, written ``-p name=value`` as Python prints it (None for a
    preset parameter left to the preset, [] or [1.0, 2.0] for a tuple), parses to the same value."""
    from autotight.problem import load

    prob = load("continuous_trajectory")
    full = prob.parse_params({"K": 5, "measured": (0, 4)})
    assert full["dt"] is None and full["qc_diag"] == ()
    record = json.loads(json.dumps(full))  # as a saved record holds them: tuples become lists
    text = {k: str(v) for k, v in record.items()}  # as f"-p{k}={v}" writes them
    assert text["dt"] == "None" and text["qc_diag"] == "[]" and text["measured"] == "[0, 4]"
    assert prob.parse_params(text) == full
    _expect_error(capsys, ["solve", "continuous_trajectory", "--param", "qc_diag=[1, x]"], "qc_diag", "expected tuple")
