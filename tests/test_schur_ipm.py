"""Our Schur-complement interior-point method (``sdp.schur_ipm``) on clique blocks.

Tolerances: the IPM stops at relative gap and infeasibilities ≤ 1e-7 (``IPM_MIN_TOL``), so its
costs are compared with Clarabel's (tol 1e-9) to 1e-6 relative; exact identities (svec ↔ vec, the
Schur complement's definition) to 1e-12.  The IPM → Clarabel fallback is forced explicitly (a
stubbed IPM result, or an iteration limit), never left to a numerical accident.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import sdp
from autotight.model import Constraint
from autotight.problem import load
from autotight.sdp import ClarabelOptions, IpmOptions, SolverConfig, clarabel_direct, schur_ipm, solve_model
from autotight.sdp.clique_program import clique_program
from autotight.sdp.covers import CliqueCovers
from autotight.sdp.registry import BACKENDS
from autotight.sdp.result import SDPResult
from autotight.svec import svec
from autotight.tightness import judge, relative_gap


IPM = SolverConfig(backend="ipm")


def _data(Q, cons):
    return sp.csr_array(Q), [sp.csr_array(c.A) for c in cons], np.array([c.b for c in cons])


def _covers(model, cons) -> CliqueCovers:
    V = model.variables
    return CliqueCovers(sp.csr_array(model.Q), [c.A for c in cons], model.d, [V.sizes[n] for n in V.names],
                        model.clique_indices() if model.cliques else None)


def _random_symmetric(rng: np.random.Generator, n: int) -> np.ndarray:
    B = rng.standard_normal((n, n))
    return B + B.T


def test_svec_to_vec_maps_svec_to_row_major_vec_and_back():
    rng = np.random.default_rng(0)
    mats = [_random_symmetric(rng, n) for n in (1, 3, 5)]
    P = schur_ipm.svec_to_vec([1, 3, 5])
    s = np.concatenate([svec(M) for M in mats])
    v = np.concatenate([M.ravel() for M in mats])
    assert np.abs(P @ s - v).max() <= 1e-12
    assert np.abs(P.T @ v - s).max() <= 1e-12


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("search", ["hkm", "nt"])
def test_schur_complement_equals_its_definition(search, compiled):
    """S_il = Σ_k ⟨A_ik, P_k A_lk Q_k⟩ on random blocks and random sparse constraints, for HKM
    (P, Q) = (X, Z⁻¹) and for NT P = Q = W (the same list, which ``assemble`` folds as one kernel), by the
    numpy loop and by the compiled kernel (``schur_kernel``)."""
    rng = np.random.default_rng(1)
    sizes = [3, 4, 3]
    R = sum(n * (n + 1) // 2 for n in sizes)
    F = sp.random_array((R, 7), density=0.3, rng=rng, format="csc")
    P = schur_ipm.svec_to_vec(sizes)
    Gv = sp.csr_array(P @ F)
    blocks = schur_ipm._Blocks(sizes)
    schur = schur_ipm._Schur(Gv, blocks, compiled=compiled)
    assert (schur.compiled is not None) == compiled

    def spd(n: int) -> np.ndarray:
        B = rng.standard_normal((n, n))
        return B @ B.T + n * np.eye(n)

    Xk = [spd(n) for n in sizes]
    Zk = [spd(n) for n in sizes]
    by_group = lambda mats: [np.stack([mats[k] for k in ids]) for _, ids, _ in blocks.groups]  # noqa: E731
    left = by_group(Xk)
    right = by_group([np.linalg.inv(Z) for Z in Zk]) if search == "hkm" else left
    vals = schur.assemble(left, right)
    S = sp.csr_array((vals, schur.cols, schur.indptr), shape=(7, 7)).toarray()
    expect = np.zeros((7, 7))
    for k, n in enumerate(sizes):
        A = [Gv[blocks.voff[k]:blocks.voff[k + 1]][:, [i]].toarray().reshape(n, n) for i in range(7)]
        Zi = np.linalg.inv(Zk[k]) if search == "hkm" else Xk[k]
        expect += np.array([[np.sum(A[i] * (Xk[k] @ A[j] @ Zi)) for j in range(7)] for i in range(7)])
    assert np.abs(S - expect).max() <= 1e-12 * np.abs(expect).max()


def _chain_maxcut(rng: np.random.Generator, cliques: int, width: int):
    cl = [np.r_[0, 1 + (width // 2) * k + np.arange(width)] for k in range(cliques)]
    N = int(max(c.max() for c in cl)) + 1
    Q = np.zeros((N, N))
    for C in cl:
        Q[np.ix_(C, C)] += _random_symmetric(rng, len(C))
    cons = [Constraint(sp.csr_array(([1.0], ([i], [i])), shape=(N, N)), 1.0, name=f"X{i}{i}=1") for i in range(N)]
    return sp.csr_array(Q), cons, cl


def test_the_block_program_holds_the_dense_data_exactly():
    """Blocks z that agree with one X on every clique: Fᵀz gives ⟨Aᵢ, X⟩ for the constraints (each spread over
    several cliques, so entries are placed in their home block or the entry's top block) and 0 for the
    transfers, and cᵀz = scale·⟨Q, X⟩."""
    from autotight.svec import svec

    rng = np.random.default_rng(4)
    Q, _, cl = _chain_maxcut(rng, 30, 6)
    N = Q.shape[0]
    As = []
    for _ in range(60):  # four random entries, each inside one of two neighbouring cliques
        k = int(rng.integers(len(cl) - 1))
        ij = np.array([rng.choice(cl[k + int(rng.integers(2))], 2) for _ in range(4)])
        A = sp.csr_array((rng.standard_normal(4), (ij[:, 0], ij[:, 1])), shape=(N, N))
        As.append(sp.csr_array(A + A.T))
    b = rng.standard_normal(len(As))
    prog = clique_program(Q, As, b, cl)
    X = rng.standard_normal((N, N))
    X = X + X.T
    z = np.concatenate([svec(X[np.ix_(C, C)]) for C in prog.cliques])
    lhs = prog.F.T @ z
    expect = np.array([np.sum(A.toarray() * X) for A in As])
    assert np.abs(lhs[:prog.m] - expect).max() <= 1e-12 * max(1.0, np.abs(expect).max())
    assert np.abs(lhs[prog.m:]).max() <= 1e-12 * np.abs(X).max()
    assert abs(prog.c @ z - prog.scale * np.sum(Q.toarray() * X)) <= 1e-12 * abs(prog.scale) * np.abs(X).sum()


def _chain_schur(rng: np.random.Generator, cliques: int, width: int):
    """The MaxCut chain's block program and its Schur-complement structure."""
    Q, cons, cl = _chain_maxcut(rng, cliques, width)
    prog = clique_program(Q, [sp.csr_array(c.A) for c in cons], np.array([c.b for c in cons]), cl)
    blocks = schur_ipm._Blocks(prog.sizes)
    return Q, cons, prog, blocks, schur_ipm._Schur(sp.csr_array(schur_ipm.svec_to_vec(prog.sizes) @ prog.F), blocks)


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("factor,search", [("band", "nt"), ("band-lu", "nt"), ("ldl", "nt"), ("superlu", "nt"),
                                           ("band", "hkm")])
def test_ipm_equals_clarabel_on_a_chain_sdp_far_from_rank_one(factor, search, compiled, monkeypatch):
    """MaxCut-type chain SDP: the optimum is far from rank 1, so the blocks must agree on their
    overlaps.  The same optimum with the banded Cholesky (the chain's default), with banded LU
    (pivoting from the first iteration), with sparse LDLᵀ (qdldl: no band) and with the SuperLU
    fallback (every LDLᵀ reported as not positive definite), and with either search direction; with
    the numpy per-block code and with the compiled kernels (``schur_kernel``, forced on 12 blocks)."""
    monkeypatch.setattr(schur_ipm, "COMPILED_MIN_BLOCKS", 1 if compiled else 10 ** 9)
    if factor in ("ldl", "superlu"):
        monkeypatch.setattr(schur_ipm._BandSchur, "make", classmethod(lambda cls, Gv, blocks: None))
    if factor == "superlu":
        monkeypatch.setattr(schur_ipm._LDLPattern, "factor", lambda self, vals: None)
    if factor == "band-lu":
        band_factor = schur_ipm._BandSchur.factor

        def pivoting(self, ab, reg, par=None):
            self.pivoting = True
            return band_factor(self, ab, reg, par)

        monkeypatch.setattr(schur_ipm._BandSchur, "factor", pivoting)
    Q, cons, cl = _chain_maxcut(np.random.default_rng(0), 12, 6)
    ref = sdp.solve(Q, cons, config=SolverConfig(clarabel=ClarabelOptions(chordal=False)))
    res = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, SolverConfig(backend="ipm", ipm=IpmOptions(search=search)))
    assert ref.status == "Solved" and res.status == "Solved", (ref.summary(), res.summary(), res.message)
    assert res.solver == "autotight-ipm"
    assert ref.log_svr < 1
    f = ref.primal_cost
    assert abs(res.primal_cost - f) <= 1e-6 * abs(f)
    assert abs(res.dual_cost - f) <= 1e-6 * abs(f)
    assert np.abs(np.diag(res.X) - 1.0).max() <= 1e-6
    for C in cl:  # the same X on every clique block
        B = np.ix_(C, C)
        assert np.abs(res.X[B] - ref.X[B]).max() <= 1e-3


