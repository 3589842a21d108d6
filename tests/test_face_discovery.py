"""`--accept cost` on a lifting with free columns, as a user writing a module would meet it.

The module (tests/stereo_translation_module.py) has a substitution variable u_j = [q_x, 1]/q_y and a
product block w_j = u_j tᵀ that no valid quadratic relation bounds.  Its primary constraints are not tight;
relations learned per landmark pair make it cost-tight, and the certificate must set the free columns aside
(``autotight.face``).
"""

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import api
from autotight.certificate import dual_matrix, stack
from autotight.face import DEPENDENT_RTOL, face_dual, forced_face, independent_rows
from autotight.pipeline import solve_instance
from autotight.problem import load
from autotight.sdp import solve_model
from autotight.tightness import Criteria

MODULE = str(Path(__file__).parent / "stereo_translation_module.py")
PARAMS = {"prior_sigma": 2.0}
COST = Criteria(accept="cost")


@pytest.fixture(scope="module")
def learned():
    """A discovery without held-out validation (training and reduction only) on seed 0."""
    return api.discover(MODULE, PARAMS, 0, criteria=COST, n_heldout=0, progress=None)


def test_primary_alone_is_not_tight_and_the_reason_names_the_free_blocks():
    p = load(MODULE)
    r = solve_instance(p, p.generate(PARAMS, seed=0), "primary", criteria=COST)
    assert not r.tight and r.verdict.rel_gap > 1e-2
    assert "w_" in r.verdict.reason  # the blocks nothing bounds


def test_discover_reaches_certified_cost_tight_and_reduces(learned):
    """Tight on the training instance, fewer pairs kept than the greedy pass added, and the kept set is
    certified there: H vanishes on the columns set aside, and the bound is within the bracket's tolerance."""
    rec = learned.record()
    assert rec["tight"] is True and rec["accept"] == "cost"
    assert 0 < rec["n_pairs"] < rec["n_greedy_pairs"] and rec["irreducible"]
    p = load(MODULE)
    inst = p.generate(PARAMS, seed=0)
    r = solve_instance(p, inst, learned.constraint_set, criteria=COST)
    c = r.certificate
    assert r.tight and c.certified and c.face
    assert c.free_residual <= 1e-12 and c.rel_bound <= COST.gap_tol
    assert abs(r.upper - r.local.from_truth.cost) <= 1e-6 * r.upper  # the point certified is the local optimum


def test_face_dual_vanishes_on_the_face_and_is_psd_off_it(learned):
    """The multipliers of the face's own SDP: H(y) is 0 on the rows set aside (to roundoff of max|H|) and
    positive semidefinite on the others, with the lifted local optimum in its null space."""
    p = load(MODULE)
    inst = p.generate(PARAMS, seed=0)
    model = p.build(inst)
    from autotight.constraint_set import resolve
    from autotight.pipeline import seeds

    cons = resolve(learned.constraint_set, p, inst, model, seeds(0).constraints())
    x = np.atleast_2d(p.lift(inst, p.local_solve(inst, inst.truth).state))
    As, _ = stack(cons)
    res = solve_model(model, cons)
    y, F = forced_face(model.Q, As, res.y, x)
    got = face_dual(model.Q, cons, F)
    assert got is not None
    H = dual_matrix(model.Q, As, got[0]).toarray()
    K = np.setdiff1d(np.arange(H.shape[0]), F)
    top = np.abs(H).max()
    assert np.abs(H[F]).max() <= 1e-12 * top
    assert np.linalg.eigvalsh(H[np.ix_(K, K)])[0] >= -1e-9 * top
    assert np.linalg.norm(H @ x.T) <= 1e-6 * top * np.linalg.norm(x)


@pytest.mark.slow
def test_discover_validates_on_held_out_instances():
    """The full discovery: validated on fresh held-out instances (tight / decided ≥ 0.9, as check counts)."""
    res = api.discover(MODULE, PARAMS, 0, criteria=COST, progress=None)
    rec = res.record()
    assert rec["tight"] is True and rec["validated"] is True
    held = rec["points"][0]["heldout"]
    assert held["instances"] >= 10 and held["fraction"] >= 0.9 and held["tight"] >= held["instances"] // 2


def test_independent_rows_span_the_rows_and_leave_out_the_dependent_ones():
    """Rows a, 2a, b, a + b·(1 + 1e-9) and a zero row: two rows are kept (a + b·(1 + 1e-9) is dependent to
    far below DEPENDENT_RTOL), the zero row never, and every row is a combination of the kept ones."""
    rng = np.random.default_rng(3)
    a = sp.random_array((1, 400), density=0.02, rng=rng).toarray()[0]
    b = sp.random_array((1, 400), density=0.02, rng=rng).toarray()[0]
    R = sp.csr_array(np.vstack([a, 2 * a, b, a + b * (1 + 1e-9), np.zeros(400)]))
    sel, norms = independent_rows(R)
    assert sel.size == 2 and 4 not in sel
    assert np.allclose(norms, np.linalg.norm(R.toarray()[sel], axis=1))
    basis = R.toarray()[sel]
    coef, *_ = np.linalg.lstsq(basis.T, R.toarray().T, rcond=None)
    assert np.abs(basis.T @ coef - R.toarray().T).max() <= DEPENDENT_RTOL * np.abs(R.toarray()).max()
