"""Discovery on pose averaging and rotation averaging."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from autotight.cli import main
from autotight.discovery import DiscoveredSet, discover, learn
from autotight.discovery.compare import span_residual
from autotight.discovery.samples import draw, relative_violation
from autotight.errors import LearningError, ProblemDefinitionError
from autotight.problem import load
from autotight.sdp import solve_model
from autotight.tightness import judge

SIGMA = 0.1


@pytest.fixture(scope="module")
def pose10():
    return discover("pose_averaging", {"M": 10, "sigma": SIGMA}, seed=0, n_heldout=10)


@pytest.fixture(scope="module")
def pose3():
    return discover("pose_averaging", {"M": 3, "sigma": SIGMA}, seed=3, n_heldout=3, compare=False)


def test_primary_and_paper_in_learned_span(pose10):
    cat, model = pose10.catalog, pose10.model
    # every homogeneous primary constraint of a measurement factor lies in that factor's learned span
    for g in cat.groups:
        basis = cat.basic(g.group.name)
        prims = [c for c in model.primary() if c.b == 0 and set(c.A.tocoo().row) <= set(g.columns)]
        for c in prims:
            assert span_residual(c, basis, g.columns) < 1e-8, c.name
    assert set(pose10.paper_span) == {"R1", "R2"}
    for fam, info in pose10.paper_span.items():
        assert info["max_residual"] < 1e-8, fam


def test_learned_constraints_hold_on_fresh_samples(pose10):
    prob = load("pose_averaging")
    fresh = draw(prob, pose10.instance, 100, np.random.default_rng(123), spread=0.5)
    cands = pose10.catalog.candidates()
    assert len(cands) > 0
    assert relative_violation(cands, fresh.thetas).max() < 1e-9


def test_discovered_set_is_tight_on_heldout_and_smaller_than_paper(pose10):
    assert pose10.tight and pose10.validated
    assert pose10.example.tight_result.log_svr > 5
    held = pose10.points[0].heldout
    assert len(held.seeds) == 10 and held.fraction >= 0.9
    M = pose10.params["M"]
    assert 0 < len(pose10.constraints) <= 4 * M


def test_reinstantiated_set_holds_on_that_instance(pose10, tmp_path):
    prob = load("pose_averaging")
    path = tmp_path / "set.json"
    pose10.discovered.save(path, pose10.model, pose10.constraints)
    ds = DiscoveredSet.load(path)
    assert ds.pairs == pose10.discovered.pairs
    inst = prob.generate({"M": 10, "sigma": SIGMA}, 999)
    model = prob.build(inst)
    cons = ds.instantiate(prob, inst, np.random.default_rng(5), model)
    assert len(cons) == len(pose10.constraints)
    fresh = draw(prob, inst, 100, np.random.default_rng(6), spread=0.5)
    assert relative_violation(cons, fresh.thetas).max() < 1e-9
    res = solve_model(model, model.primary() + cons)
    local = prob.local_solve(inst, inst.truth)
    v = judge(res, local.cost)
    assert v.tight, v.reason
    assert abs(res.primal_cost - local.cost) <= 1e-6 * abs(local.cost)


def test_reduced_set_is_irreducible(pose3):
    """Dropping any pair breaks tightness on some training instance; the whole set is tight on every one."""
    assert pose3.tight
    prob = load("pose_averaging")
    chosen = pose3.discovered.pairs
    assert len(chosen) >= 1
    for tr in pose3.trainers:
        full = [c for q in chosen for c in tr.pairs[q]]
        assert judge(solve_model(tr.model, tr.model.primary() + full), tr.local.best.cost).tight
    for p in chosen:
        broken = []
        for tr in pose3.trainers:
            rest = [c for q in chosen if q != p for c in tr.pairs[q]]
            broken.append(not judge(solve_model(tr.model, tr.model.primary() + rest), tr.local.best.cost).tight)
        assert any(broken), f"dropping {p} keeps the SDP tight on every training instance"
    assert prob.name == pose3.problem


def test_rotation_averaging_needs_nothing():
    res = discover("rotation_averaging", {"M": 5, "sigma": SIGMA}, seed=1, n_heldout=3)
    assert res.tight and res.validated
    assert res.discovered.pairs == [] and res.constraints == []
    assert res.example.tight_result.log_svr > 5
    assert res.points[0].heldout.fraction == 1.0


def test_identities_carry_over_between_factors_and_instances():
    prob = load("pose_averaging")
    idents = []
    for seed in (0, 1):
        inst = prob.generate({"M": 4, "sigma": 0.2}, seed)
        cat = learn(prob, inst, prob.build(inst), np.random.default_rng(seed))
        per_factor = {g.group.name: tuple(g.identities) for g in cat.groups if g.group.type == "pose_meas"}
        assert len(set(per_factor.values())) == 1  # the same free monomials on every factor
        idents.append(next(iter(per_factor.values())))
    assert idents[0] == idents[1]


# --- bad input -------------------------------------------------------------------------------

TOY = '''
import numpy as np
from autotight.model import Factor, Model, QuadForm, Variables
from autotight.problem import Instance, LocalResult, Param
NAME = "toy"
DESCRIPTION = "toy"
PARAMS = {"noise": Param(0.0, "", low=0.0)}
def generate(p, rng): return Instance(NAME, dict(p), {}, {"x": np.array([1.0, 2.0])})
def build(inst):
    V = Variables([("a", 1), ("b", 1)])
    return Model(V, [Factor("f", "t", ("h", "a", "b"), cost=QuadForm(V).add("a", "a", 1.0).matrix())])
def lift(inst, s): return np.array([1.0, s["x"][0], s["x"][1]])
def sample(inst, rng, nominal, spread):
    a = nominal["x"][0] + spread * rng.standard_normal()
    return {"x": np.array([a, a * a + inst.params["noise"] * rng.standard_normal()])}
def cost(inst, s): return float(s["x"][0] ** 2)
def local_solve(inst, init): return LocalResult(init, cost(inst, init), 0, True)
def recover(inst, T): return {"x": T.ravel()[1:]}
def random_state(inst, rng): return sample(inst, rng, inst.truth, 1.0)
def errors(inst, s): return {}
'''


def _write(tmp_path: Path, text: str, name: str = "toy.py") -> str:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return str(p)


def test_no_spectral_gap_is_a_clear_error(tmp_path):
    prob = load(_write(tmp_path, TOY))
    inst = prob.generate({"noise": 1e-4}, 0)
    with pytest.raises(LearningError, match="no clear spectral gap.*smaller"):
        learn(prob, inst, prob.build(inst), np.random.default_rng(0))
    # the same module without noise has a clean gap and finds b = a²
    inst = prob.generate({"noise": 0.0}, 0)
    cat = learn(prob, inst, prob.build(inst), np.random.default_rng(0))
    assert cat.groups[0].gap_decades > 6 and len(cat.candidates()) >= 1


def test_infeasible_sampler_is_a_clear_error(tmp_path):
    bad = TOY.replace("Model(V, [", "Model(V, constraints=[__import__('autotight.model').model.Constraint("
                      "QuadForm(V).add('a','a',1.0).add('h','b',-1.0).matrix(), name='b=a²')], factors=[")
    prob = load(_write(tmp_path, bad))
    inst = prob.generate({"noise": 1e-3}, 0)
    with pytest.raises(LearningError, match="infeasible points.*b=a²"):
        learn(prob, inst, prob.build(inst), np.random.default_rng(0))


def test_inconsistent_block_sizes_are_a_clear_error(tmp_path):
    bad = TOY.replace('V = Variables([("a", 1), ("b", 1)])', 'V = Variables([("a", 1), ("b", 2)])').replace(
        '[Factor("f", "t", ("h", "a", "b"), cost=QuadForm(V).add("a", "a", 1.0).matrix())]',
        '[Factor("f", "t", ("h", "a")), Factor("g", "t", ("h", "b"))]')
    prob = load(_write(tmp_path, bad))
    with pytest.raises(ProblemDefinitionError, match="inconsistent block sizes"):
        prob.build(prob.generate({}, 0))


def test_cli_failure_leaves_nothing_on_disk(tmp_path, capsys):
    path = _write(tmp_path, TOY)
    out = tmp_path / "out.json"
    code = main(["discover", path, "--param", "noise=1e-4", "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "no clear spectral gap" in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".out.json*"))


def test_cli_json_keys(capsys):
    code = main(["discover", "pose_averaging", "-p", "M=3", "--heldout", "2", "--json"])
    assert code == 0
    obj = json.loads(capsys.readouterr().out)
    for key in ("problem", "params", "seed", "tight", "validated", "validation", "n_primary", "n_paper",
                "n_candidate_pairs", "n_pairs", "n_constraints", "points", "paper_in_span", "times"):
        assert key in obj
    assert obj["tight"] is True and obj["n_constraints"] <= obj["n_paper"]
    ev = obj["points"][0]["heldout"]
    assert ev["instances"] == 2 and ev["tight"] + ev["undecided"] + ev["not_tight"] == 2
    assert obj["validated"] is True and obj["validation"]["rounds"][-1]["passed"] is True


# ----------------------------------------------------------------------------- free monomials


def test_a_noise_row_is_not_taken_as_a_free_monomial():
    """A nullspace basis whose last row is numerical noise (1e-11): scanning from the end, that row
    must not become a free monomial, or N_F is near-singular and the basic solutions blow up (they
    did, to 1e16, on σ = 1 trajectory factors)."""
    from autotight.discovery.nullspace import basic_solutions, free_monomials

    rng = np.random.default_rng(4)
    m, k = 40, 6
    N, _ = np.linalg.qr(rng.standard_normal((m, k)))
    N[-1] = 1e-11 * rng.standard_normal(k)  # a monomial outside every relation, up to noise
    N, _ = np.linalg.qr(N)
    F = free_monomials(N)
    assert m - 1 not in F and len(F) == k
    V = basic_solutions(N, F)
    assert np.allclose(V[F], np.eye(k))
    assert np.abs(V).max() < 1e4  # well conditioned
    # V spans the same space as N
    P = N @ N.T
    assert np.linalg.norm(V - P @ V) <= 1e-10 * np.linalg.norm(V)


def test_ill_conditioned_free_monomials_are_refused():
    from autotight.discovery.nullspace import basic_solutions

    N = np.array([[1.0, 0.0], [0.0, 1e-12], [0.0, 0.0]])
    with pytest.raises(LearningError, match="ill-conditioned"):
        basic_solutions(N, np.array([0, 1]))


def test_every_motion_factor_learns_the_same_relations_at_high_noise():
    """Continuous time, K = 11, σ = 0.3, seed 0: every motion factor's basic solutions have the same
    identities and contain the paper's R3, R6 and R8 (before the fix, four factors had garbage bases)."""
    from autotight.discovery.compare import paper_in_span

    prob = load("continuous_trajectory")
    inst = prob.generate(prob.parse_params({"K": 11, "sigma": 0.3}), 0)
    model = prob.build(inst)
    cat = learn(prob, inst, model, np.random.default_rng([0, 2]), "factors", types=["motion"])
    motion = [g for g in cat.groups if g.group.type == "motion"]
    assert len(motion) == 10
    assert all(g.identities == motion[0].identities for g in motion)
    assert max(np.abs(g.coeffs).max() for g in motion) < 1e3
    span = paper_in_span(cat)
    for fam in ("R3", "R6", "R8"):
        assert span[fam]["max_residual"] < 1e-8, (fam, span[fam])