def test_ipm_on_one_dense_block_equals_clarabel(ra):
    """decompose=False: one block of all N columns (rotation averaging, M = 4, rank-1 optimum).  With
    HKM this small degenerate SDP stops AlmostSolved (relative gap 9e-7); NT solves it."""
    inst = ra.generate({"M": 4, "sigma": 0.1}, 3)
    model = ra.build(inst)
    cons = model.primary()
    ref = sdp.solve(model.Q, cons)
    res = sdp.solve(model.Q, cons, config=SolverConfig(backend="ipm", decompose=False))
    assert res.status == "Solved" and res.n_calls == 1, (res.status, res.message)
    assert res.cliques is not None and len(res.cliques) == 1 and len(res.cliques[0]) == model.variables.N
    f = ref.primal_cost
    assert abs(res.primal_cost - f) <= 1e-6 * f
    assert res.log_svr > 5
    local = ra.local_solve(inst, inst.truth)
    assert judge(res, local.cost).tight


def test_contradictory_constraints_are_a_status_not_an_exception(ra):
    """h² = 1 and h² = 2: the IPM has no infeasibility certificate and must not report a solution, with
    either step rule (its retry); ``sdp.solve`` then asks Clarabel, whose certificate gives the status,
    and says so."""
    inst = ra.generate({"M": 2, "sigma": 0.1}, 0)
    model = ra.build(inst)
    N = model.variables.N
    cons = model.primary() + [Constraint(sp.csr_array(([1.0], ([0], [0])), shape=(N, N)), 2.0, name="h2=2")]
    Q = sp.csr_array(model.Q)
    prog = clique_program(Q, [sp.csr_array(c.A) for c in cons], np.array([c.b for c in cons]), [np.arange(N)])
    own = schur_ipm.solve_blocks(prog.F, prog.c, prog.g, prog.sizes)
    assert own.status in ("NumericalError", "InsufficientProgress", "MaxIterations"), own.status
    res = sdp.solve(model.Q, cons, config=SolverConfig(backend="ipm", decompose=False))
    assert not res.usable and "infeasible" in res.status.lower(), res.status
    assert res.n_calls == 3, res.message
    assert res.message.startswith(f"1. autotight-ipm {own.status}"), res.message
    assert "2. retried with the fixed step fraction" in res.message and "3. solved again by clarabel" in res.message
    v = judge(res, 1.0)
    assert not v.tight and res.status in v.reason


def test_above_the_fallback_size_an_unusable_ipm_result_stands_and_says_why(ra, monkeypatch):
    """The contradictory SDP above with ``FALLBACK_MAX_N`` below its size: the IPM's calls only (its own and
    its retry), its status reported as it is, and the message names the fallback that was not tried."""
    inst = ra.generate({"M": 2, "sigma": 0.1}, 0)
    model = ra.build(inst)
    N = model.variables.N
    cons = model.primary() + [Constraint(sp.csr_array(([1.0], ([0], [0])), shape=(N, N)), 2.0, name="h2=2")]
    monkeypatch.setattr(sdp, "FALLBACK_MAX_N", N - 1)
    res = sdp.solve(model.Q, cons, config=SolverConfig(backend="ipm", decompose=False))
    assert not res.usable and res.n_calls == 2 and res.solver == "autotight-ipm", res.message
    assert f"not solved again by clarabel: N = {N} columns > {N - 1}" in res.message


