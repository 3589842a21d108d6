"""Memory proportional to nonzeros: constraint storage, build, the clique program and a sparse X."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp

import autotight.sdp.clique_program as cp
from autotight.model import Constraint
from autotight.pipeline import solve_instance
from autotight.problem import load
from autotight.sdp.clique_program import clique_program
from autotight.sdp.config import SolverConfig


def _model(K: int):
    prob = load("discrete_trajectory")
    inst = prob.generate(prob.parse_params({"K": K}), np.random.default_rng(0))
    return prob, inst, prob.build(inst)


def _bytes(c: Constraint) -> int:
    A = c.A
    return A.data.nbytes + A.row.nbytes + A.col.nbytes


def test_constraints_are_stored_in_space_proportional_to_nonzeros():
    sizes = {}
    for K in (20, 40):
        _, _, model = _model(K)
        cons = model.all_constraints()
        assert all(isinstance(c.A, sp.coo_array) for c in cons)
        assert all(c.A.row.size == c.A.nnz and c.A.col.size == c.A.nnz for c in cons)  # no N + 1 array
        sizes[K] = sum(_bytes(c) for c in cons)
    assert 1.8 < sizes[40] / sizes[20] < 2.2, sizes


def _peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_build_and_clique_program_memory_grow_linearly():
    peaks_build, peaks_prog = {}, {}
    for K in (30, 60):
        prob, inst, _ = _model(K)
        peaks_build[K] = _peak(lambda: prob.build(inst))
        model = prob.build(inst)
        cons = model.primary() + model.paper_constraints()
        peaks_prog[K] = _peak(lambda: clique_program(model.Q, [c.A for c in cons], np.array([c.b for c in cons]),
                                                     model.clique_indices()))
    assert peaks_build[60] / peaks_build[30] < 2.4, peaks_build
    assert peaks_prog[60] / peaks_prog[30] < 2.4, peaks_prog


@pytest.mark.parametrize("backend", ["ipm", "clarabel"])
def test_sparse_solution_matches_dense(monkeypatch, backend):
    prob, inst, model = _model(6)
    inst.seed = 0
    cfg = SolverConfig(backend=backend, decompose=True)
    dense = solve_instance(prob, inst, "paper", config=cfg, model=model, n_random=0)
    monkeypatch.setattr(cp, "DENSE_X_MAX", 10)
    sparse = solve_instance(prob, inst, "paper", config=cfg, model=model, n_random=0)
    assert isinstance(dense.sdp.X, np.ndarray) and sp.issparse(sparse.sdp.X)
    assert sparse.sdp.X.nnz < 0.5 * model.variables.N ** 2
    assert sparse.tight and dense.tight
    assert abs(sparse.sdp.primal_cost - dense.sdp.primal_cost) <= 1e-9 * abs(dense.sdp.primal_cost)
    assert abs(sparse.log_svr - dense.log_svr) < 1e-6
    assert np.allclose(sparse.sdp.Theta, dense.sdp.Theta, rtol=1e-6, atol=1e-8)
    assert abs(sparse.sdp.eigvals[0] - dense.sdp.eigvals[0]) <= 1e-8 * dense.sdp.eigvals[0]


def test_size_estimate_counts_a_dense_x_only_for_solvers_that_hold_one():
    """Discrete trajectory K = 1000 (N ≈ 24 000): a solve that may hold X dense needs N² entries
    (> 50 GB: refused on this machine), one on our clique cover (``--solver ipm``, ``--decompose``)
    keeps X on the cliques' pattern, so only the data's nonzeros count, linearly above the size where
    Clarabel may solve again: K = 1000 within 1.2 GB (measured 0.83 GB) and K = 10 000 within 7–9 GB
    (measured 7.86 GB)."""
    from autotight.limits import (COVER_BASE_BYTES, COVER_BYTES_PER_NONZERO, COVER_BYTES_PER_NONZERO_SQUARED,
                                  estimate_size, holds_dense_x)
    from autotight.sdp import FALLBACK_MAX_N

    prob = load("discrete_trajectory")
    params = prob.parse_params({"K": 1000})
    assert holds_dense_x(None) and holds_dense_x(SolverConfig())
    assert not holds_dense_x(SolverConfig(backend="ipm")) and not holds_dense_x(SolverConfig(decompose=True))
    assert holds_dense_x(SolverConfig(backend="ipm", decompose=False))
    dense, cover = estimate_size(prob, params, True), estimate_size(prob, params, False)
    assert 23_000 < dense.N < 25_000 and dense.bytes > 50e9
    assert cover.nonzeros == dense.nonzeros
    z = cover.nonzeros
    assert cover.N > FALLBACK_MAX_N and cover.bytes == pytest.approx(COVER_BASE_BYTES + z * COVER_BYTES_PER_NONZERO)
    assert 0.82e9 <= cover.bytes < 1.2e9
    assert 7e9 < estimate_size(prob, prob.parse_params({"K": 10_000}), False).bytes < 9e9
    small = estimate_size(prob, prob.parse_params({"K": 300}), False)  # Clarabel may solve again: superlinear
    zs = small.nonzeros
    assert small.N <= FALLBACK_MAX_N and small.bytes == pytest.approx(
        COVER_BASE_BYTES + zs * COVER_BYTES_PER_NONZERO + zs ** 2 * COVER_BYTES_PER_NONZERO_SQUARED)
