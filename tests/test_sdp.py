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
from autotight.errors import AutotightError
from autotight.sdp import (ClarabelOptions, SolverConfig, SolverConfigError, SolverOptions, clarabel_direct, log_svr,
                           rank_d_factor)
from autotight.sdp.registry import BACKENDS
from autotight.sdp.result import SDPResult
from autotight.tightness import judge


def _small_instance(ra, M: int, seed: int, sigma: float = 0.1):
    inst = ra.generate({"M": M, "sigma": sigma}, seed)
    return inst, ra.build(inst)


def _on_cover(Q, cons, cliques, d: int = 1) -> SDPResult:
    """Clarabel's clique path on exactly this cover (the SDP layer would choose its own)."""
    As = [sp.csr_array(c.A) for c in cons]
    return clarabel_direct.solve_cliques(sp.csr_array(Q), As, np.array([c.b for c in cons]), d, cliques, SolverConfig())


def test_dense_cvxpy_and_clique_paths_agree(ra, factor_cliques):
    """Rotation averaging, M = 3 (N = 19): the three backends reach the same optimal cost."""
    inst, model = _small_instance(ra, 3, seed=5)
    cons = model.primary()
    dense = sdp.solve(model.Q, cons)
    clique = sdp.solve(model.Q, cons, cliques=factor_cliques(model), config=SolverConfig(decompose=True))
    scs = sdp.solve(model.Q, cons, config=SolverConfig(backend="cvxpy:SCS"))
    assert clique.solver == "clarabel-cliques" and clique.cliques is not None
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
    clique = _on_cover(model.Q, cons, cl)
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


def test_a_cover_hint_outside_the_pattern_raises(ra):
    """A cover hint that misses cost entries is a programming error: ValueError, not a status."""
    inst, model = _small_instance(ra, 2, seed=0)
    bad = [model.variables.index(("h", "c1", "c2", "c3"))]
    with pytest.raises(ValueError, match="misses .* nonzero entries"):
        sdp.solve(model.Q, model.primary(), cliques=bad, config=SolverConfig(decompose=True))
    with pytest.raises(ValueError, match="outside every clique"):
        _on_cover(model.Q, model.primary(), bad)


def test_bad_shapes_raise_value_error(ra):
    """Shape errors are bugs: they raise, they never become a "Failed" status."""
    inst, model = _small_instance(ra, 2, seed=0)
    N = model.variables.N
    wrong = Constraint(sp.csr_array(([1.0], ([0], [0])), shape=(N + 1, N + 1)), 1.0, name="wrong")
    for backend in ("clarabel", "ipm"):
        with pytest.raises(ValueError, match="wrong"):
            sdp.solve(model.Q, model.primary() + [wrong], config=SolverConfig(backend=backend))
    with pytest.raises(ValueError, match="square"):
        sdp.solve(sp.csr_array(np.ones((3, 4))), [])
    with pytest.raises(ValueError, match="scale"):
        sdp.solve(model.Q, model.primary(), scale=-np.ones(N))


@pytest.mark.parametrize("solver,use_cliques", [("clarabel", False), ("clarabel", True), ("cvxpy:SCS", False)])
def test_contradictory_constraints_return_infeasible_status(ra, factor_cliques, solver, use_cliques):
    """h² = 1 together with h² = 2: no X exists; the solver's status is returned."""
    inst, model = _small_instance(ra, 2, seed=0)
    N = model.variables.N
    E = sp.csr_array(([1.0], ([0], [0])), shape=(N, N))
    cons = model.primary() + [Constraint(E, 2.0, name="h2=2")]
    res = sdp.solve(model.Q, cons, cliques=factor_cliques(model),
                    config=SolverConfig(backend=solver, decompose=use_cliques if solver == "clarabel" else None))
    expected = "clarabel-cliques" if use_cliques else "clarabel-chordal" if solver == "clarabel" else "cvxpy-scs"
    assert res.solver == expected
    assert not res.usable
    assert not res.solved
    assert "infeasible" in res.status.lower(), res.status
    v = judge(res, 1.0)
    assert not v.tight and res.status in v.reason