def test_an_unusable_ipm_result_is_solved_again_by_clarabel_and_both_calls_count(ra, monkeypatch):
    """The IPM backend is stubbed to stop short (InsufficientProgress, no X, 1.5 s), its retry too:
    Clarabel's answer is returned, n_calls is 3, the calls' times are summed and the message lists each."""
    inst = ra.generate({"M": 3, "sigma": 0.1}, 0)
    model = ra.build(inst)

    def short(Q, As, b, d, cliques, config):
        return SDPResult(status="InsufficientProgress", solver="autotight-ipm", d=d, X=None, y=None,
                         primal_cost=float("nan"), dual_cost=float("nan"), solve_time_s=1.5, setup_time_s=0.25,
                         message="no progress in 5 iterations")

    monkeypatch.setattr(BACKENDS["ipm"], "solve", short)
    res = sdp.solve(model.Q, model.primary(), config=IPM)
    ref = sdp.solve(model.Q, model.primary())
    assert res.solver.startswith("clarabel") and res.status == "Solved"
    assert res.n_calls == 3
    assert res.solve_time_s == pytest.approx(3.0 + ref.solve_time_s, abs=0.5 * ref.solve_time_s + 0.05)
    assert res.solve_time_s > 3.0 and res.setup_time_s > 0.5
    assert res.message.startswith("1. autotight-ipm InsufficientProgress (1.50 s; no progress in 5 iterations)")
    assert "; 2. retried with the fixed step fraction" in res.message
    assert "; 3. solved again by clarabel: clarabel" in res.message
    assert abs(res.primal_cost - ref.primal_cost) <= 1e-9 * ref.primal_cost


def test_unknown_search_direction_is_an_error():
    with pytest.raises(ValueError, match="search direction"):
        schur_ipm.solve_blocks(sp.csc_matrix((1, 1)), np.zeros(1), np.zeros(1), [1], search="aho")


def test_iteration_limit_is_reported(ra):
    inst = ra.generate({"M": 6, "sigma": 0.1}, 0)
    model = ra.build(inst)
    res = sdp.solve(model.Q, model.primary(), config=SolverConfig(backend="ipm", max_iter=2))
    assert res.status == "MaxIterations" and not res.usable  # the IPM's, then Clarabel's, at 2 iterations
    assert res.n_calls == 2  # MaxIterations is not retried
    assert res.message.startswith("1. autotight-ipm MaxIterations") and "gap" in res.message  # its residuals are kept
    assert "2. solved again by clarabel: clarabel-cliques MaxIterations" in res.message


def test_block_program_has_the_dense_optimum_with_clarabel_too(ra, factor_cliques):
    """clique_program is shared: the Clarabel clique path and the IPM solve the same block program."""
    inst = ra.generate({"M": 5, "sigma": 0.1}, 2)
    model = ra.build(inst)
    Q = sp.csr_array(model.Q)
    cons = model.primary()
    prog = clique_program(Q, [sp.csr_array(c.A) for c in cons], np.array([c.b for c in cons]), factor_cliques(model))
    assert prog.F.shape[1] > len(cons)  # transfers were added for the overlaps
    a = clarabel_direct.solve_cliques(*_data(model.Q, cons), 1, factor_cliques(model), SolverConfig())
    b = schur_ipm.solve_ipm(*_data(model.Q, cons), 1, factor_cliques(model), IPM)
    assert a.usable and b.usable, (a.status, b.status)
    assert abs(a.primal_cost - b.primal_cost) <= 1e-6 * a.primal_cost


@pytest.mark.parametrize("seed", [0, 1])
def test_ipm_regression_discrete_trajectory_k20_is_tight(seed):
    """The paper's constraints at K = 20, σ = 0.1 with our IPM on the clique cover: rank 1 and the
    cost of the local solver started at the ground truth to 1e-6 relative."""
    prob = load("discrete_trajectory")
    inst = prob.generate({"K": 20}, seed)
    model = prob.build(inst)
    res = solve_model(model, model.primary() + model.paper_constraints(), IPM)
    assert res.solver == "autotight-ipm" and res.n_calls == 1
    assert res.usable, (res.summary(), res.message)
    assert res.log_svr > 5
    local = prob.local_solve(inst, inst.truth)
    assert abs(relative_gap(res.primal_cost, local.cost)) < 1e-6


def test_schur_complement_stays_sparse_along_a_chain():
    """S couples only constraints that share a block: doubling the chain doubles nnz(S) (a dense
    or fill-heavy S would quadruple it), and S is never stored densely."""
    nnz, size = [], []
    for cliques in (12, 24):
        schur = _chain_schur(np.random.default_rng(0), cliques, 6)[-1]
        nnz.append(schur.rows.size)
        size.append(schur.M)
    assert 1.8 <= size[1] / size[0] <= 2.2 and 1.8 <= nnz[1] / nnz[0] <= 2.2, (size, nnz)


@pytest.mark.parametrize("compiled", [False, True])
def test_band_schur_equals_the_sparse_schur_complement_and_solves_it(compiled):
    """On a chain, ``_BandSchur`` holds the same S as ``_Schur`` (to rounding) in a band whose width does not
    grow with the chain's length, and both of its factorisations (Cholesky, and LU with pivoting) solve
    S Δy = r to a residual near roundoff; with the numpy code and with the compiled kernels (the band's
    assembly, scaling and full storage)."""
    rng = np.random.default_rng(3)
    widths = []
    for cliques in (12, 24):
        _, _, prog, blocks, schur = _chain_schur(rng, cliques, 6)
        band = schur_ipm._BandSchur.make(sp.csr_array(schur_ipm.svec_to_vec(prog.sizes) @ prog.F), blocks,
                                         compiled=compiled)
        assert band is not None and (band.compiled is not None) == compiled
        widths.append(band.b)
        B = [rng.standard_normal((ids.size, n, n)) for n, ids, _ in blocks.groups]
        W = [b @ np.swapaxes(b, 1, 2) + b.shape[-1] * np.eye(b.shape[-1]) for b in B]  # positive definite
        S = sp.csr_array((schur.assemble(W, W), schur.cols, schur.indptr), shape=(schur.M, schur.M)).toarray()
        ab = band.assemble(W, W)
        Sp = S[np.ix_(band.order, band.order)]  # S in the band's order
        for t in range(band.b + 1):
            assert np.allclose(ab[t, :schur.M - t], np.diagonal(Sp, -t), rtol=0, atol=1e-12 * np.abs(S).max())
        assert np.abs(np.tril(Sp, -band.b - 1)).max() == 0.0  # nothing outside the band
        r = rng.standard_normal(schur.M)
        for pivoting in (False, True):
            band.pivoting = pivoting
            dy = band.factor(ab, schur_ipm.SCHUR_REG)(r)
            assert np.linalg.norm(S @ dy - r) <= 1e-8 * np.linalg.norm(r), pivoting
    assert widths[0] == widths[1]


