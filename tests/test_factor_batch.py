"""Batched factor construction (``autotight.factor_batch``) reproduces the per-factor builders."""

import numpy as np
import pytest
import scipy.sparse as sp

import autotight as at
from autotight.errors import ProblemDefinitionError
from autotight.factor_batch import FactorBatch, coefficients, features, probe_points
from autotight.model import QuadForm, Variables, fast_coo


def test_fast_coo_equals_scipy_constructor():
    rng = np.random.default_rng(0)
    keys = np.unique(rng.integers(0, 50 * 50, 40))
    r, c = np.divmod(keys, 50)
    v = rng.standard_normal(keys.size)
    A, B = fast_coo(v, r, c, 50), sp.coo_array((v, (r, c)), shape=(50, 50))
    assert A.shape == B.shape and A.nnz == B.nnz
    assert np.array_equal(A.toarray(), B.toarray())
    x = rng.standard_normal(50)
    assert np.allclose(A @ x, B @ x, rtol=0, atol=1e-14)


@pytest.mark.parametrize("degree", [1, 2])
def test_polynomial_interpolation_is_exact(degree):
    rng = np.random.default_rng(1)
    p = 4
    coef = rng.standard_normal((features(np.zeros((1, p)), degree).shape[1], 3))
    D = rng.standard_normal((5, p))
    values = features(probe_points(p, degree), degree) @ coef
    assert np.allclose(features(D, degree) @ coefficients(values, p, degree), features(D, degree) @ coef,
                       rtol=0, atol=1e-12)


def test_non_polynomial_builder_is_refused():
    V = Variables([("x", 2)])

    def build(d):
        return [QuadForm(V).add("x", "x", np.diag([np.sin(d[0]), 1.0])).matrix()]

    batch = FactorBatch(build, V.N, 1, 1)
    with pytest.raises(ProblemDefinitionError):
        batch.values(np.array([[0.7], [1.3]]))


def test_batched_discrete_build_equals_direct():
    """Discrete trajectory's factors made at once by ``pose_batch`` equal those made one by one by ``_pose``
    (the hand-written builds, ``discrete_reference``), constraint by constraint, to rounding."""
    from discrete_reference import hand_written_model

    prob = at.load_problem("discrete_trajectory")
    inst = prob.generate({"K": 12, "sigma": 0.2}, 3)
    batched = hand_written_model(inst, batched=True)
    direct = hand_written_model(inst)
    ca, cb = direct.all_constraints(), batched.all_constraints()
    assert len(ca) == len(cb) > 0
    worst = 0.0
    for a, b in zip(ca, cb):
        assert (a.name, a.family, a.factor, a.b) == (b.name, b.family, b.factor, b.b)
        assert np.array_equal(a.A.row, b.A.row) and np.array_equal(a.A.col, b.A.col)
        worst = max(worst, float(np.abs(a.A.data - b.A.data).max() / np.abs(a.A.data).max()))
    assert worst < 1e-14
    assert abs(direct.Q - batched.Q).max() < 1e-14
    assert [(f.name, f.type, f.blocks, f.roles) for f in direct.factors] == \
        [(f.name, f.type, f.blocks, f.roles) for f in batched.factors]
    # the batched model's constraints hold at the true state's lifting
    x = prob.lift(inst, prob.local_solve(inst, inst.truth).state).ravel()
    assert max(abs(c.value(np.outer(x, x))) for c in cb) < 1e-9


def test_batched_pose_averaging_build_equals_direct():
    """Pose averaging's measurement factors made at once by ``pose_batch`` (as discrete_trajectory makes them)
    equal those made one by one by ``_pose``, constraint by constraint, to rounding."""
    from pose_reference import hand_written_model

    prob = at.load_problem("pose_averaging")
    inst = prob.generate({"M": 9, "sigma": 0.2}, 5)
    batched, direct = hand_written_model(inst, batched=True), hand_written_model(inst)
    ca, cb = direct.all_constraints(), batched.all_constraints()
    assert [(c.name, c.family, c.factor, c.b) for c in ca] == [(c.name, c.family, c.factor, c.b) for c in cb]
    for a, b in zip(ca, cb):
        assert np.array_equal(a.A.row, b.A.row) and np.array_equal(a.A.col, b.A.col)
        assert np.abs(a.A.data - b.A.data).max() <= 1e-14 * np.abs(a.A.data).max()
    assert abs(direct.Q - batched.Q).max() < 1e-14
    assert [(f.name, f.type, f.blocks, f.roles) for f in direct.factors] == \
        [(f.name, f.type, f.blocks, f.roles) for f in batched.factors]
