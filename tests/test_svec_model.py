"""svec convention, monomials, quadratic-form builders and Model validation.

Tolerances: all identities here are exact in real arithmetic; they are checked to 1e-12
relative to the size of the quantities involved (a few ulps times the number of terms).
"""

from __future__ import annotations

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp

from autotight.affine import LEVI, Affine, const, cross_rows, cayley_rows, quad, var
from autotight.errors import ProblemDefinitionError
from autotight.model import Constraint, Factor, Model, QuadForm, Variables
from autotight.svec import (monomials, poly_to_sym, reusing_entries, smat, stored_entries, svec, svec_dim, svec_sparse,
                            sym_to_poly, triu_indices)
from autotight import sdp

REL = 1e-12


def rand_sym(rng: np.random.Generator, n: int) -> np.ndarray:
    B = rng.standard_normal((n, n))
    return (B + B.T) / 2


def rand_sparse_sym(rng: np.random.Generator, n: int, density: float = 0.2) -> sp.csr_array:
    B = sp.random_array((n, n), density=density, rng=rng, data_sampler=rng.standard_normal)
    return sp.csr_array((B + B.T) / 2)


# ----------------------------------------------------------------------------- svec / smat


@pytest.mark.parametrize("n", [1, 2, 5, 12])
def test_svec_smat_round_trip(n):
    rng = np.random.default_rng(100 + n)
    X = rand_sym(rng, n)
    v = svec(X)
    assert v.shape == (svec_dim(n),)
    np.testing.assert_allclose(smat(v), X, rtol=0, atol=REL * np.abs(X).max())
    np.testing.assert_allclose(smat(v, n), X, rtol=0, atol=REL * np.abs(X).max())
    # and the other way round, starting from an arbitrary vector
    w = rng.standard_normal(svec_dim(n))
    np.testing.assert_allclose(svec(smat(w)), w, rtol=0, atol=REL * np.abs(w).max())


def test_svec_is_an_isometry_for_sparse_symmetric():
    """⟨A, X⟩ = tr(AX) = svec(A)·svec(X), and the dense/sparse/column svec variants agree."""
    rng = np.random.default_rng(7)
    for n in (3, 8, 20):
        for _ in range(5):
            A = rand_sparse_sym(rng, n)
            X = rand_sym(rng, n)
            inner = float(np.trace(A.toarray() @ X))
            scale = np.abs(A.toarray()).sum() * np.abs(X).max()
            assert abs(svec(A) @ svec(X) - inner) <= REL * scale
            assert abs(svec(A.toarray()) @ svec(X) - inner) <= REL * scale
            col = svec_sparse(A)
            assert col.shape == (svec_dim(n), 1)
            np.testing.assert_allclose(col.toarray().ravel(), svec(A.toarray()), rtol=0, atol=REL)
            # Frobenius norm is preserved
            assert abs(np.linalg.norm(svec(X)) - np.linalg.norm(X)) <= REL * np.linalg.norm(X)


def test_reused_entries_are_the_same_sums_and_read_only():
    rng = np.random.default_rng(3)
    As = [sp.coo_array(sp.random_array((6, 6), density=0.3, rng=rng)) for _ in range(5)]
    As = [sp.coo_array(A + A.T) for A in As] + [sp.csr_array(np.eye(6))]
    fresh = stored_entries(As)
    with reusing_entries():
        first = stored_entries(As)
        again = stored_entries(list(As))  # another list of the same matrices
        other = stored_entries(As[:3])
        with reusing_entries():  # nested: the outer block's results
            inner = stored_entries(As)
    for a, b, c, d in zip(fresh, first, again, inner):
        np.testing.assert_array_equal(a, b)
        assert c is b and d is b
    assert other[3].max() == 2 and other[0].size < first[0].size
    with pytest.raises(ValueError):
        first[2][0] = 1.0  # shared between calls: read-only
    after = stored_entries(As)  # the block has ended: computed afresh, writable
    assert after[2] is not first[2] and after[2].flags.writeable