def _spd_blocks(rng: np.random.Generator, B: int, n: int, floor: float) -> np.ndarray:
    A = rng.standard_normal((B, n, n))
    return A @ np.swapaxes(A, 1, 2) + floor * np.eye(n)


def _brute_step(X: np.ndarray, dX: np.ndarray) -> float:
    """The largest α with X_k + α dX_k ⪰ 0 for every block, from the generalised eigenvalues of (dX_k, X_k)."""
    import scipy.linalg as sla

    lam = min(float(sla.eigh(d, x, eigvals_only=True)[0]) for x, d in zip(X, dX))
    return np.inf if lam >= 0 else -1.0 / lam


@pytest.mark.parametrize("n,B", [(1, 5), (4, 30), (9, 40)])
def test_compiled_step_length_is_the_largest_step_in_the_cone(n, B):
    """``schur_kernel.max_step`` (eigenvalues only where a Cholesky test fails) equals the brute-force step
    from every block's generalised eigenvalues and the numpy ``_max_step``, for directions that leave the
    cone at very different steps per block, for directions inside it (∞), and with a limit below and
    above the step."""
    from autotight.sdp import schur_kernel

    rng = np.random.default_rng(n)
    X = _spd_blocks(rng, B, n, 0.1)
    Linv = [np.linalg.inv(np.linalg.cholesky(X))]
    D = rng.standard_normal((B, n, n))
    dX = (D + np.swapaxes(D, 1, 2)) * rng.uniform(0.01, 10.0, B)[:, None, None]  # leaves the cone at many steps
    psd = _spd_blocks(rng, B, n, 0.0)  # X + α·psd ⪰ 0 for every α ≥ 0
    for direction, expect in [(dX, _brute_step(X, dX)), (psd, np.inf), (-X, 1.0)]:
        assert schur_ipm._max_step(Linv, [direction]) == pytest.approx(expect, rel=1e-9)
        got = schur_kernel.max_step(Linv, [direction])
        assert got == pytest.approx(expect, rel=1e-9)
        assert got == schur_ipm._max_step(Linv, [direction])  # the same eigenvalue computation
        for limit in (0.5 * expect, 2.0 * expect) if np.isfinite(expect) else (3.0,):
            assert schur_kernel.max_step(Linv, [direction], limit) == pytest.approx(min(expect, limit), rel=1e-9)


def test_compiled_kernels_leave_the_iterates_unchanged(monkeypatch):
    """A 60-block chain solved with the compiled kernels (threshold lowered) and with the numpy code
    (threshold raised) takes the same iterations to the same costs, with S as a band and stored whole
    (sparse LDLᵀ), for NT and HKM: the kernels do the same arithmetic (bit for bit here; the tolerance
    leaves room for a BLAS that rounds the numpy path's products differently)."""
    Q, cons, cl = _chain_maxcut(np.random.default_rng(5), 60, 6)
    make = schur_ipm._BandSchur.make
    out = {}
    for band in (True, False):
        monkeypatch.setattr(schur_ipm._BandSchur, "make", make if band else classmethod(lambda cls, Gv, blocks: None))
        for compiled in (True, False):
            monkeypatch.setattr(schur_ipm, "COMPILED_MIN_BLOCKS", 1 if compiled else 10 ** 9)
            for search in ("nt", "hkm"):
                out[band, compiled, search] = schur_ipm.solve_ipm(
                    *_data(Q, cons), 1, cl, SolverConfig(backend="ipm", ipm=IpmOptions(search=search)))
    for band, search in [(True, "nt"), (True, "hkm"), (False, "nt"), (False, "hkm")]:
        a, b = out[band, True, search], out[band, False, search]
        assert a.status == b.status and a.status in ("Solved", "AlmostSolved"), (a.summary(), b.summary())
        assert a.iterations == b.iterations
        assert abs(a.primal_cost - b.primal_cost) <= 1e-9 * abs(b.primal_cost)
        assert abs(a.dual_cost - b.dual_cost) <= 1e-9 * abs(b.dual_cost)


def test_block_incidence_counts_the_constraints_each_block_receives():
    """On a chain whose constraints each fit in one clique, ``chordal.block_incidence`` (home
    constraints plus the transfers to the parent and from the children) counts exactly the rows of
    the Schur complement, and each block is within 3 of its own part."""
    from autotight.sdp.chordal import block_incidence, column_support

    Q, cons, prog, _, schur = _chain_schur(np.random.default_rng(0), 7, 6)
    actual = np.array([G.shape[0] for G in schur.per_block], float)
    inc, M = block_incidence(prog.cliques, column_support([c.A for c in cons], Q.shape[0]))
    est = np.array([i.size for i in inc], float)
    # a diagonal constraint X_ii = 1 on a shared column may be placed in either clique holding it
    assert M == schur.M and est.sum() == actual.sum(), (est, actual)
    assert np.abs(est - actual).max() <= 3, (est, actual)