def test_max_iter_one_returns_status(ra):
    inst, model = _small_instance(ra, 10, seed=0)
    res = sdp.solve(model.Q, model.primary(), config=SolverConfig(max_iter=1))
    assert res.status == "MaxIterations" and res.n_calls == 1  # not a status that is retried
    assert not res.usable
    assert res.iterations == 1
    v = judge(res, 20.0)
    assert not v.tight and "MaxIterations" in v.reason


def test_config_validation_errors():
    """A bad config is an input error (AutotightError), raised when it is built, before any work."""
    import cvxpy as cp

    bad = [dict(backend="gurobi-direct"), dict(backend="cvxpy:NOPE"), dict(backend="ipm:fast"), dict(tol=0.0),
           dict(tol=2.0), dict(max_iter=0), dict(time_limit=-1.0), dict(threads=-1), dict(scale="always"),
           dict(decompose="yes"), dict(clarabel={"chordal": False}), dict(ipm="hkm")]
    if "MOSEK" not in cp.installed_solvers():
        bad.append(dict(backend="cvxpy:MOSEK"))
    for kw in bad:
        with pytest.raises(SolverConfigError) as e:
            SolverConfig(**kw)
        assert isinstance(e.value, AutotightError) and "\n" not in str(e.value), kw
    with pytest.raises(SolverConfigError, match="unknown solver 'gurobi-direct'"):
        SolverConfig(backend="gurobi-direct")
    with pytest.raises(SolverConfigError, match="'NOPE' is not installed"):
        SolverConfig(backend="cvxpy:NOPE")
    with pytest.raises(SolverConfigError, match="tol"):
        SolverConfig(tol=0.0)
    assert SolverOptions is SolverConfig  # the old name keeps working
    assert SolverOptions(tol=1e-8).backend == "auto"  # picked by size
    assert SolverConfig(backend="cvxpy:scs").backend_arg == "scs"


class _Dummy:
    """A backend registered by a test: returns a fixed X = e₀e₀ᵀ, or raises what it is told to."""

    name, decompose_default, cover, fallback = "dummy", False, None, None
    errors: tuple = (ZeroDivisionError,)

    def __init__(self, raise_: BaseException | None = None):
        self.raise_, self.calls = raise_, 0

    def check(self, arg):
        pass

    def solve(self, Q, As, b, d, cliques, config):
        self.calls += 1
        if self.raise_ is not None:
            raise self.raise_
        X = np.zeros(Q.shape)
        X[0, 0] = 1.0
        return SDPResult(status="Solved", solver="dummy", d=d, X=X, y=np.zeros(len(As)),
                         primal_cost=float(Q[0, 0]), dual_cost=float(Q[0, 0]), solve_time_s=0.25, setup_time_s=0.5)

    def retries(self, config, decomposed, N):
        return []


def test_a_registered_backend_is_reachable_by_name(monkeypatch):
    dummy = _Dummy()
    monkeypatch.setitem(BACKENDS, "dummy", dummy)
    Q = sp.csr_array(np.diag([3.0, 1.0]))
    h2 = Constraint(sp.csr_array(([1.0], ([0], [0])), shape=(2, 2)), 1.0, name="h2")
    res = sdp.solve(Q, [h2], config=SolverConfig(backend="dummy"))
    assert dummy.calls == 1 and res.solver == "dummy" and res.status == "Solved"
    assert res.primal_cost == 3.0 and res.n_calls == 1 and res.solve_time_s == 0.25 and res.setup_time_s == 0.5
    assert res.log_svr == np.inf and res.cost_scale == 3.0  # the layer's finishing reads X
    assert sdp.check_solver("dummy") == "dummy"


def test_only_declared_solver_errors_become_statuses(monkeypatch):
    """An exception the backend declares (here ZeroDivisionError) is a "Failed" status; a ValueError
    (a bug) propagates."""
    Q = sp.csr_array(np.eye(2))
    monkeypatch.setitem(BACKENDS, "dummy", _Dummy(ZeroDivisionError("pivot")))
    res = sdp.solve(Q, [], config=SolverConfig(backend="dummy"))
    assert res.status == "Failed: ZeroDivisionError: pivot" and not res.usable and res.n_calls == 1
    monkeypatch.setitem(BACKENDS, "dummy", _Dummy(ValueError("bad shape")))
    with pytest.raises(ValueError, match="bad shape"):
        sdp.solve(Q, [], config=SolverConfig(backend="dummy"))


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