def test_svec_order_is_column_major_upper_triangle():
    i, j = triu_indices(3)
    assert list(zip(i.tolist(), j.tolist())) == [(0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2)]
    X = np.array([[1.0, 2.0, 4.0], [2.0, 3.0, 5.0], [4.0, 5.0, 6.0]])
    r2 = np.sqrt(2.0)
    np.testing.assert_allclose(svec(X), [1, 2 * r2, 3, 4 * r2, 5 * r2, 6], rtol=1e-15)


def _clarabel_min_eig(C: np.ndarray, order: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, np.ndarray]:
    """min ⟨C, X⟩ s.t. tr X = 1, X ⪰ 0 given to Clarabel on x = svec(X) (our order by default).

    With ``order`` the objective is laid out in a different triangle order, as a wrong svec would.
    """
    n = C.shape[0]
    m = svec_dim(n)
    q = svec(C)
    if order is not None:
        i, j = order
        q = C[i, j] * np.where(i == j, 1.0, np.sqrt(2.0))
    A = sp.vstack([sp.csc_array(svec(np.eye(n))[None, :]), -sp.eye_array(m)], format="csc")
    b = np.concatenate([[1.0], np.zeros(m)])
    s = clarabel.DefaultSettings()
    s.verbose = False
    s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = 1e-10
    sol = clarabel.DefaultSolver(sp.csc_matrix((m, m)), q, sp.csc_matrix(A), b,
                                 [clarabel.ZeroConeT(1), clarabel.PSDTriangleConeT(n)], s).solve()
    assert str(sol.status) == "Solved"
    return float(sol.obj_val), smat(np.asarray(sol.x), n)


def test_svec_order_matches_clarabel_psd_triangle_cone():
    """min ⟨C,X⟩, tr X = 1, X ⪰ 0 has the solution X = v vᵀ, v the eigenvector of λ_min(C).

    Clarabel returns it in our svec layout only if svec and PSDTriangleConeT agree on the order
    and on the √2 scaling; a row-major layout of the same data gives a different X.
    """
    rng = np.random.default_rng(11)
    n = 4
    C = rand_sym(rng, n)
    w, V = np.linalg.eigh(C)
    assert w[1] - w[0] > 1e-2  # distinct smallest eigenvalue, so the optimum is unique
    v = V[:, 0]
    val, X = _clarabel_min_eig(C)
    assert abs(val - w[0]) <= 1e-7 * max(1.0, abs(w[0]))
    np.testing.assert_allclose(X, np.outer(v, v), atol=1e-6)
    # the same helper library call through autotight.sdp (dense dual form) agrees
    res = sdp.solve(sp.csr_array(C), [Constraint(sp.csr_array(np.eye(n)), 1.0, name="trace")])
    assert res.status == "Solved"
    np.testing.assert_allclose(res.X, np.outer(v, v), atol=1e-6)
    assert abs(res.primal_cost - w[0]) <= 1e-7 * max(1.0, abs(w[0]))
    # control: a row-major upper-triangle layout is not what Clarabel expects
    ii, jj = np.triu_indices(n)
    _, X_wrong = _clarabel_min_eig(C, order=(ii, jj))
    assert np.abs(X_wrong - np.outer(v, v)).max() > 1e-2


# ----------------------------------------------------------------------------- monomials