def test_block_incidence_follows_constraints_that_spill_across_the_tree():
    """Pose averaging (M = 40, with a set learned at M = 5) on its block cover merged to 32 columns, which puts
    ρ_m and φ_m in different cliques, so most constraints reach outside their home clique: the estimated Schur
    complement has the IPM's number of rows and a half bandwidth within 10 % of the one the IPM's own
    structure gives, and the estimated cost ranks the model's own cover, merged to 48 columns (a chain
    of the factors' cliques), below it, as its band is narrower."""
    from autotight.constraint_set import ConstraintSet
    from autotight.sdp.chordal import block_incidence, merged_covers

    prob = load("pose_averaging")
    inst = prob.generate({"M": 40}, 0)
    model = prob.build(inst)
    # the set the scale benchmark applies (learned at M = 5)
    learned = ConstraintSet.load(Path(__file__).parents[1] / "benchmarks" / "results" / "scale_set_pose_M5.json")
    cons = model.primary() + learned.apply(prob, inst, model, np.random.default_rng(0))
    covers = _covers(model, cons)
    block_cover = covers.blocks[32]
    inc, M = block_incidence(block_cover, covers.support)
    prog = clique_program(sp.csr_array(model.Q), [sp.csr_array(c.A) for c in cons],
                          np.array([c.b for c in cons]), block_cover)
    Gv = sp.csr_array(schur_ipm.svec_to_vec(prog.sizes) @ prog.F)
    _, _, actual = schur_ipm.block_data(Gv, schur_ipm._Blocks(prog.sizes))
    assert M == Gv.shape[1]
    b_est, b_actual = schur_ipm.band_order(inc, M)[1], schur_ipm.band_order(actual, M)[1]
    assert abs(b_est - b_actual) <= 0.1 * b_actual, (b_est, b_actual)
    own = merged_covers(model.clique_indices(), (48,))[48]
    inc_own, M_own = block_incidence(own, covers.support)
    assert schur_ipm.band_order(inc_own, M_own)[1] < b_est

    def cost(cover):
        return schur_ipm.iteration_cost([len(c) for c in cover], *block_incidence(cover, covers.support))

    assert cost(own) < cost(block_cover)
    assert cost(covers.choose("ipm")) <= cost(own)


def _holds_every_nonzero(cover: list[np.ndarray], matrices: list) -> bool:
    """Every nonzero (i, j) of every matrix lies in some clique of ``cover``."""
    inc = np.zeros((len(cover), matrices[0].shape[0]), bool)
    for k, c in enumerate(cover):
        inc[k, c] = True
    return all(np.all((inc[:, E.row] & inc[:, E.col]).any(axis=0)) for E in map(sp.coo_array, matrices))


def test_ipm_cover_minimises_the_estimated_iteration_cost():
    """CliqueCovers.choose("ipm") on the discrete trajectory: a clique tree that holds every nonzero
    (i, j) of Q and of the constraints in some clique, whose estimated cost is no larger than that of
    Clarabel's cover or of the model's own cliques (both are among its candidates)."""
    from autotight.sdp.chordal import block_incidence, column_support, has_running_intersection

    prob = load("discrete_trajectory")
    model = prob.build(prob.generate({"K": 12}, 0))
    cons = model.primary() + model.paper_constraints()
    support = column_support([c.A for c in cons], model.variables.N)

    def cost(cl):
        return schur_ipm.iteration_cost([len(c) for c in cl], *block_incidence(cl, support))

    covers = _covers(model, cons)
    chosen = covers.choose("ipm")
    assert has_running_intersection(chosen)
    assert _holds_every_nonzero(chosen, [model.Q] + [c.A for c in cons])
    assert cost(chosen) <= cost(covers.choose("clarabel")) and cost(chosen) <= cost(model.clique_indices())


def test_refinement_is_kept_only_when_it_lowers_the_residual(monkeypatch):
    """A factorisation that returns three times the solution: one refinement step would give
    −3× (residual 4‖r‖); the solve keeps the unrefined 3× (residual 2‖r‖)."""
    _, _, _, blocks, schur = _chain_schur(np.random.default_rng(1), 4, 4)
    vals = schur.assemble(blocks.identity(1.0), blocks.identity(1.0))
    S = sp.csr_array((vals, schur.cols, schur.indptr), shape=(schur.M, schur.M))
    d = vals[schur.diag]
    exact = np.linalg.inv(S.toarray() / np.sqrt(np.outer(d, d)))  # D S D with unit diagonal
    monkeypatch.setattr(schur._ldl, "factor", lambda upper: (lambda r: 3 * exact @ r))
    r = np.random.default_rng(2).standard_normal(schur.M)
    dy = schur.factor(vals, 0.0)(r)
    assert np.linalg.norm(S @ dy - r) == pytest.approx(2 * np.linalg.norm(r), rel=1e-8)


def _continuous_kept(K: int, seed: int):
    prob = load("continuous_trajectory")
    model = prob.build(prob.generate({"K": K, "marginalize": False}, seed))
    return model, model.primary() + model.paper_constraints()


def test_block_cover_keeps_blocks_whole_and_finds_the_small_separators():
    """chordal.block_cliques on continuous time with ϖ kept (K = 7): a clique tree holding every
    nonzero of Q and the constraints, each clique a union of whole variable blocks with h, and
    the IPM's chosen cover (that cover merged) has separators of at most 13 columns
    ({h, ξ_{k+1,k}, ϖ_{k+1}}) where the model's chain has 19 ({h, pose k+1, ϖ_{k+1}}), and is
    estimated cheaper than the model's."""
    from autotight.sdp.chordal import block_incidence, clique_tree, has_running_intersection

    model, cons = _continuous_kept(7, 0)
    V = model.variables
    covers = _covers(model, cons)
    cl = covers.blocks[0]  # unmerged
    assert has_running_intersection(cl) and all(c[0] == 0 for c in cl)
    starts = {V.offsets[n]: V.sizes[n] for n in V.names}
    for c in cl:  # whole blocks: the columns split into runs that start a block and span it
        cols = set(c.tolist())
        assert all(set(range(o, o + size)) <= cols or not (set(range(o, o + size)) & cols)
                   for o, size in starts.items())
    assert _holds_every_nonzero(cl, [model.Q] + [c.A for c in cons])

    def separators(cover):
        parent = clique_tree(cover)
        return [np.intersect1d(cover[k], cover[parent[k]]).size for k in range(len(cover)) if parent[k] >= 0]

    chosen = covers.choose("ipm")  # the block cover with small neighbours merged
    assert max(separators(chosen)) <= 13 < max(separators(model.clique_indices())) == 19

    def cost(cover):
        return schur_ipm.iteration_cost([len(c) for c in cover], *block_incidence(cover, covers.support))

    assert cost(chosen) < cost(model.clique_indices())


def test_ipm_keeps_going_while_the_costs_fall_by_orders_of_magnitude():
    """Continuous time with ϖ kept (K = 9): the optimum is ~3e-4 of max|Q|, so the relative gap
    stays above 1 for the first ~15 iterations while both costs fall by 1e5.  The stall rule counts
    the absolute gap as progress (a rule on the relative gap stopped this solve at iteration 7 with
    gap 1.4): the IPM alone ends usable, at Clarabel's cost to 1e-5."""
    model, cons = _continuous_kept(9, 0)
    res = solve_model(model, cons, IPM)
    assert res.solver == "autotight-ipm" and res.usable, res.message
    assert res.iterations > 15
    ref = solve_model(model, cons)
    assert abs(res.primal_cost - ref.primal_cost) <= 1e-5 * abs(ref.primal_cost), (res.primal_cost, ref.primal_cost)


