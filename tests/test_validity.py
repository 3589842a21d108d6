"""No verdict from an invalid constraint set (autotight.validity, the pipeline's checks, the dual polish cap).

Every random quantity comes from an explicit ``numpy.random.Generator`` with a stated seed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import autotight as at
import autotight.pipeline as pipeline
from autotight.cli import main
from autotight.discovery.templates import check_tolerance
from autotight.model import Constraint
from autotight.pipeline import LocalSearch, local_search, seeds, solve_instance
from autotight.problem import LocalResult, load
from autotight.validity import VALID_RTOL, InvalidConstraintError, check_valid, relative_violations

POSE_SET = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "scale_set_pose_M5.json"


def _pin(model, theta_other: np.ndarray, blocks: tuple[str, ...]) -> list[Constraint]:
    """h·x_j = v_j h² for every column j of ``blocks``, v from another instance's truth: valid at that
    instance only."""
    V, out = model.variables, []
    for blk in blocks:
        for j in range(V.slice(blk).start, V.slice(blk).stop):
            A = sp.coo_array((np.array([0.5, 0.5, -theta_other[j]]), (np.array([0, j, 0]), np.array([j, 0, 0]))),
                             shape=(V.N, V.N))
            out.append(Constraint(A, 0.0, name=f"pin {blk}[{j}]", family="learned"))
    return out


def _pose(seed: int = 7, other: int = 8, M: int = 5):
    p = load("pose_averaging")
    inst = p.generate({"M": M}, seed)
    theta_other = np.atleast_2d(p.lift(p.generate({"M": M}, other), p.generate({"M": M}, other).truth))[0]
    return p, inst, p.build(inst), theta_other


def test_valid_constraints_hold_to_roundoff_and_a_shift_is_measured():
    """The paper's families at fresh samples: relative violation ≤ 1e-12; b shifted by s·(Σ|A| + |b|)
    at a point where every term is O(1) gives a violation of the order of s."""
    p, inst, model, _ = _pose()
    rng = np.random.default_rng(0)
    cons = model.primary() + model.paper_constraints()
    thetas = [p.lift(inst, p.sample(inst, rng)) for _ in range(4)]
    assert relative_violations(cons, thetas).max() <= 1e-12
    c = model.paper_constraints()[0]
    shifted = Constraint(c.A, c.b + 1e-3 * (np.abs(c.A.data).sum() + abs(c.b)), family="learned")
    v = float(relative_violations([shifted], thetas).max())
    assert 1e-5 < v < 1e-1


def test_a_set_file_cannot_raise_its_own_tolerance(tmp_path, capsys):
    """A set file whose template is shifted (it holds at no feasible point) and whose tolerances are raised
    to 0.5: applying it is a one-line error naming the template and the factor (exit 2), not a verdict."""
    d = json.loads(POSE_SET.read_text())
    tpl = d["templates"][0]
    tpl["W"][0][0] = 0.5  # the constant feature's coefficient of the first monomial: a shifted b
    d["learn_options"]["heldout_tol"] = 0.5  # the loosest a set file may state (below 1)
    tpl["check"]["heldout_tol"] = 0.5
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(d))
    code = main(["solve", "pose_averaging", "-p", "M=5", "--seed", "3", "--set", str(path)])
    err = capsys.readouterr().err
    assert code == 2
    assert "pose_meas:r[2]·rho[2]" in err and "factor meas_" in err and "TIGHT" not in err


@pytest.mark.parametrize("saved", [1.0, 1e300, float("nan"), float("inf"), -1.0, 0.0])
def test_the_check_tolerance_is_the_tools(saved):
    assert check_tolerance(saved) == VALID_RTOL


def test_a_stricter_saved_tolerance_is_kept():
    assert check_tolerance(1e-8) == 1e-8


@pytest.mark.parametrize("accept", ["rank", "cost", "certified"])
def test_pinning_constraints_from_python_raise(accept):
    """Constraints pinning the rotation to another instance's truth: InvalidConstraintError (an
    AutotightError) naming a pin, under every acceptance rule."""
    p, inst, model, theta_other = _pose()
    pins = _pin(model, theta_other, ("c1", "c2", "c3"))
    with pytest.raises(InvalidConstraintError, match=r"pin c\d\[\d+\]") as e:
        at.solve(p, {"M": 5}, 7, constraints=model.paper_constraints() + pins, criteria=at.Criteria(accept=accept))
    assert isinstance(e.value, at.AutotightError)


def test_without_the_check_an_invalid_set_is_still_never_tight(monkeypatch):
    """Defence in depth: with the validity check switched off, the pinned SDP's bound lies far above the
    best feasible cost; the polish does not absorb that excess (beyond the solve's accuracy) and the
    certificate refuses an x̂ that violates the constraints."""
    monkeypatch.setattr(pipeline, "check_valid", lambda *a, **k: None)
    p, inst, model, theta_other = _pose(M=3)
    pins = _pin(model, theta_other, ("c1", "c2", "c3"))
    r = solve_instance(p, inst, model.paper_constraints() + pins, criteria=at.Criteria(accept="cost"))
    assert not r.tight
    assert r.certificate is not None and not r.certificate.certified
    assert r.verdict.lower > r.upper  # the claimed bound exceeds a feasible cost: nothing was lowered onto it


def _invalid(model, valid: list[Constraint], theta_other: np.ndarray, rng: np.random.Generator) -> Constraint:
    """One random invalid constraint: a valid one with b shifted (by 1e-4 to 1 of its magnitude), a lifted
    entry pinned to another instance's value, or a valid one with one coefficient (and its mirror) scaled."""
    kind, N = int(rng.integers(3)), model.variables.N
    if kind == 0:
        c = valid[rng.integers(len(valid))]
        mag = float(np.abs(c.A.data).sum() + abs(c.b))
        return Constraint(c.A, c.b + mag * 10 ** rng.uniform(-4, 0) * rng.choice([-1, 1]), name="shifted",
                          family="learned")
    if kind == 1:
        return _pin_entry(N, int(rng.integers(1, N)), theta_other)
    c = valid[rng.integers(len(valid))]
    data = c.A.data.copy()
    k = int(rng.integers(data.size))
    mirror = (c.A.row == c.A.col[k]) & (c.A.col == c.A.row[k])
    data[mirror] = data[k] * rng.uniform(1.1, 3.0) * rng.choice([-1, 1])
    return Constraint(sp.coo_array((data, (c.A.row, c.A.col)), shape=c.A.shape), c.b, name="scaled", family="learned")


def _pin_entry(N: int, j: int, theta_other: np.ndarray) -> Constraint:
    A = sp.coo_array((np.array([0.5, 0.5, -theta_other[j]]), (np.array([0, j, 0]), np.array([j, 0, 0]))), shape=(N, N))
    return Constraint(A, 0.0, name=f"pin {j}", family="learned")


@pytest.mark.parametrize("name,params", [("pose_averaging", {"M": 5}), ("discrete_trajectory", {"K": 5})])
def test_random_invalid_constraints_never_give_tight_or_certified(name, params):
    """100 draws per problem (200 in all) on two instances each: a valid set plus one invalid constraint
    (shifted b, pinned entry, scaled coefficient) is refused or judged neither tight nor certified."""
    p = load(name)
    rng = np.random.default_rng(2024)
    refused = 0
    for seed in (0, 1):
        inst = p.generate(params, seed)
        other = p.generate(params, seed + 100)
        theta_other = np.atleast_2d(p.lift(other, other.truth))[0]
        model = p.build(inst)
        loc = local_search(p, inst, seeds(seed).local(), 1)
        valid = [c for c in model.primary() + model.paper_constraints() if c.family != "homogenisation"]
        for _ in range(50):
            bad = _invalid(model, valid, theta_other, rng)
            try:
                r = solve_instance(p, inst, model.paper_constraints() + [bad], model=model, local=loc)
            except InvalidConstraintError:
                refused += 1
                continue
            assert not r.tight and not (r.certificate is not None and r.certificate.certified), bad.name
    assert refused > 0


def test_check_valid_names_an_infeasible_point_by_its_primary_constraint():
    """A lifted point off the variety (the rotation's columns scaled by 2) violates a primary constraint:
    the point is at fault (ProblemModuleError), not the set."""
    p, inst, model, _ = _pose()
    theta = np.array(np.atleast_2d(p.lift(inst, inst.truth))[0])
    for blk in ("c1", "c2", "c3"):
        theta[model.variables.slice(blk)] *= 2
    with pytest.raises(at.AutotightError, match="is not feasible: it violates the primary constraint"):
        check_valid(p.name, model.primary(), {"a scaled rotation": theta})


def test_the_sdp_estimate_joins_the_upper_bound():
    """A local solver that always returns the ground truth (cost above the optimum at σ = 0.1): the SDP's
    own rounded estimate still sets U, so the relaxation is judged tight and U is below the truth's cost."""
    p = load("pose_averaging")
    inst = p.generate({"M": 5, "sigma": 0.1}, 3)
    model = p.build(inst)
    truth = LocalResult(inst.truth, p.lifted_cost(inst, inst.truth, model), 0, False, message="returns the truth")
    broken = load("pose_averaging")
    broken.local_solve = lambda inst_, init, **kw: truth  # type: ignore[method-assign]
    r = solve_instance(broken, inst, "paper", model=model, local=LocalSearch(truth, [truth]))
    assert r.upper < truth.cost * (1 - 1e-6)
    assert r.tight and r.verdict.rank_tight
