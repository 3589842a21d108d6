"""The problem contract: derived defaults, the checked boundary into module code, and check_problem.

Broken modules are rotation_averaging.py with one change each (written to tmp_path).
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from autotight.checks import COST_RTOL, FEAS_TOL, check_problem
from autotight.cli import main
from autotight.errors import AutotightError, ProblemDefinitionError, ProblemModuleError
from autotight.problem import available, default_errors, load, perturb_state

# small sizes so that every shipped problem checks in a few seconds
SMALL = {"rotation_averaging": {"M": 4}, "pose_averaging": {"M": 3}, "discrete_trajectory": {"K": 3},
         "continuous_trajectory": {"K": 3}, "pose_graph": {"n_poses": 3}, "landmark_slam": {"n_poses": 2},
         "landmark_localization": {}, "robust_pose_averaging": {"M": 3},
         "range_only": {"n_positions": 2}, "wahba": {}, "mono_localization": {}, "stereo_1d": {},
         "stereo_2d": {}, "stereo_3d": {}, "robust_wahba": {"n_points": 3}}
# problems whose model has one factor per type: no two factors to compare identities between
SINGLE_FACTOR = {"wahba", "mono_localization"}

HEAD = """
from problems.rotation_averaging import *  # noqa: F401,F403
import problems.rotation_averaging as ra
import numpy as np
"""


def _module(tmp_path: Path, name: str, body: str, head: str = HEAD) -> str:
    p = tmp_path / f"{name}.py"
    p.write_text(textwrap.dedent(head) + f"NAME = {name!r}\n" + textwrap.dedent(body))
    return str(p)


def _fails(res, check: str) -> list[str]:
    return [f for f in res.failures if f.startswith(check + ":")]


# ------------------------------------------------------------------ every shipped problem passes


def test_small_params_cover_every_shipped_problem():
    assert sorted(SMALL) == available()


@pytest.mark.parametrize("name", sorted(SMALL))
def test_shipped_problem_passes_check(name):
    res = check_problem(name, SMALL[name], seed=0)
    assert res.ok, res.lines()
    assert not res.warnings, res.warnings
    m = res.measurements
    assert m["sample_violation"] <= FEAS_TOL and m["local_violation"] <= FEAS_TOL
    assert m["cost_rel_diff"] <= COST_RTOL and m["local_cost_rel_diff"] <= COST_RTOL
    assert m["recover_rel_diff"] <= 1e-6
    assert m["cost_local"] <= m["cost_truth"] * (1 + 1e-9)
    assert name in SINGLE_FACTOR or any(p.startswith("identities: factors") for p in res.passed), res.passed


# ------------------------------------------------------------------ broken modules fail with a named reason


def test_cost_off_by_a_constant_fails(tmp_path):
    path = _module(tmp_path, "ra_cost_plus_one", """
        def cost(inst, state):
            return ra.cost(inst, state) + 1.0
        """)
    res = check_problem(path, {"M": 3})
    assert not res.ok
    [msg] = _fails(res, "cost")
    assert "differs from ⟨Q, lift(x)lift(x)ᵀ⟩ + offset" in msg
    assert res.measurements["cost_rel_diff"] > 1e-4
    assert not _fails(res, "sample-feasible") and not _fails(res, "recover")


def test_lift_with_two_entries_swapped_fails(tmp_path):
    path = _module(tmp_path, "ra_lift_swapped", """
        def lift(inst, state):
            x = np.atleast_2d(ra.lift(inst, state)).copy()  # (1, N)
            x[:, [1, 2]] = x[:, [2, 1]]
            return x
        """)
    res = check_problem(path, {"M": 3})
    [msg] = _fails(res, "sample-feasible")
    assert "is violated by" in msg and "lift() puts entries" in msg
    # the property, not which of the tied constraints argmax names: the one named is a primary constraint
    # and is violated on the swapped lifting as much as the message says
    named = msg.split("primary constraint '", 1)[1].split("'", 1)[0]
    prob = load(path)
    inst = prob.generate({"M": 3}, 0)
    model = prob.build(inst)
    [con] = [c for c in model.primary() if c.name == named]
    from autotight.discovery.samples import relative_violation
    assert relative_violation([con], np.atleast_2d(prob.lift(inst, inst.truth))[None])[0] > 1e-3
    assert _fails(res, "recover")
    assert res.measurements["sample_violation"] > 1e-3


def test_sampler_off_the_constraints_by_1e4_fails(tmp_path):
    path = _module(tmp_path, "ra_sample_off", """
        def sample(inst, rng, nominal, spread):
            s = ra.sample(inst, rng, nominal, spread)
            return {"C": s["C"] + 1e-4 * rng.standard_normal((3, 3))}
        """)
    res = check_problem(path, {"M": 3})
    [msg] = _fails(res, "sample-feasible")
    assert "lift(sample 1) failed, so sample() may return states off the constraints" in msg
    assert "'ra_sample_off'" in msg and "lift raised ValueError" in msg


def test_sampler_off_the_constraints_within_lifts_tolerance_fails(tmp_path):
    # 1e-7 off: lift still accepts C as a rotation, the relative violation names the constraint
    path = _module(tmp_path, "ra_sample_off_small", """
        def sample(inst, rng, nominal, spread):
            s = ra.sample(inst, rng, nominal, spread)
            return {"C": s["C"] + 1e-7 * rng.standard_normal((3, 3))}
        """)
    res = check_problem(path, {"M": 3})
    [msg] = _fails(res, "sample-feasible")
    assert "orth(" in msg.split("primary constraint '", 1)[1].split("'", 1)[0]  # an orthonormality constraint
    assert 1e-8 < res.measurements["sample_violation"] < 1e-5


def test_recover_returning_a_transposed_rotation_fails(tmp_path):
    path = _module(tmp_path, "ra_recover_transposed", """
        def recover(inst, Theta):
            s = ra.recover(inst, Theta)
            return s | {"C": s["C"].T}
        """)
    res = check_problem(path, {"M": 3})
    assert [f.split(":")[0] for f in res.failures] == ["recover"]
    assert "differs from x in entry 'C'" in res.failures[0]
    assert res.measurements["recover_rel_diff"] > 0.1


def test_factors_without_shared_roles_warn(tmp_path):
    path = _module(tmp_path, "ra_no_roles", """
        def build(inst):
            model = ra.build(inst)
            for f in model.factors:
                f.roles = f.blocks  # what leaving out roles gives
            return model
        """)
    res = check_problem(path, {"M": 3})
    assert res.ok, res.failures
    [w] = [w for w in res.warnings if "have different roles" in w]
    assert w.startswith("identities: factors 'meas_0' and 'meas_1' of type 'rotation_meas'")
    assert "phi_0→phi_1" in w
    assert any(line.startswith("WARN identities:") for line in res.lines())


DT_HEAD = """
from problems.discrete_trajectory import *  # noqa: F401,F403
from problems._pose import unary_transport, binary_transport
import numpy as np
"""


def test_declared_transports_are_checked(tmp_path):
    res = check_problem("discrete_trajectory", {"K": 3})
    assert res.measurements["transport_pose_meas_rel_error"] <= 1e-8
    assert res.measurements["transport_odometry_rel_error"] <= 1e-8
    # the unary map used for the binary factor's first pose: right shape, wrong change of variables
    path = _module(tmp_path, "dt_bad_transport", """
        def _wrong(d):
            M = binary_transport(d)
            M[10:13, 0] = 0.0  # r₁ ↦ C̃ r₁, forgetting + r̃
            return M
        TRANSPORTS = {"pose_meas": unary_transport, "odometry": _wrong}
        """, head=DT_HEAD)
    res = check_problem(path, {"K": 3})
    [f] = _fails(res, "transport")
    assert "TRANSPORTS['odometry']" in f and "does not carry" in f
    assert res.measurements["transport_odometry_rel_error"] > 1e-3


def test_check_module_cli_exit_codes(tmp_path, capsys):
    assert main(["check-module", "rotation_averaging", "-p", "M=3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-1].startswith("OK") and all(not line.startswith("FAIL") for line in out)
    bad = _module(tmp_path, "ra_cost_plus_one", """
        def cost(inst, state):
            return ra.cost(inst, state) + 1.0
        """)
    assert main(["check-module", bad, "-p", "M=3", "--json"]) == 1
    rec = json.loads(capsys.readouterr().out)
    assert rec["ok"] is False and [f.split(":")[0] for f in rec["failures"]] == ["cost"]
    assert main(["check-module", bad, "-p", "M=0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("autotight: error: parameter M=0")


# ------------------------------------------------------------------ the boundary into module code


def _problem_error(exc_info, module: str, part: str, *needles: str) -> str:
    msg = str(exc_info.value)
    assert "\n" not in msg
    assert msg.startswith(f"problem module {module!r} (") and f"): {part} " in msg, msg
    for n in needles:
        assert n in msg, (n, msg)
    return msg


@pytest.mark.parametrize("part, body, call, needles, cause", [
    ("generate", "def generate(params, rng):\n    return {'C': np.eye(3)}\n", "generate",
     ("returned dict, expected autotight.problem.Instance",), None),
    ("generate", "def generate(params, rng):\n    return {}['M']\n", "generate", ("raised KeyError: 'M'",), KeyError),
    ("local_solve", "def local_solve(inst, init, max_iter=200):\n    return None\n", "local_solve",
     ("returned NoneType, expected autotight.problem.LocalResult",), None),
    ("errors", "def errors(inst, state):\n    return 'small'\n", "errors", ("returned str, expected dict[str, float]",),
     None),
    ("recover", "def recover(inst, Theta):\n    raise TypeError('bad Theta')\n", "recover",
     ("raised TypeError: bad Theta",), TypeError),
    ("sample", "def sample(inst, rng, nominal, spread):\n    raise RuntimeError('no luck')\n", "sample",
     ("raised RuntimeError: no luck",), RuntimeError),
    ("lift", "def lift(inst, state):\n    return np.atleast_2d(ra.lift(inst, state))[:, :-1]\n", "lift",
     ("returned an array of shape (1, 18), expected (19,) or (1, 19) (build's Variables: d = 1, N = 19)",), None),
])
def test_module_part_errors_name_module_part_and_exception(tmp_path, part, body, call, needles, cause):
    name = f"ra_bad_{part}_{call}"
    path = _module(tmp_path, name, body)
    prob = load(path)
    calls = {
        "generate": lambda: prob.generate({"M": 3}, 0),
        "local_solve": lambda: prob.local_solve(inst, inst.truth),
        "errors": lambda: prob.errors(inst, inst.truth),
        "recover": lambda: prob.recover(inst, prob.lift(inst, inst.truth)),
        "sample": lambda: prob.sample(inst, np.random.default_rng(0)),
        "lift": lambda: (prob.build(inst), prob.lift(inst, inst.truth)),
    }
    if call != "generate":
        inst = load("rotation_averaging").generate({"M": 3}, 0)
    with pytest.raises(ProblemModuleError) as ei:
        calls[call]()
    msg = _problem_error(ei, name, part, *needles)
    assert path in msg
    assert isinstance(ei.value, ProblemDefinitionError) and isinstance(ei.value, AutotightError)
    if cause is not None:
        assert type(ei.value.__cause__) is cause  # raised from the original: its traceback is kept


def test_errors_with_a_non_number_value_names_the_entry(tmp_path):
    prob = load(_module(tmp_path, "ra_bad_error_value", "def errors(inst, state):\n    return {'deg': 'big'}\n"))
    inst = prob.generate({"M": 3}, 0)
    with pytest.raises(ProblemModuleError, match=r"errors returned str for 'deg', expected dict\[str, float\]"):
        prob.errors(inst, inst.truth)


def test_autotight_errors_raised_by_a_module_pass_through(tmp_path):
    prob = load(_module(tmp_path, "ra_param_error", """
        from autotight.errors import ParameterError
        def generate(params, rng):
            raise ParameterError("M too large for this data")
        """))
    with pytest.raises(AutotightError, match="^M too large for this data$") as ei:
        prob.generate({"M": 3}, 0)
    assert not isinstance(ei.value, ProblemModuleError)


def test_paths_that_are_not_python_modules(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ProblemDefinitionError, match=r"is not a \.py file$"):
        load(str(tmp_path / "notes.txt"))
    with pytest.raises(ProblemDefinitionError, match="is a directory, not a .py file"):
        load(str(tmp_path) + "/")
    with pytest.raises(ProblemDefinitionError, match="no problem file"):
        load(str(tmp_path / "nowhere.py"))


def test_a_shipped_module_given_by_path_loads_in_its_package_and_a_lone_relative_import_is_explained(tmp_path):
    """problems/discrete_trajectory.py imports its package's helpers relatively: by path it is the same module
    as by name (it was an ImportError).  A user file with a relative import gets a one-line hint."""
    path = Path(__file__).resolve().parents[1] / "problems" / "discrete_trajectory.py"
    assert load(str(path)).module is load("discrete_trajectory").module
    lone = tmp_path / "lone.py"
    lone.write_text("from ._pose import POSE_ROLES  # noqa: F401\n")
    with pytest.raises(ProblemModuleError, match="import its package's helpers absolutely.*relative import"):
        load(str(lone))


def test_a_missing_import_inside_the_module_names_the_module(tmp_path):
    path = _module(tmp_path, "ra_missing_dep", "import surely_not_installed_pkg  # noqa: F401\n")
    with pytest.raises(ProblemModuleError) as ei:
        load(path)
    msg = str(ei.value)
    assert msg == (f"cannot import problem file {path}: ModuleNotFoundError: "
                   "No module named 'surely_not_installed_pkg'")
    assert isinstance(ei.value.__cause__, ModuleNotFoundError)


# ------------------------------------------------------------------ the smaller contract


MINIMAL = """
'''Rotation averaging with only the required parts.'''
from problems.rotation_averaging import PARAMS, build, generate, lift, local_solve, recover, sample  # noqa: F401
"""


def test_minimal_module_gets_derived_parts_and_passes(tmp_path):
    p = tmp_path / "ra_minimal.py"
    p.write_text(textwrap.dedent(MINIMAL))
    prob, ra = load(str(p)), load("rotation_averaging")
    assert prob.name == "ra_minimal" and prob.description == "Rotation averaging with only the required parts."
    assert prob.derived == ("cost", "random_state", "errors")
    inst = prob.generate({"M": 4}, 3)
    rng = np.random.default_rng(1)
    for _ in range(3):
        s = prob.sample(inst, rng)
        assert prob.cost(inst, s) == pytest.approx(ra.cost(inst, s), rel=1e-12)
        assert prob.errors(inst, s)["C_deg"] == pytest.approx(ra.errors(inst, s)["rotation_deg"], abs=1e-9)
    far = [prob.errors(inst, prob.random_state(inst, rng))["C_deg"] for _ in range(20)]
    assert np.median(far) > 60  # random starts are far from the truth, not near it
    res = check_problem(prob, {"M": 4})
    assert res.ok and "derived" in next(p for p in res.passed if p.startswith("cost:"))


def test_spread_is_module_overridable_and_reaches_discovery(tmp_path):
    from autotight.discovery.learn import LearnOptions
    from autotight.discovery.samples import draw

    prob = load(_module(tmp_path, "ra_spread", "from autotight.problem import Meta\nMETA = Meta(spread=0.05)\n"))
    assert prob.spread == 0.05 and load("rotation_averaging").spread == 0.5
    assert LearnOptions().spread is None
    inst = prob.generate({"M": 3}, 0)
    a = draw(prob, inst, 4, np.random.default_rng(5), None).thetas
    b = draw(prob, inst, 4, np.random.default_rng(5), 0.05).thetas
    c = draw(prob, inst, 4, np.random.default_rng(5), 0.5).thetas
    assert np.array_equal(a, b) and not np.allclose(a, c)
    with pytest.raises(ProblemDefinitionError, match="META.spread must be a positive number"):
        load(_module(tmp_path, "ra_bad_spread", "from autotight.problem import Meta\nMETA = Meta(spread=-1)\n"))


def test_tool_policy_is_one_meta_value_and_loose_names_are_refused_with_the_replacement(tmp_path):
    with pytest.raises(ProblemDefinitionError, match=r"SIGMAS, SPREAD is tool policy: declare it as "
                                                     r"META = Meta\(sigmas=…, spread=…\)"):
        load(_module(tmp_path, "ra_loose", "SIGMAS = [0.1]\nSPREAD = 0.2\n"))
    with pytest.raises(ProblemDefinitionError, match="META must be a Meta"):
        load(_module(tmp_path, "ra_meta_dict", "META = {'sigmas': [0.1]}\n"))
    prob = load(_module(tmp_path, "ra_meta", "from autotight.problem import Meta\nMETA = Meta(sigmas=[0.2, 0.4])\n"))
    from autotight.module_parts import sigmas

    assert sigmas(prob) == (0.2, 0.4) and sigmas(load("rotation_averaging"), (1.0,)) == (1.0,)


def test_default_errors_and_perturb_state_by_entry_kind():
    rng = np.random.default_rng(0)
    from autotight import lie

    C = np.array([lie.random_rotation(rng) for _ in range(2)])
    T = np.array([lie.make_pose(lie.random_rotation(rng), rng.standard_normal(3)) for _ in range(2)])
    truth = {"C": C, "T": T, "l": np.zeros((2, 3)), "label": "x"}
    state = {"C": np.array([C[0], lie.exp_so3(np.radians([0, 0, 10.0])) @ C[1]]),
             "T": T.copy(), "l": np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]])}
    state["T"][1, :3, 3] += [0.0, 2.0, 0.0]
    e = default_errors(state, truth)
    assert e["C_deg"] == pytest.approx(10.0, abs=1e-9)
    assert e["T_rotation_deg"] == pytest.approx(0.0, abs=1e-6)
    assert e["T_translation"] == pytest.approx(np.sqrt(2.0), rel=1e-12)  # RMS of (0, 2)
    assert e["l_err"] == pytest.approx(np.sqrt(12.5), rel=1e-12)  # RMS of (5, 0)
    assert set(e) == {"C_deg", "T_rotation_deg", "T_translation", "l_err"}
    p = perturb_state({"C": C, "T": T, "l": truth["l"]}, rng, 0.3)
    assert np.allclose(np.einsum("sji,sjk->sik", p["C"], p["C"]), np.eye(3))
    assert np.allclose(p["T"][:, 3], [0, 0, 0, 1]) and np.all(np.linalg.det(p["T"][:, :3, :3]) > 0)
    assert not np.allclose(p["l"], 0)


def test_worked_example_in_the_docs_passes_the_check(tmp_path):
    import re

    doc = (Path(__file__).resolve().parents[1] / "docs" / "problem_contract.md").read_text()
    [code] = re.findall(r"```python\n(.*?)```", doc, re.S)
    assert "from ._cayley" not in code and "problems._cayley" not in code and "autotight.affine" not in code
    p = tmp_path / "doc_example.py"
    p.write_text(code + "\nfrom problems.rotation_averaging import cost, generate, local_solve  # noqa: E402,F401\n")
    res = check_problem(str(p), {"M": 3})
    assert res.ok and not res.warnings, res.lines()


def test_rotation_averaging_imports_only_public_helpers():
    src = (Path(__file__).resolve().parents[1] / "problems" / "rotation_averaging.py").read_text()
    imports = [line for line in src.splitlines() if line.startswith(("from ", "import "))]
    assert not any("._cayley" in line or "autotight.affine" in line or "from ." in line for line in imports), imports


def test_check_module_broken_generate_is_a_failed_check_and_bad_parameters_are_bad_input(tmp_path, capsys):
    path = _module(tmp_path, "ra_generate_keyerror", "def generate(params, rng):\n    return {}['M']\n")
    assert main(["check-module", path]) == 1
    out = capsys.readouterr().out.splitlines()
    assert [line for line in out if line.startswith("FAIL ")] == [
        f"FAIL setup: problem module 'ra_generate_keyerror' ({path}): generate raised KeyError: 'M'"]
    refuse = _module(tmp_path, "ra_refuses", """
        from autotight.errors import ParameterError
        def generate(params, rng):
            raise ParameterError("this combination of parameters is impossible")
        """)
    assert main(["check-module", refuse]) == 2
    assert capsys.readouterr().err.strip() == "autotight: error: this combination of parameters is impossible"


def test_assert_problem_module_passes_a_kept_contract_and_lists_every_failed_check(tmp_path):
    from autotight.testing import assert_problem_module

    res = assert_problem_module("rotation_averaging", {"M": 3})
    assert res.ok and res.measurements["sample_violation"] <= 1e-8
    broken = _module(tmp_path, "ra_two_broken", """
        def sample(inst, rng, nominal, spread):
            return dict(nominal)
        def errors(inst, state):
            return {'a': 'x'}
        """)
    with pytest.raises(AssertionError) as e:
        assert_problem_module(broken, {"M": 3})
    lines = str(e.value).splitlines()
    assert lines[0].startswith("problem ra_two_broken fails")
    failed = {ln.split(":")[0] for ln in lines[1:]}
    assert {"FAIL sample-spread", "FAIL errors"} <= failed, lines