@pytest.mark.parametrize("d", [1, 2, 3])
def test_poly_sym_monomials_consistent(d):
    """⟨poly_to_sym(p), ΘᵀΘ⟩ = p · m(Θ) for vector (d = 1) and matrix (d = 2, 3) liftings."""
    rng = np.random.default_rng(20 + d)
    N = 7
    S = 6
    Thetas = rng.standard_normal((S, d, N))
    m = monomials(Thetas)
    assert m.shape == (S, svec_dim(N))
    for _ in range(5):
        p = rng.standard_normal(svec_dim(N)) * (rng.random(svec_dim(N)) < 0.4)
        A = poly_to_sym(p, N)
        assert sp.issparse(A)
        assert abs(A - A.T).max() == 0
        np.testing.assert_allclose(sym_to_poly(A), p, rtol=0, atol=REL)
        np.testing.assert_allclose(sym_to_poly(A.toarray()), p, rtol=0, atol=REL)
        for s in range(S):
            T = Thetas[s]
            X = T.T @ T
            direct = float(np.sum(A.toarray() * X))
            if d == 1:
                x = T[0]
                assert abs(x @ A.toarray() @ x - direct) <= REL * np.abs(p).sum() * np.abs(X).max()
            assert abs(p @ m[s] - direct) <= REL * np.abs(p).sum() * np.abs(X).max()
            # monomials are the entries of ΘᵀΘ in svec order, without √2
            np.testing.assert_allclose(m[s] * np.where(np.equal(*triu_indices(N)), 1.0, np.sqrt(2.0)), svec(X),
                                       rtol=1e-13, atol=1e-13)


def test_sym_to_poly_inverts_arbitrary_symmetric():
    rng = np.random.default_rng(3)
    A = rand_sparse_sym(rng, 9, density=0.3)
    p = sym_to_poly(A)
    np.testing.assert_allclose(poly_to_sym(p, 9).toarray(), A.toarray(), rtol=0, atol=REL)


def test_monomials_rejects_bad_shape():
    with pytest.raises(ValueError):
        monomials(np.zeros((3, 4)))


# ----------------------------------------------------------------------------- QuadForm / Affine


def _vars(d: int = 1) -> Variables:
    return Variables([("a", 3), ("b", 2), ("c", 3)], d=d)


def _rand_theta(V: Variables, rng: np.random.Generator, h_sign: float = 1.0) -> np.ndarray:
    vals = {n: rng.standard_normal((V.d, V.sizes[n])) if V.d > 1 else rng.standard_normal(V.sizes[n])
            for n in V.names[1:]}
    T = V.assemble(vals)
    T[:, V.slice("h")] *= h_sign
    return T


def _ev(A: sp.sparray, T: np.ndarray) -> float:
    return float(np.sum(A.toarray() * (T.T @ T)))


@pytest.mark.parametrize("h_sign", [1.0, -1.0])
def test_quadform_vector_lifting(h_sign):
    """add, linear and const build exactly x_aᵀ M x_b, h vᵀx_b and c h² (checked with h = ±1)."""
    rng = np.random.default_rng(31)
    V = _vars()
    M = rng.standard_normal((3, 2))
    v = rng.standard_normal(3)
    c0 = 1.7
    A = QuadForm(V).add("a", "b", M).linear("c", v).const(c0).add("c", "c", 2.5).matrix()
    assert abs(A - A.T).max() == 0
    for _ in range(10):
        T = _rand_theta(V, rng, h_sign)
        x = T[0]
        h, xa, xb, xc = x[V.slice("h")][0], x[V.slice("a")], x[V.slice("b")], x[V.slice("c")]
        expected = xa @ M @ xb + h * (v @ xc) + c0 * h * h + 2.5 * xc @ xc
        assert abs(_ev(A, T) - expected) <= REL * (1 + abs(expected)) * 10


def test_quadform_matrix_lifting_d2():
    """d = 2: add(a, b, M) = Σ M_ij θ_{a,i}ᵀ θ_{b,j}; const(c) = c because the h block is I."""
    rng = np.random.default_rng(32)
    V = _vars(d=2)
    M = rng.standard_normal((3, 2))
    A = QuadForm(V).add("a", "b", M).const(3.0).matrix()
    for _ in range(10):
        T = _rand_theta(V, rng)
        Ta, Tb = T[:, V.slice("a")], T[:, V.slice("b")]
        expected = float(np.sum(M * (Ta.T @ Tb))) + 3.0
        assert abs(_ev(A, T) - expected) <= 1e-12 * (1 + abs(expected)) * 10
    with pytest.raises(ProblemDefinitionError):
        QuadForm(V).linear("a", np.ones(3))


