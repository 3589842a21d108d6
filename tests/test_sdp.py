"""The Shor SDP backends: dense dual form, clique form, cvxpy; statuses; log SVR and rank-d factors.

Tolerances:
- dense vs clique Clarabel (both interior point at tol 1e-9): costs equal to 1e-6 relative;
- vs cvxpy:SCS (first-order, eps 1e-7 in the path): costs equal to 1e-3 relative.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import sdp
from autotight.model import Constraint
from autotight.sdp import SolverOptions, log_svr, rank_d_factor
from autotight.tightness import judge


def _small_instance(ra, M: int, seed: int, sigma: float = 0.1):
    inst = ra.generate({"M": M, "sigma": sigma}, seed)
    return inst, ra.build(inst)


def test_dense_cvxpy_and_clique_paths_agree(ra, factor_cliques):
    """Rotation averaging, M = 3 (N = 19): the three backends reach the same optimal cost."""
    inst, model = _small_instance(ra, 3, seed=5)
    cons = model.primary()
    dense = sdp.solve(model.Q, cons)
    clique = sdp.solve(model.Q, cons, cliques=factor_cliques(model))
    scs = sdp.solve(model.Q, cons, solver="cvxpy:SCS")
    assert dense.status == "Solved"
    assert clique.usable and scs.usable, (clique.status, scs.status)
    f = dense.primal_cost
    assert f > 0
    assert abs(dense.dual_cost - f) <= 1e-6 * f  # strong duality at the solver's accuracy
    assert abs(clique.primal_cost - f) <= 1e-6 * f
    assert abs(scs.primal_cost - f) <= 1e-3 * f
    # the multipliers of the dense dual form certify the cost: bᵀy = ⟨Q, X⟩
    b = np.array([c.b for c in cons])
    assert abs(b @ dense.y - f) <= 1e-6 * f
    # the SDP is a relaxation: its cost is not above the local solution's
    local = ra.local_solve(inst, inst.truth)
    assert f <= local.cost * (1 + 1e-6)


def test_clique_path_equals_dense_on_rotation_averaging(ra, factor_cliques):
    """Cliques = factor blocks {h, c1, c2, c3, φ_m}: same cost, same X, both rank 1."""
    inst, model = _small_instance(ra, 10, seed=1)
    cl = factor_cliques(model)
    assert len(cl) == 10 and all(len(c) == 13 for c in cl)
    assert all(np.array_equal(c[:10], np.arange(10)) for c in cl)  # h, c1, c2, c3 in every clique
    cons = model.primary()
    dense = sdp.solve(model.Q, cons)
    clique = sdp.solve(model.Q, cons, cliques=cl)
    assert dense.status == "Solved"
    assert clique.usable, clique.status
    f = dense.primal_cost
    assert abs(clique.primal_cost - f) <= 1e-6 * f
    assert abs(clique.dual_cost - f) <= 1e-6 * f
    assert dense.log_svr > 5 and clique.log_svr > 5
    assert len(clique.clique_log_svr) == 10 and min(clique.clique_log_svr) > 5
    # X agrees on every entry (on the pattern from the solve, off it from the rank-1 completion).
    # 1e-4 relative (‖X‖_F ≈ 4 here): the clique solve stalls a little short of the dense
    # path's accuracy (AlmostSolved on some seeds, X within ~3e-5 of the optimum).
    assert np.linalg.norm(clique.X - dense.X) <= 1e-4 * np.linalg.norm(dense.X)
    # every constraint holds on the clique path's X (its entries off the pattern are never used)
    N = model.variables.N
    for c in cons:
        assert abs(c.value(clique.X)) <= 1e-6 * (1 + np.abs(c.A).sum()), c.name
    assert clique.X.shape == (N, N)
    # both recover the same rotation, to the accuracy of X above (1e-4 · ‖X‖_F ≈ 4e-4)
    C_d = ra.recover(inst, dense.Theta)["C"]
    C_c = ra.recover(inst, clique.Theta)["C"]
    assert np.linalg.norm(C_d - C_c) <= 4e-4
    # the dense path's rotation equals the local optimum's to far better accuracy
    C_loc = ra.local_solve(inst, inst.truth).state["C"]
    assert np.linalg.norm(C_d - C_loc) <= 1e-5


def test_clique_outside_pattern_is_a_status_not_an_exception(ra):
    """Cliques that miss a cost entry: the solve returns a 'Failed' status."""
    inst, model = _small_instance(ra, 2, seed=0)
    bad = [model.variables.index(("h", "c1", "c2", "c3"))]
    res = sdp.solve(model.Q, model.primary(), cliques=bad)
    assert res.status.startswith("Failed")
    assert not res.usable
    assert np.isnan(res.primal_cost)


@pytest.mark.parametrize("solver,use_cliques", [("clarabel", False), ("clarabel", True), ("cvxpy:SCS", False)])
def test_contradictory_constraints_return_infeasible_status(ra, factor_cliques, solver, use_cliques):
    """h² = 1 together with h² = 2: no X exists; the solver's status is returned."""
    inst, model = _small_instance(ra, 2, seed=0)
    N = model.variables.N
    E = sp.csr_array(([1.0], ([0], [0])), shape=(N, N))
    cons = model.primary() + [Constraint(E, 2.0, name="h2=2")]
    res = sdp.solve(model.Q, cons, solver=solver, cliques=factor_cliques(model) if use_cliques else None)
    assert not res.usable
    assert not res.solved
    assert "infeasible" in res.status.lower(), res.status
    v = judge(res, 1.0)
    assert not v.tight and res.status in v.reason