def test_clarabel_resolves_on_its_own_cover(monkeypatch):
    """When the IPM ends unusable (forced: the IPM backend is stubbed to stall), Clarabel re-solves on
    the cover chosen for Clarabel (smaller cliques), not on the IPM's: discrete trajectory, K = 12."""
    prob = load("discrete_trajectory")
    model = prob.build(prob.generate({"K": 12}, 0))
    cons = model.primary() + model.paper_constraints()
    seen: dict[str, list] = {"ipm": [], "clarabel": []}

    def stalled(Q, As, b, d, cliques, config):
        seen["ipm"].append(cliques)
        return SDPResult(status="InsufficientProgress", solver="autotight-ipm", d=d, X=None, y=None,
                         primal_cost=float("nan"), dual_cost=float("nan"), solve_time_s=0.0)

    real = BACKENDS["clarabel"].solve
    monkeypatch.setattr(BACKENDS["ipm"], "solve", stalled)
    monkeypatch.setattr(BACKENDS["clarabel"], "solve",
                        lambda Q, As, b, d, cliques, config:
                        seen["clarabel"].append(cliques) or real(Q, As, b, d, cliques, config))
    res = solve_model(model, cons, IPM)
    assert res.usable and res.solver == "clarabel-cliques" and res.n_calls == 3, res.message  # IPM, retry, Clarabel
    covers = _covers(model, cons)
    want, ipm = covers.choose("clarabel"), covers.choose("ipm")
    assert [c.tolist() for c in want] != [c.tolist() for c in ipm]
    assert len(seen["ipm"]) == 2 and all([c.tolist() for c in s] == [c.tolist() for c in ipm] for s in seen["ipm"])
    assert len(seen["clarabel"]) == 1 and [c.tolist() for c in seen["clarabel"][0]] == [c.tolist() for c in want]


def test_ipm_residuals_are_entrywise_and_do_not_grow_with_the_number_of_rows():
    """pinf is ‖g − A(X)‖_∞ / (1 + ‖g‖_∞), recomputed here from the returned X (discrete
    trajectory K = 12 and 36, paper set, one block per pose: the column cover merged up to 32
    columns, fixed here because the iteration count moves by a few with the clique tree's root):
    at a fixed accuracy per row it does not grow with the chain's length, so the longer chain
    reaches Solved in a comparable number of iterations (a 2-norm over all rows stalled at K = 300)."""
    prob = load("discrete_trajectory")
    its = []
    for K in (12, 36):
        model = prob.build(prob.generate({"K": K}, 0))
        cons = model.primary() + model.paper_constraints()
        Q, As, b = _data(model.Q, cons)
        prog = clique_program(Q, As, b, _covers(model, cons).columns[32])
        sol = schur_ipm.solve_blocks(prog.F, prog.c, prog.g, prog.sizes)
        assert sol.status in ("Solved", "AlmostSolved"), sol.message  # the residuals below are the property
        rp = prog.g - prog.F.T @ sol.z
        pinf = np.max(np.abs(rp)) / (1 + np.max(np.abs(prog.g)))
        # the same measure up to the rounding of A(X) in two evaluation orders (a 2-norm would differ by ~√rows)
        assert pinf == pytest.approx(sol.pinf, rel=1e-3, abs=1e-15)
        assert sol.pinf <= 1e-7 and np.linalg.norm(rp) / (1 + np.linalg.norm(prog.g)) > sol.pinf
        its.append(sol.iterations)
    assert its[1] <= its[0] + 4, its


def test_stall_clock_ignores_jitter_at_a_floor_and_measures_already_within_tol():
    """The residuals of discrete trajectory K = 300 (paper set) from iteration 28 on: the best max
    residual creeps down by < 10 % and dinf jitters around 2e-14, far below tol.  Neither is progress,
    so the IPM stops 6 iterations after the last real improvement (it ran 13 before); a 10× fall of
    pinf is progress."""
    clock = schur_ipm._StallClock(tol=1e-7)
    clock.tick(27, 3.0e-7, 1e-6, 6e-8, 3.0e-7, 2.6e-14)
    clock.tick(28, 1.5e-7, 5e-7, 3e-8, 1.5e-7, 2.9e-14)
    stopped = None
    for it in range(29, 45):
        clock.tick(it, 1.5e-7 - 1e-10 * it, 5e-7, 2.9e-8, 1.5e-7 - 1e-10 * it, 2.9e-14 * 0.8 ** (it % 3))
        if clock.stalled(it):
            stopped = it
            break
    assert stopped == 28 + schur_ipm.STALL_ITERATIONS_ALMOST
    clock = schur_ipm._StallClock(tol=1e-7)
    clock.tick(0, 1e-3, 1.0, 1e-3, 1e-3, 1e-3)
    for it in range(1, 5):
        clock.tick(it, 1e-3, 1.0, 1e-3, 1e-3, 1e-3)
    assert not clock.stalled(4)
    clock.tick(5, 1e-3, 1.0, 1e-3, 1e-4, 1e-3)  # pinf falls 10×, the max residual does not
    assert not clock.stalled(9) and clock.stalled(10) == schur_ipm.STALL_ITERATIONS


def test_almost_solved_means_clarabels_reduced_accuracy():
    """A stopped solve is AlmostSolved at a relative gap ≤ 5e-5 and infeasibilities ≤ 1e-4, as
    Clarabel's reduced tolerances (the IPM's best iterate on discrete K = 1000, paper set: gap
    1.5e-5, pinf 6.8e-6); not above either, and never in place of Solved."""
    assert schur_ipm.almost_solved("InsufficientProgress", 1.5e-5, 6.8e-6, 2.4e-11)
    assert schur_ipm.almost_solved("MaxIterations", 5e-5, 1e-4, 1e-4)
    assert not schur_ipm.almost_solved("InsufficientProgress", 6e-5, 1e-6, 1e-6)
    assert not schur_ipm.almost_solved("InsufficientProgress", 1e-6, 2e-4, 1e-6)
    assert not schur_ipm.almost_solved("InsufficientProgress", 1e-6, 1e-6, 2e-4)
    assert not schur_ipm.almost_solved("Solved", 1e-9, 1e-9, 1e-9)