def test_quadform_rejects_bad_shapes_and_blocks():
    V = _vars()
    with pytest.raises(ProblemDefinitionError, match="shape"):
        QuadForm(V).add("a", "b", np.ones((2, 3)))
    with pytest.raises(ProblemDefinitionError, match="scalar coefficient"):
        QuadForm(V).add("a", "b", 1.0)
    with pytest.raises(ProblemDefinitionError, match="unknown block 'zz'"):
        QuadForm(V).add("a", "zz", np.ones((3, 3)))


def test_affine_quad_cross_and_cayley_rows():
    """quad(u, w, L) = uᵀLw; cross_rows = φ × u; cayley_rows = a − b − ½ φ × (a + b) per component."""
    rng = np.random.default_rng(33)
    V = Variables([("c", 3), ("phi", 3), ("r", 3)])
    G = rng.standard_normal((3, 3))
    k = rng.standard_normal(3)
    u = var("c", G) + const(k)  # u = G c + k h
    w = var("r") - 0.5 * var("phi")
    L = rng.standard_normal((3, 3))
    Aq = quad(V, u, w, L).matrix()
    crosses = [q.matrix() for q in cross_rows(V, var("phi"), u)]
    ct = rng.standard_normal(3)
    cay = cayley_rows(V, "phi", var("c"), const(ct))
    cay_rho = cayley_rows(V, "phi", var("c"), const(ct), rho=var("r"))
    for _ in range(10):
        x = rng.standard_normal(V.N)
        x[0] = 1.0
        T = x[None, :]
        c, phi, r = x[V.slice("c")], x[V.slice("phi")], x[V.slice("r")]
        uu, ww = G @ c + k, r - 0.5 * phi
        scale = 1 + np.abs(uu).max() * np.abs(ww).max() * 10
        assert abs(_ev(Aq, T) - uu @ L @ ww) <= REL * scale
        np.testing.assert_allclose([_ev(A, T) for A in crosses], np.cross(phi, uu), rtol=0, atol=REL * scale)
        np.testing.assert_allclose([_ev(A, T) for A in cay], c - ct - 0.5 * np.cross(phi, c + ct),
                                   rtol=0, atol=REL * scale)
        np.testing.assert_allclose([_ev(A, T) for A in cay_rho], c - ct - 0.5 * np.cross(phi, c + ct) - r,
                                   rtol=0, atol=REL * scale)
    # the Levi-Civita tensor matches numpy's cross product
    a, b = rng.standard_normal(3), rng.standard_normal(3)
    np.testing.assert_allclose([a @ LEVI[q] @ b for q in range(3)], np.cross(a, b), rtol=1e-14, atol=1e-14)


def test_affine_rows_must_agree():
    with pytest.raises(ValueError):
        Affine({"a": np.eye(3)}) + Affine({"b": np.ones((2, 3))})


# ----------------------------------------------------------------------------- Variables / Model


def test_variables_layout_and_assemble():
    V = Variables([("a", 3), ("b", 2)])
    assert V.names == ["h", "a", "b"] and V.N == 6
    assert V.slice("b") == slice(4, 6)
    np.testing.assert_array_equal(V.index(["b", "h"]), [4, 5, 0])
    assert V.block_of(4) == ("b", 0)
    T = V.assemble({"a": [1, 2, 3], "b": [4, 5]})
    np.testing.assert_array_equal(T, [[1, 1, 2, 3, 4, 5]])
    with pytest.raises(ProblemDefinitionError, match="missing blocks"):
        V.assemble({"a": [1, 2, 3]})
    with pytest.raises(ProblemDefinitionError, match="shape"):
        V.assemble({"a": [1, 2], "b": [4, 5]})
    V2 = Variables([("a", 2)], d=2)
    T2 = V2.assemble({"a": np.arange(4.0).reshape(2, 2)})
    np.testing.assert_array_equal(T2[:, :2], np.eye(2))