def test_max_iter_one_returns_status(ra):
    inst, model = _small_instance(ra, 10, seed=0)
    res = sdp.solve(model.Q, model.primary(), options=SolverOptions(max_iter=1))
    assert res.status == "MaxIterations"
    assert not res.usable
    assert res.iterations == 1
    v = judge(res, 20.0)
    assert not v.tight and "MaxIterations" in v.reason


def test_unknown_solver_is_an_error():
    with pytest.raises(ValueError, match="unknown solver"):
        sdp.solve(sp.eye_array(2, format="csr"), [], solver="gurobi-direct")


# ----------------------------------------------------------------------------- log SVR, rank-d factor


def test_log_svr_known_spectra():
    assert log_svr(np.array([4.0, 1e-3, 1e-4])) == pytest.approx(np.log10(4e3), rel=1e-12)
    assert log_svr(np.array([4.0, 0.0, 0.0])) == np.inf
    assert log_svr(np.array([4.0, -1e-12])) == np.inf  # tiny negative eigenvalues count as zero
    assert log_svr(np.array([3.0, 2.0, 1e-6]), d=2) == pytest.approx(np.log10(2e6), rel=1e-12)
    assert log_svr(np.array([3.0, 3.0, 1.0]), d=1) == pytest.approx(0.0, abs=1e-15)


def test_rank1_factor_recovers_x_with_positive_h():
    rng = np.random.default_rng(41)
    x = rng.standard_normal(8)
    x[0] = 1.0
    X = np.outer(x, x)
    w, T = rank_d_factor(X, 1)
    assert T.shape == (1, 8)
    np.testing.assert_allclose(T[0], x, rtol=0, atol=1e-12 * np.linalg.norm(x))
    assert w[0] == pytest.approx(x @ x, rel=1e-12)
    assert abs(w[1]) <= 1e-12 * w[0]
    # a known second eigenvalue: add ε u uᵀ with u ⟂ x
    u = rng.standard_normal(8)
    u -= (u @ x) / (x @ x) * x
    u /= np.linalg.norm(u)
    eps = 1e-6
    w2, T2 = rank_d_factor(X + eps * np.outer(u, u), 1)
    assert log_svr(w2) == pytest.approx(np.log10((x @ x) / eps), rel=1e-6)
    np.testing.assert_allclose(T2[0], x, atol=1e-9)