def test_merged_covers_equal_merge_small_at_every_cap():
    """The caps below every union with the parent skip the merging pass and share one list: the same cover."""
    from autotight.sdp.chordal import merge_small, merged_covers

    cl = _chain_cliques(8, 5)  # unions of neighbours: 9 columns
    caps = (0, 6, 8, 9, 14, 40)
    covers = merged_covers(cl, caps)
    for cap in caps:
        want = merge_small(cl, cap)
        assert [c.tolist() for c in covers[cap]] == [c.tolist() for c in want]
    assert covers[0] is covers[6] is covers[8]  # nothing merges below 9
    assert len(covers[9]) < len(cl)


def test_entry_cliques_are_the_maximal_cliques_of_a_chordal_extension():
    """On random graphs: every edge lies in a clique, no clique lies inside another, the cliques form a clique
    tree, and they equal the pairwise ``maximal`` of all elimination cliques (the linear test agrees)."""
    from autotight.sdp.chordal import clique_tree, entry_cliques, maximal

    rng = np.random.default_rng(7)
    for trial in range(60):
        N = int(rng.integers(3, 30))
        r, c = rng.integers(1, N, 2 * N), rng.integers(1, N, 2 * N)
        cl = entry_cliques(N, r, c)
        sets = [set(k.tolist()) for k in cl]
        assert all(any({a, b} <= s for s in sets) for a, b in zip(r.tolist(), c.tolist()))
        assert all(0 in s for s in sets)  # h is in every clique
        assert not any(a < b for a in sets for b in sets)
        assert [k.tolist() for k in maximal(cl)] == [k.tolist() for k in cl]
        assert _subtree_property(cl, clique_tree(cl))


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
    dense = sdp.solve(sp.csr_array(Q), cons, config=SolverConfig(clarabel=ClarabelOptions(chordal=False)))
    split = _on_cover(Q, cons, cl)
    assert dense.status == "Solved" and split.status == "Solved", (dense.status, split.status)
    assert dense.log_svr < 1  # far from rank 1
    f = dense.primal_cost
    assert abs(split.primal_cost - f) <= 1e-7 * abs(f)
    assert abs(split.dual_cost - f) <= 1e-7 * abs(f)
    for C in cl:  # the same X on every clique block (the completion off the pattern may differ)
        B = np.ix_(C, C)
        assert np.abs(split.X[B] - dense.X[B]).max() <= 1e-4
    assert np.allclose(np.diag(split.X), 1.0, atol=1e-7)


def test_a_stalled_solve_is_retried_and_every_call_is_counted(ra, monkeypatch):
    """A solve that stalls with the small regularisation is solved again with Clarabel's default
    one, then (still stalled, ≤ 100 columns) with clique-graph merging; the first Solved result is
    kept.  n_calls counts the three calls, solve_time_s and setup_time_s sum all three, and the
    message lists each attempt."""
    inst, model = _small_instance(ra, 4, seed=0)
    real = clarabel_direct.solve_dense
    calls, times = [], []

    def stalling(Q, As, b, d, opts):
        calls.append((opts.clarabel.regularization, opts.clarabel.merge))
        res = real(Q, As, b, d, opts)
        if len(calls) < 3:
            res.status, res.X = "InsufficientProgress", None
        times.append((res.solve_time_s, res.setup_time_s))
        return res

    monkeypatch.setattr(clarabel_direct, "solve_dense", stalling)
    res = sdp.solve(model.Q, model.primary())
    assert calls == [("small", "parent_child"), ("default", "parent_child"), ("small", "clique_graph")]
    assert res.status == "Solved" and res.usable
    assert res.n_calls == 3
    assert res.solve_time_s == pytest.approx(sum(t for t, _ in times), rel=1e-12)
    assert res.setup_time_s == pytest.approx(sum(t for _, t in times), rel=1e-12)
    parts = res.message.split("; ")
    assert parts[0] == f"1. clarabel-chordal InsufficientProgress ({times[0][0]:.2f} s)", res.message
    assert f"Solved ({times[2][0]:.2f} s)" in parts[2]  # each attempt's own time
    assert parts[1].startswith("2. retried with default regularisation: clarabel-chordal InsufficientProgress")
    assert parts[2].startswith("3. retried with clique_graph merge: clarabel-chordal Solved")
    local = ra.local_solve(inst, inst.truth)
    assert abs(res.primal_cost - local.cost) <= 1e-6 * local.cost


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