def test_variables_validation():
    with pytest.raises(ProblemDefinitionError, match="duplicate block names"):
        Variables([("a", 3), ("a", 2)])
    with pytest.raises(ProblemDefinitionError, match="duplicate block names"):
        Variables([("h", 3)])
    with pytest.raises(ProblemDefinitionError, match="positive size"):
        Variables([("a", 0)])
    with pytest.raises(ProblemDefinitionError, match="width d"):
        Variables([("a", 3)], d=4)


def _model_parts():
    V = Variables([("a", 3), ("b", 3), ("e", 2)])
    A = QuadForm(V).add("a", "a", 1.0).const(-1.0).matrix()
    return V, A


def test_model_validation_errors():
    V, A = _model_parts()
    ok = Model(V, [Factor("f1", "t", ("h", "a"), cost=A), Factor("f2", "t", ("h", "b"))])
    assert ok.Q.shape == (V.N, V.N)
    # Q is the sum of the factor costs
    assert abs(ok.Q - A).max() == 0
    with pytest.raises(ProblemDefinitionError, match="unknown block 'zz'"):
        Model(V, [Factor("f1", "t", ("h", "zz"))])
    with pytest.raises(ProblemDefinitionError, match="inconsistent block sizes"):
        Model(V, [Factor("f1", "t", ("h", "a")), Factor("f2", "t", ("h", "e"))])
    with pytest.raises(ProblemDefinitionError, match="unique"):
        Model(V, [Factor("f1", "t", ("h", "a")), Factor("f1", "t", ("h", "b"))])
    with pytest.raises(ProblemDefinitionError, match="shape"):
        Model(V, [Factor("f1", "t", ("h", "a"), constraints=[Constraint(sp.csr_array((3, 3)), 0.0, "small")])])
    with pytest.raises(ProblemDefinitionError, match="roles"):
        Factor("f1", "t", ("h", "a"), roles=("h",))
    with pytest.raises(ProblemDefinitionError, match="unknown paper families"):
        ok.paper_constraints(["R9"])
    with pytest.raises(ProblemDefinitionError, match="no factor named"):
        ok.factor("nope")


def test_model_homogenisation_and_primary():
    """h² = 1 for d = 1; X_hh = I for d = 2 (3 constraints); factor constraints are included."""
    V, A = _model_parts()
    c = Constraint(A, 0.0, name="a'a=1")
    m1 = Model(V, [Factor("f1", "t", ("a",), constraints=[c])])
    assert m1.factors[0].blocks == ("h", "a")  # h is put first
    prim = m1.primary()
    assert [p.family for p in prim] == ["homogenisation", "primary"]
    assert prim[1].factor == "f1"
    x = np.zeros(V.N)
    x[0], x[1:4] = 1.0, [0.6, 0.8, 0.0]
    X = np.outer(x, x)
    assert [abs(p.value(X)) for p in prim] == [0.0, pytest.approx(0.0, abs=1e-15)]
    V2 = Variables([("a", 2)], d=2)
    m2 = Model(V2, [])
    hom = m2.homogenisation()
    assert len(hom) == 3
    rng = np.random.default_rng(4)
    T = V2.assemble({"a": rng.standard_normal((2, 2))})
    assert max(abs(h.value(T.T @ T)) for h in hom) <= 1e-15
    T[0, 1] = 0.3  # h block no longer I: an off-diagonal constraint is violated
    assert max(abs(h.value(T.T @ T)) for h in hom) >= 0.29


def test_position_to_ij_inverts_the_svec_order():
    from autotight.svec import position_to_ij, triu_indices

    i, j = triu_indices(400)  # svec order: position p is (i[p], j[p])
    gi, gj = position_to_ij(np.arange(i.size))
    assert np.array_equal(gi, i) and np.array_equal(gj, j)