@pytest.mark.parametrize("d", [2, 3])
def test_rank_d_factor_with_identity_h_block(d):
    """X = ΘᵀΘ with Θ_h = I_d: the factor is Θ itself (h block exactly I), log SVR large."""
    rng = np.random.default_rng(50 + d)
    N = 9
    Theta = rng.standard_normal((d, N))
    Theta[:, :d] = np.eye(d)
    X = Theta.T @ Theta
    w, T = rank_d_factor(X, d)
    np.testing.assert_allclose(T, Theta, rtol=0, atol=1e-10)
    assert np.sum(w > 1e-10 * w[0]) == d
    assert log_svr(w, d) > 10
    # a rank-(d+1) X: the SVR at d is finite and equals the known eigenvalue ratio
    v = rng.standard_normal(N)
    v -= Theta.T @ np.linalg.lstsq(Theta.T, v, rcond=None)[0]  # v ⟂ rows of Θ
    v /= np.linalg.norm(v)
    Xp = X + 1e-3 * np.outer(v, v)
    wp, _ = rank_d_factor(Xp, d)
    lam_d = np.sort(np.linalg.eigvalsh(X))[::-1][d - 1]
    assert log_svr(wp, d) == pytest.approx(np.log10(lam_d / 1e-3), rel=1e-8)


# ----------------------------------------------------------------------------- clique trees and merging


def _chain_cliques(n_links: int, width: int) -> list[np.ndarray]:
    """h = column 0 plus a chain of overlapping windows of ``width`` columns, overlap 2."""
    step = width - 2
    return [np.r_[0, 1 + step * k + np.arange(width)] for k in range(n_links)]


def _subtree_property(cliques, parent) -> bool:
    """For every column, the cliques holding it are connected in the tree (one of them has no
    parent holding the column)."""
    cols = np.unique(np.concatenate(cliques))
    for v in cols:
        holders = [k for k, C in enumerate(cliques) if v in C]
        tops = [k for k in holders if parent[k] < 0 or v not in cliques[parent[k]]]
        if len(tops) != 1:
            return False
    return True


def test_clique_tree_has_the_subtree_property():
    from autotight.sdp.chordal import clique_tree

    cl = _chain_cliques(6, 5)
    rng = np.random.default_rng(3)
    cl = [cl[i] for i in rng.permutation(len(cl))]
    parent = clique_tree(cl)
    assert (parent < 0).sum() == 1
    assert _subtree_property(cl, parent)


def test_merge_small_respects_the_cap_and_keeps_a_clique_tree():
    from autotight.sdp.chordal import clique_tree, has_running_intersection, merge_small

    cl = _chain_cliques(8, 5)  # 8 cliques of 6 columns, neighbours share h and 2 columns
    merged = merge_small(cl, 10)
    assert all(len(c) <= 10 for c in merged)
    assert len(merged) < len(cl)
    assert has_running_intersection(merged)
    assert _subtree_property(merged, clique_tree(merged))
    # every original clique lies inside a merged one (nothing is lost)
    assert all(any(set(c) <= set(m) for m in merged) for c in cl)
    assert len(merge_small(cl, 6)) == len(cl)  # no union fits: unchanged


def test_decomposed_dual_equals_dense_on_a_relaxation_that_is_not_rank_one():
    """A MaxCut-type SDP (min ⟨Q,X⟩, X_ii = 1) on a chain of overlapping cliques with random Q: its
    optimum is far from rank 1, so the clique blocks must agree on their overlaps through the
    transfer variables for the decomposed dual to reach the dense optimum (to 1e-7 relative)."""
    rng = np.random.default_rng(0)
    cl = _chain_cliques(14, 4)
    N = int(max(c.max() for c in cl)) + 1
    Q = np.zeros((N, N))
    for C in cl:
        B = rng.standard_normal((len(C), len(C)))
        Q[np.ix_(C, C)] += B + B.T
    cons = [Constraint(sp.csr_array(([1.0], ([i], [i])), shape=(N, N)), 1.0, name=f"X{i}{i}=1") for i in range(N)]
    dense = sdp.solve(sp.csr_array(Q), cons, options=SolverOptions(clarabel_chordal=False))
    split = sdp.solve(sp.csr_array(Q), cons, cliques=cl)
    assert dense.status == "Solved" and split.status == "Solved", (dense.status, split.status)
    assert dense.log_svr < 1  # far from rank 1
    f = dense.primal_cost
    assert abs(split.primal_cost - f) <= 1e-7 * abs(f)
    assert abs(split.dual_cost - f) <= 1e-7 * abs(f)
    for C in cl:  # the same X on every clique block (the completion off the pattern may differ)
        B = np.ix_(C, C)
        assert np.abs(split.X[B] - dense.X[B]).max() <= 1e-4
    assert np.allclose(np.diag(split.X), 1.0, atol=1e-7)