# ----------------------------------------------------------------------------- scaling X = D X' D


def test_block_scale_is_the_rms_per_block_with_a_floor():
    from autotight.model import Variables
    from autotight.sdp.scaling import block_scale

    V = Variables([("a", 2), ("b", 3), ("z", 1)])  # h: 0, a: 1–2, b: 3–5, z: 6
    t1 = np.array([1.0, 3.0, -4.0, 1e-3, -1e-3, 1e-3, 0.0])
    t2 = np.array([1.0, 0.0, 5.0, 2e-3, 2e-3, -2e-3, 0.0])
    D = block_scale(V, [t1, t2[None, :]], floor_rel=1e-4)
    rms_a = np.sqrt((9 + 16 + 0 + 25) / 4)
    rms_b = np.sqrt((3 * 1e-6 + 3 * 4e-6) / 6)
    np.testing.assert_allclose(D, [1.0, rms_a, rms_a, rms_b, rms_b, rms_b, 1e-4 * rms_a], rtol=1e-12)
    with pytest.raises(ValueError, match="shape"):
        block_scale(V, [np.ones(5)])
    with pytest.raises(ValueError, match="at least one"):
        block_scale(V, [])


def test_scaling_reaches_the_local_optimum_at_low_noise():
    """Pose averaging, M = 10, σ = 0.001, seed 2, paper set: the residual blocks are ~1e-3 of the
    rotation blocks.  With D from the lifted local solution the SDP's primal cost comes within 1e-6
    (relative) of the local optimum U (measured: 4e-10 after the default-regularisation retry;
    unscaled, Clarabel stops 2.5e-5 above U)."""
    from autotight.problem import load
    from autotight.sdp.scaling import block_scale

    prob = load("pose_averaging")
    inst = prob.generate({"M": 10, "sigma": 0.001}, 2)
    model = prob.build(inst)
    cons = model.primary() + model.paper_constraints()
    loc = prob.local_solve(inst, inst.truth)
    D = block_scale(model.variables, [prob.lift(inst, loc.state)])
    assert D.min() < 0.02 < 0.5 < D.max()  # the scaling is far from the identity here
    res = sdp.solve_model(model, cons, scale=D)
    assert res.usable, res.message
    assert abs(res.primal_cost - loc.cost) <= 1e-6 * abs(loc.cost), (res.primal_cost, loc.cost, res.message)
    assert abs(res.dual_cost - loc.cost) <= 1e-6 * abs(loc.cost)
    assert res.log_svr > 5  # read from the unscaled X
    est = prob.recover(inst, res.Theta)
    assert abs(prob.cost(inst, est) - loc.cost) <= 1e-6 * loc.cost


def test_scaled_and_unscaled_solves_agree_on_a_well_conditioned_instance():
    """A MaxCut SDP (min ⟨Q,X⟩, X_ii = 1, N = 6) whose optimum is rank 1 with a strictly
    complementary dual, so an interior-point X converges at the rate of the gap (on the degenerate
    optima of tight relaxations X is only accurate to ~√tol, 1e-6 here, scaled or not).  With a
    random D in [0.5, 2]: the same cost and X to 1e-7, the same y (to 1e-5); with scale="none" the vector is
    ignored (bit-identical result)."""
    N = 6
    B = np.random.default_rng(1).standard_normal((N, N))
    Q = sp.csr_array(B + B.T)
    cons = [Constraint(sp.csr_array(([1.0], ([i], [i])), shape=(N, N)), 1.0, name=f"X{i}{i}=1") for i in range(N)]
    D = np.random.default_rng(9).uniform(0.5, 2.0, N)
    plain = sdp.solve(Q, cons)
    scaled = sdp.solve(Q, cons, scale=D)
    assert plain.status == "Solved" and scaled.status == "Solved", (plain.message, scaled.message)
    assert plain.log_svr > 5 and scaled.log_svr > 5  # rank 1, read from the unscaled X
    f = abs(plain.primal_cost)
    assert abs(scaled.primal_cost - plain.primal_cost) <= 1e-7 * f
    assert abs(scaled.dual_cost - plain.dual_cost) <= 1e-7 * f
    assert np.abs(scaled.X - plain.X).max() <= 1e-7 * np.abs(plain.X).max()
    # y is not rescaled (a rescaled y would differ by factors D_i² in [0.25, 4]); the multipliers
    # are fixed less sharply than X here, to ~1e-6 relative
    assert np.abs(scaled.y - plain.y).max() <= 1e-5 * np.abs(plain.y).max()
    ignored = sdp.solve(Q, cons, scale=D, config=SolverConfig(scale="none"))
    assert np.array_equal(ignored.X, plain.X)


