"""Recession directions that are combinations of columns (``autotight.recession``).

Toy QCQP on x = [h, a, b]: min (a + b − 2h)² + (a + b − 3h)²/10 s.t. h² = 1, a² = b².  Along
v = e_a − e_b both the constraint and the cost are flat (vᵀAv = 1 − 1 = 0, (v_a + v_b)² = 0), so the
relaxation's optimal set is unbounded along v although a and b each appear squared: no column is a
recession column, no trace bound exists and H has v in its null space.  With s = a + b the cost is a
convex quadratic in s, minimised at s* = 23/11 (a = b = s*/2 is feasible), so p* = (s* − 2)² + (s* − 3)²/10
= 1/11 and the relaxation is tight in cost.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from autotight import api, sdp
from autotight.certificate import certificate
from autotight.constraint_set import ConstraintSet
from autotight.model import Constraint
from autotight.recession import NULL_RTOL, Frame, echelon, frame_certificate, null_dimension, recession_frame
from autotight.tightness import Criteria

COST = Criteria(accept="cost")

P_STAR = 1.0 / 11.0
S_STAR = 23.0 / 11.0


def _toy(extra: bool = False):
    u1, u2 = np.array([-2.0, 1.0, 1.0]), np.array([-3.0, 1.0, 1.0])
    Q = sp.csr_array(np.outer(u1, u1) + np.outer(u2, u2) / 10)
    cons = [Constraint(sp.coo_array(([1.0], ([0], [0])), shape=(3, 3)), 1.0, name="h²", family="homogenisation"),
            Constraint(sp.coo_array(np.diag([0.0, 1.0, -1.0])), 0.0, name="a² = b²", family="primary")]
    if extra:  # a² = h² too: a, b = ±1, nothing is free
        cons.append(Constraint(sp.coo_array(np.diag([-1.0, 1.0, 0.0])), 0.0, name="a² = h²", family="primary"))
    return Q, cons


def test_the_toy_direction_is_found_exactly_and_certifies():
    Q, cons = _toy()
    theta = np.array([1.0, S_STAR / 2, S_STAR / 2])
    assert abs(theta @ Q @ theta - P_STAR) < 1e-14
    res = sdp.solve(Q, cons)
    plain = certificate(Q, cons, res.y, theta)
    assert not plain.certified  # v is in H's null space and nothing bounds tr X
    got = recession_frame(Q, cons, res.y)
    assert got is not None
    frame = got[0]
    v = frame.directions[0] * frame.directions[0][frame.pivots[0]]
    assert frame.directions.shape == (1, 3)
    assert np.array_equal(np.abs(v), [0.0, 1.0, 1.0]) and v[1] == -v[2]  # ±(e_a − e_b), exactly
    got = frame_certificate(Q, cons, res.y, theta, plain, names=["h", "a", "b"])
    assert got is not None
    y, cert, note, free, (Qf, cons_f, theta_f) = got
    assert cert.certified and cert.rel_bound <= 1e-6
    # the bound is one of the given relaxation: bᵀy (same b) never exceeds the optimum
    b = np.array([c.b for c in cons])
    assert b @ y <= P_STAR + 1e-9 and P_STAR - b @ y <= 1e-6 * P_STAR
    assert "a − b" in cert.face or "−a + b" in cert.face


def test_no_frame_when_nothing_recedes():
    Q, cons = _toy(extra=True)
    res = sdp.solve(Q, cons)
    assert recession_frame(Q, cons, res.y) is None


def test_the_frame_is_a_congruence():
    rng = np.random.default_rng(0)
    n = 6
    rows = np.array([[0.0, 1.0, 0.0, -1.0, 0.5, 0.0], [0.0, 0.0, 1.0, 0.0, -1.0, 2.0]])
    frame = Frame.of(rows, np.array([1, 2]))
    assert np.allclose((frame.T @ frame.T_inv).toarray(), np.eye(n), atol=0, rtol=0)
    assert np.allclose(frame.T.toarray()[:, [1, 2]], rows.T)  # the directions are the frame's columns
    A = rng.standard_normal((n, n))
    A = sp.csr_array(A + A.T)
    G = rng.standard_normal((n, n))
    Xp = G @ G.T  # X′ ⪰ 0
    X = frame.T @ Xp @ frame.T.T
    assert abs(np.sum(frame.congruent(A).toarray() * Xp) - np.sum(A.toarray() * X)) <= 1e-12 * np.abs(A).sum() * \
        np.abs(X).max()
    x = rng.standard_normal(n)
    assert np.allclose(frame.T @ frame.point(x), x, rtol=0, atol=1e-14)


def test_echelon_snaps_to_simple_fractions():
    rng = np.random.default_rng(1)
    rows = np.array([[1.0, 0.0, -1.0, 0.5], [0.0, 1.0, 1.0 / 3.0, 0.0]])
    V = rows.T @ rng.standard_normal((2, 2))  # the same span, mixed
    got, piv = echelon(V + 1e-9 * rng.standard_normal(V.shape))
    # the span is the same and its entries are the exact fractions again
    assert np.linalg.matrix_rank(np.vstack([got, rows]), tol=1e-12) == 2
    assert all(float(Fraction(e).limit_denominator(12)) == e for e in got.ravel())


ROBUST_SET = Path(__file__).parent / "data" / "robust_wahba_2d3.json"


def test_robust_wahba_is_certified_in_the_frame_of_its_free_translation():
    """Robust Wahba (d = 2, N = 3) with a set discovered by ``autotight discover robust_wahba -p dim=2
    -p n_points=3 --accept cost`` (tests/data): the relaxation grows at no cost along t_a − Σᵢ zᵢ,a (all
    points outliers), so only the frame of those directions certifies.  Each certificate's bound bᵀy is
    checked against the global optimum (the module's local solver enumerates the labellings)."""
    cs = ConstraintSet.load(ROBUST_SET)
    certified = 0
    for seed in range(1, 7):
        r = api.solve("robust_wahba", {"dim": 2, "n_points": 3}, seed, constraints=cs, criteria=COST)
        c = r.certificate
        global_cost = r.local.best.cost
        assert c.dual_value <= global_cost + 1e-9 * abs(global_cost)  # a lower bound, whatever is claimed
        if c.certified:
            assert c.rel_bound <= COST.gap_tol and "recession direction" in c.face
            for a, k in (("x", 0), ("y", 1)):  # both directions, in either sign
                assert (f"−t.{a} + z0.{k} + z1.{k} + z2.{k}" in c.face or f"t.{a} − z0.{k} − z1.{k} − z2.{k}"
                        in c.face)
            certified += 1
    assert certified >= 4


def test_certify_without_the_sdp_uses_the_frame_too():
    """``autotight certify`` (local solve, multipliers from the clique barrier, no full SDP) on the same set:
    the barrier's y certifies nothing in the given frame; in the frame of the two directions it does, and
    the lower bound it proves, f(x̂) − bound, is below the global optimum (the labellings enumerated)."""
    cs = ConstraintSet.load(ROBUST_SET)
    params = {"dim": 2, "n_points": 3}
    cert = api.certify("robust_wahba", params, 1, constraints=cs)
    assert cert.certified and cert.rel_bound <= COST.gap_tol and "recession direction" in cert.face
    prob = api.load_problem("robust_wahba")
    inst = prob.generate(prob.parse_params(params), 1)
    global_cost = prob.local_solve(inst, inst.truth).cost
    assert abs(cert.cost - global_cost) <= 1e-9 * global_cost  # x̂ is the global optimum …
    assert cert.cost - cert.bound <= global_cost  # … and the bound proved is below it


def test_a_null_space_holds_only_eigenvalues_far_below_the_largest():
    """H's near-null space ends at its largest gap among eigenvalues ≤ NULL_RTOL·max|w|: a larger gap between two
    parts of the range (0.36 → 300 here; 0.36 → 39 on robust Wahba) is not a null space."""
    rng = np.random.default_rng(0)
    null = np.array([1e-7, 1.5e-7, 2e-7, 3e-7])  # x̂ and three directions
    smeared = np.geomspace(5e-5, 0.36, 49)  # consecutive ratios ≈ 1.2: no gap inside
    big = np.array([300.0, 400.0, 500.0, 700.0, 800.0, 900.0, 1000.0])
    assert 300 / 0.36 > 5e-5 / 3e-7 > 100 and 0.36 > NULL_RTOL * 1000  # the largest gap lies beyond NULL_RTOL
    w = rng.permutation(np.concatenate([null, smeared, big])) * rng.choice([-1.0, 1.0], 60)
    assert null_dimension(w) == null.size
    assert null_dimension(np.concatenate([smeared, big])) == 0  # nothing near null at all