def test_a_stalled_solve_is_retried_with_default_regularisation(ra, monkeypatch):
    """A solve that stalls with the small regularisation is re-solved with Clarabel's default one;
    the result is the retry's, and the message records both statuses."""
    import autotight.sdp as sdp_pkg

    inst, model = _small_instance(ra, 4, seed=0)
    real = sdp_pkg.solve_dense
    calls = []

    def stalling(Q, As, b, d, opts):
        calls.append(opts.regularization)
        res = real(Q, As, b, d, opts)
        if opts.regularization == "small":
            res.status, res.X = "InsufficientProgress", None
        return res

    monkeypatch.setattr(sdp_pkg, "solve_dense", stalling)
    res = sdp.solve(model.Q, model.primary())
    assert calls[:2] == ["small", "default"]
    assert res.status == "Solved" and res.usable
    assert "InsufficientProgress; retried with default regularisation: Solved" in res.message
    local = ra.local_solve(inst, inst.truth)
    assert abs(res.primal_cost - local.cost) <= 1e-6 * local.cost  # tight, at the default's accuracy


def test_top_only_factor_matches_the_full_eigendecomposition():
    """rank_d_factor(top_only=True) (Lanczos, used for large decomposed solves) returns the d + 1
    largest eigenvalues and the same rank-d factor as the full eigendecomposition."""
    rng = np.random.default_rng(7)
    N, d = 300, 2
    B = rng.standard_normal((N, 6))
    X = B @ np.diag([50.0, 20.0, 1.0, 0.5, 0.1, 0.01]) @ B.T
    w, T = rank_d_factor(X, d)
    wt, Tt = rank_d_factor(X, d, top_only=True)
    assert wt.size == d + 1
    np.testing.assert_allclose(wt, w[:d + 1], rtol=1e-9)
    np.testing.assert_allclose(Tt, T, rtol=0, atol=1e-8 * np.abs(T).max())


def test_top_only_factor_falls_back_when_lanczos_does_not_converge(monkeypatch):
    """If ARPACK does not converge, the factor comes from the full eigendecomposition."""
    import scipy.sparse.linalg as spla

    def no_convergence(*a, **k):
        raise spla.ArpackNoConvergence("no convergence", np.zeros(0), np.zeros((0, 0)))

    monkeypatch.setattr(spla, "eigsh", no_convergence)
    rng = np.random.default_rng(8)
    B = rng.standard_normal((40, 3))
    X = B @ B.T
    w, T = rank_d_factor(X, 1, top_only=True)
    np.testing.assert_allclose(w, np.sort(np.linalg.eigvalsh(X))[::-1], rtol=1e-9, atol=1e-9 * w[0])


def test_block_cliques_expand_block_cliques_to_columns():
    """Blocks h (1), a (2), b (3), c (2); the matrices couple a–b and b–c only: the block graph is a
    path, its cliques {h, a, b} and {h, b, c}, expanded to their columns."""
    from autotight.sdp.chordal import block_cliques, nonzeros

    N = 8  # h: 0, a: 1–2, b: 3–5, c: 6–7
    A = sp.csr_array(([1.0, 1.0], ([2, 4], [4, 2])), shape=(N, N))
    B = sp.csr_array(([1.0, 1.0], ([5, 7], [7, 5])), shape=(N, N))
    got = sorted(c.tolist() for c in block_cliques([1, 2, 3, 2], *nonzeros([A, B])[1:]))
    assert got == [[0, 1, 2, 3, 4, 5], [0, 3, 4, 5, 6, 7]]