def test_effective_tolerance_is_the_backends_floor_when_higher():
    """The pipeline retries an undecided verdict at tol / 100 only when that changes what the backend
    solves to: Clarabel goes down to 1e-13, our IPM stops at its floor IPM_MIN_TOL (1e-7)."""
    from autotight.sdp.schur_ipm import IPM_MIN_TOL

    assert sdp.effective_tol(SolverConfig(tol=1e-8)) == 1e-8
    assert sdp.effective_tol(SolverConfig(backend="ipm", tol=1e-8)) == IPM_MIN_TOL == 1e-7
    assert sdp.effective_tol(SolverConfig(backend="ipm", tol=1e-5)) == 1e-5


def test_home_cliques_is_the_clique_holding_most_columns_lowest_on_ties():
    """``chordal.home_cliques`` against the direct count |C_k ∩ S_j| per clique and constraint, on random
    covers with a hub of columns in all but one clique (the product is then nearly dense) and many ties."""
    from autotight.sdp.chordal import home_cliques, support_matrix

    for seed in range(20):
        rng = np.random.default_rng(seed)
        N, p, m = 30, 12, 40
        hub = [1, 2, 3]
        cliques = [np.unique(np.r_[0, hub if k else [], rng.choice(np.arange(4, N), 5, replace=False)]).astype(np.int64)
                   for k in range(p)]
        cols = [rng.choice(N, rng.integers(1, 6), replace=False) for _ in range(m)]
        rows = np.concatenate(cols)
        owner = np.repeat(np.arange(m), [c.size for c in cols])
        support = support_matrix(rows, rows, owner, N, m)
        count = np.array([[np.intersect1d(c, s).size for s in cols] for c in cliques])  # (p, m)
        want = np.argmax(count, axis=0)  # the first maximum: the lowest clique index
        assert np.array_equal(home_cliques(cliques, support), want)



@pytest.mark.parametrize("counts_max", [None, 0])
def test_home_cliques_with_several_hub_patterns_equals_the_direct_count(counts_max, monkeypatch):
    """Hub columns each in a different half or more of the cliques (several hub patterns, as a block cover of
    pose averaging has), constraints mostly on hub columns (so that a pattern's lowest clique often holds other
    columns of the constraint too), ties everywhere: the direct count's first maximum; also with no room for the
    hub counts (every column through the sparse product)."""
    from autotight.sdp import chordal
    from autotight.sdp.chordal import home_cliques, support_matrix

    if counts_max is not None:
        monkeypatch.setattr(chordal, "HUB_COUNTS_MAX", counts_max)

    for seed in range(40):
        rng = np.random.default_rng(seed)
        N, p, m = 24, int(rng.integers(2, 14)), 60
        hub = np.arange(1, 7)
        cliques = []
        for k in range(p):
            held = hub[rng.random(hub.size) < 0.7]
            cliques.append(np.unique(np.r_[0, held, rng.choice(np.arange(7, N), 3, replace=False)]).astype(np.int64))
        cols = [np.unique(np.r_[rng.choice(hub, rng.integers(0, 4), replace=False),
                                rng.choice(np.arange(N), rng.integers(0, 3), replace=False)]).astype(np.int64)
                for _ in range(m)]
        cols = [c if c.size else np.array([0]) for c in cols]
        rows = np.concatenate(cols)
        owner = np.repeat(np.arange(m), [c.size for c in cols])
        support = support_matrix(rows, rows, owner, N, m)
        count = np.array([[np.intersect1d(c, s).size for s in cols] for c in cliques])
        assert np.array_equal(home_cliques(cliques, support), np.argmax(count, axis=0)), seed