def test_ipm_cover_keeps_variable_blocks_whole_so_constraints_stay_in_one_clique():
    """Pose averaging M = 40 (paper set): the IPM's cover is a block cover (each clique a union of whole
    variable blocks), in which at most 10 % of the constraints reach outside their home clique; in the
    column cover merged up to 16 columns, which the cost estimate used to rank first (and which ran
    6× slower per iteration at M = 200), over 90 % do."""
    from autotight.sdp.chordal import home_cliques, incidence

    prob = load("pose_averaging")
    model = prob.build(prob.generate({"M": 40}, 0))
    cons = model.primary() + model.paper_constraints()
    covers = _covers(model, cons)
    V = model.variables

    def spilled(cover) -> float:
        B = incidence(cover, V.N)
        inside = np.asarray(B[home_cliques(cover, covers.support)].multiply(covers.support.T).sum(axis=1)).ravel()
        return float(np.mean(inside < np.asarray(covers.support.sum(axis=0)).ravel()))

    chosen = covers.choose("ipm")
    for c in chosen:
        cols = set(c.tolist())
        assert all(set(range(V.offsets[n], V.offsets[n] + V.sizes[n])) <= cols
                   or not set(range(V.offsets[n], V.offsets[n] + V.sizes[n])) & cols for n in V.names)
    assert spilled(chosen) <= 0.1 < 0.9 < spilled(covers.columns[16])


def _steps_once_almost_solved(monkeypatch, length: float) -> list[int]:
    """From the first iterate within AlmostSolved's bounds on, every step has ``length``; returns the list that
    then holds that iterate's number (clear it before the next solve)."""
    seen: list[int] = []
    tick = schur_ipm._StallClock.tick

    def watch(self, it, err, diff, gap, pinf, dinf):
        if gap <= schur_ipm.REDUCED_TOL_GAP and max(pinf, dinf) <= schur_ipm.REDUCED_TOL_FEAS and not seen:
            seen.append(it)
        return tick(self, it, err, diff, gap, pinf, dinf)

    monkeypatch.setattr(schur_ipm._StallClock, "tick", watch)
    step = schur_ipm._step
    monkeypatch.setattr(schur_ipm, "_step", lambda Linv, dX, gamma: length if seen else step(Linv, dX, gamma))
    return seen


def test_a_solve_that_jams_once_almost_solved_stops_with_its_best_iterate(monkeypatch):
    """Steps forced to 1e-3 once the relative gap and infeasibilities are within AlmostSolved's bounds: the
    solve stops after JAM_ITERATIONS jammed steps, AlmostSolved and saying why, with the best iterate's costs;
    the same solve unjammed continues to Solved at those costs up to the reduced accuracy."""
    monkeypatch.setattr(schur_ipm, "COMPILED_MIN_BLOCKS", 10 ** 9)
    Q, cons, cl = _chain_maxcut(np.random.default_rng(0), 12, 6)
    free = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, IPM)
    seen = _steps_once_almost_solved(monkeypatch, 1e-3)
    res = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, IPM)
    assert free.status == "Solved" and seen and free.iterations > seen[0] + schur_ipm.JAM_ITERATIONS
    assert res.status == "AlmostSolved" and "jammed" in res.message
    assert res.iterations == seen[0] + schur_ipm.JAM_ITERATIONS
    f = free.primal_cost
    assert abs(res.primal_cost - f) <= schur_ipm.REDUCED_TOL_GAP * abs(f)


def test_a_stop_rule_is_asked_once_the_best_iterate_stands_and_ends_the_solve_there(monkeypatch):
    """Steps forced to 0 once AlmostSolved, the jam rule off: the best iterate stands.  A rule that says False is
    asked once and changes nothing: the same iterations and y, to the stall limit.  A rule that says True ends
    the solve STOP_ASK_ITERATIONS iterations after that iterate, AlmostSolved and saying why; it was given the
    iterate's multipliers of the constraints as given, which the result returns."""
    monkeypatch.setattr(schur_ipm, "COMPILED_MIN_BLOCKS", 10 ** 9)
    monkeypatch.setattr(schur_ipm, "JAM_ITERATIONS", 10 ** 6)
    Q, cons, cl = _chain_maxcut(np.random.default_rng(0), 12, 6)
    seen = _steps_once_almost_solved(monkeypatch, 0.0)
    plain = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, IPM)
    seen.clear()
    asked: list[np.ndarray] = []

    def rule(answer):
        def ask(y):
            asked.append(y.copy())
            return answer
        return ask

    no = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, IPM, stop=rule(False))
    assert len(asked) == 1 and asked[0].shape == (len(cons),)
    assert no.iterations == plain.iterations and no.status == plain.status == "AlmostSolved"
    assert "no progress" in plain.message
    np.testing.assert_array_equal(no.y, plain.y)
    seen.clear()
    asked.clear()
    yes = schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, IPM, stop=rule(True))
    assert yes.status == "AlmostSolved" and "stopped by the caller's test of y" in yes.message
    assert yes.iterations <= seen[0] + schur_ipm.STOP_ASK_ITERATIONS < plain.iterations
    assert len(asked) == 1
    np.testing.assert_array_equal(asked[0], yes.y)
    f = plain.primal_cost
    assert abs(yes.primal_cost - f) <= schur_ipm.REDUCED_TOL_GAP * abs(f)


def test_the_pipeline_stops_the_sdp_once_its_multipliers_certify_the_local_solution(monkeypatch):
    """With STOP_ASK_ITERATIONS = 0 the pipeline's rule is asked at each new best iterate once AlmostSolved, and
    the solve ends at the first whose y certifies the local solution.
    The verdict is the one of the solve run to its end (tight and certified), at fewer or as many iterations,
    its cost within the reduced accuracy; the rule says no to multipliers that certify nothing."""
    import autotight as at
    from autotight import pipeline

    monkeypatch.setattr(schur_ipm, "STOP_ASK_ITERATIONS", 0)
    stopped = at.solve("discrete_trajectory", {"K": 10}, 0, solver="ipm")
    rule = pipeline.certifies_local
    monkeypatch.setattr(pipeline, "certifies_local", lambda *a, **k: (lambda y: False))
    full = at.solve("discrete_trajectory", {"K": 10}, 0, solver="ipm")
    assert "stopped by the caller's test of y" in stopped.sdp.message
    assert "stopped" not in full.sdp.message
    assert stopped.sdp.iterations <= full.sdp.iterations
    assert stopped.outcome == full.outcome == "tight"
    assert stopped.certificate.certified and full.certificate.certified
    f = full.sdp.primal_cost
    assert abs(stopped.sdp.primal_cost - f) <= schur_ipm.REDUCED_TOL_GAP * abs(f)
    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": 10}), 0)
    model = prob.build(inst)
    cons = model.homogenisation() + model.primary()
    assert not rule(prob, inst, model, cons, full.local.best, at.Criteria())(np.zeros(len(cons)))


def test_block_threads_split_each_stack_and_give_every_block_the_unsplit_result():
    """``BlockThreads.each`` runs a per-block function on slices of each stack in two threads: every block's
    result equals the one-call result to the bit (tuples too), and a stack below ``MIN_SPLIT_BLOCKS`` stays
    whole; ``submit`` without workers runs at once."""
    from autotight.sdp.block_threads import MIN_SPLIT_BLOCKS, BlockThreads

    rng = np.random.default_rng(4)
    stacks = [_spd_blocks(rng, 3 * MIN_SPLIT_BLOCKS + 1, 7, 0.1), _spd_blocks(rng, MIN_SPLIT_BLOCKS - 1, 5, 0.1)]
    def factors(S):
        L = np.linalg.cholesky(S)
        return L, np.linalg.inv(L)

    whole = [factors(S) for S in stacks]
    seen = []

    def recording(S):
        seen.append(S.shape[0])
        return factors(S)

    with BlockThreads(2) as par:
        split = par.each(recording, stacks)
        assert par.submit(np.add, 1, 2).result() == 3
    assert sorted(seen) == sorted([MIN_SPLIT_BLOCKS - 1, (3 * MIN_SPLIT_BLOCKS + 1) // 2,
                                   3 * MIN_SPLIT_BLOCKS + 1 - (3 * MIN_SPLIT_BLOCKS + 1) // 2])
    for (L, Li), (L2, Li2) in zip(whole, split):
        assert np.array_equal(L, L2) and np.array_equal(Li, Li2)
    one = BlockThreads(1)
    assert one.submit(np.add, 1, 2).result() == 3 and one.each(np.linalg.inv, stacks[:1])[0].shape == stacks[0].shape


def test_threaded_assembly_and_band_scaling_equal_the_sequential_ones():
    """The compiled assembly of S cut into two output ranges (one per thread) and the band's scaling by
    column ranges give the same entries to the bit as one thread; the general band storage written in one
    pass equals ``_full_band`` of the scaled band."""
    from autotight.sdp import schur_kernel
    from autotight.sdp.block_threads import BlockThreads

    rng = np.random.default_rng(6)
    _, _, prog, blocks, _ = _chain_schur(rng, 40, 6)
    band = schur_ipm._BandSchur.make(sp.csr_array(schur_ipm.svec_to_vec(prog.sizes) @ prog.F), blocks, compiled=True)
    assert band is not None and band.compiled is not None and band.compiled._plan() is not None
    W = [b @ np.swapaxes(b, 1, 2) + b.shape[-1] * np.eye(b.shape[-1])
         for b in (rng.standard_normal((ids.size, n, n)) for n, ids, _ in blocks.groups)]
    one = band.assemble(W, W).copy()
    with BlockThreads(2) as par:
        two = band.assemble(W, W, par).copy()
        assert np.array_equal(one, two) and np.abs(one).max() > 0
        dsc = 1 / np.sqrt(one[0])
        scaled = schur_kernel.scaled_band(one, dsc, 1e-12)
        assert np.array_equal(scaled, schur_kernel.scaled_band(one, dsc, 1e-12, par=par))
        full = schur_kernel.scaled_full_band(one, dsc, 1e-12, par=par)
    assert np.array_equal(full, band._full_band(scaled))
    assert np.array_equal(full, schur_kernel.scaled_full_band(one, dsc, 1e-12))


@pytest.mark.parametrize("search,lu", [("nt", False), ("nt", True), ("hkm", False)])
def test_two_threads_leave_the_iterates_unchanged_to_the_bit(search, lu, monkeypatch):
    """A 160-block chain (compiled kernels) solved with one thread and with two (the slices' threshold
    lowered so that every threaded path runs: per-block slices, the assembly's two ranges, both step lengths
    at once, the band's scaling for banded Cholesky, or into the general band storage for LU with pivoting
    from the first iteration) ends with the same iterate, costs and multipliers, bit for bit."""
    from autotight.sdp import block_threads

    monkeypatch.setattr(block_threads, "MIN_SPLIT_BLOCKS", 4)
    if lu:
        band_factor = schur_ipm._BandSchur.factor

        def pivoting(self, ab, reg, par=None):
            assert self.compiled is not None and self.compiled._plan() is not None  # the split assembly runs
            self.pivoting = True
            return band_factor(self, ab, reg, par)

        monkeypatch.setattr(schur_ipm._BandSchur, "factor", pivoting)
    Q, cons, cl = _chain_maxcut(np.random.default_rng(8), 160, 6)
    out = {t: schur_ipm.solve_ipm(*_data(Q, cons), 1, cl, SolverConfig(backend="ipm",
                                                                    ipm=IpmOptions(search=search, threads=t)))
           for t in (1, 2)}
    a, b = out[1], out[2]
    assert a.status in ("Solved", "AlmostSolved"), a.summary()
    assert (a.status, a.iterations, a.primal_cost, a.dual_cost) == (b.status, b.iterations, b.primal_cost, b.dual_cost)
    assert np.array_equal(a.y, b.y) and np.array_equal(np.asarray(a.X), np.asarray(b.X))


def test_ipm_threads_option_is_checked():
    from autotight.errors import SolverConfigError

    for bad in (0, 3, True, 1.5, "2"):
        with pytest.raises(SolverConfigError, match="IpmOptions.threads"):
            IpmOptions(threads=bad)
    assert IpmOptions(threads=1).threads == 1 and IpmOptions().threads is None


def test_default_threads_follow_the_cpus_and_omp_num_threads(monkeypatch):
    """Two threads where the process may use two CPUs; one when OMP_NUM_THREADS says one (a parallel worker),
    and a value that is not a positive integer is ignored."""
    from autotight.sdp import block_threads

    monkeypatch.setattr(block_threads.os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert block_threads.default_workers() == 2
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert block_threads.default_workers() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "x")
    assert block_threads.default_workers() == 2
    monkeypatch.setattr(block_threads.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert block_threads.default_workers() == 1
