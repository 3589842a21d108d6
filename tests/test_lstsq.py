"""Minimum-norm least squares (autotight.lstsq): the factorised proximal steps against a dense solve."""

import numpy as np
import pytest
import scipy.sparse as sp

from autotight import lstsq
from autotight.lstsq import min_norm_lstsq


def _chain(rng: np.random.Generator, blocks: int, rows: int = 6, cols: int = 9) -> sp.csr_array:
    """A chain: block k's columns touch rows of blocks k and k + 1; one column repeated (rank-deficient
    in columns) and one row the sum of two others (rank-deficient in rows)."""
    n, m = blocks * rows, blocks * cols
    G = sp.lil_array((n, m))
    for k in range(blocks):
        r = slice(k * rows, min((k + 2) * rows, n))
        G[r, k * cols:(k + 1) * cols] = rng.standard_normal((min((k + 2) * rows, n) - k * rows, cols))
    D = G.toarray()
    D[:, m - 1] = D[:, 0]
    D[n - 1] = D[0] + D[1]
    return sp.csr_array(D)


@pytest.mark.parametrize("consistent", [True, False])
def test_factorised_path_equals_the_dense_minimum_norm_solution(monkeypatch, consistent):
    """Forced onto the factorisation (LSQR_MAX_COLUMNS = 0): equal to pinv(G) r to 1e-9 relative, for a
    consistent right-hand side and for one with a residual, and orthogonal to G's nullspace."""
    monkeypatch.setattr(lstsq, "LSQR_MAX_COLUMNS", 0)
    rng = np.random.default_rng(0)
    G = _chain(rng, 40)
    Gd = G.toarray()
    r = Gd @ rng.standard_normal(G.shape[1]) if consistent else rng.standard_normal(G.shape[0])
    x = min_norm_lstsq(G, r)
    ref = np.linalg.pinv(Gd) @ r
    assert np.linalg.norm(x - ref) <= 1e-9 * np.linalg.norm(ref)
    null = np.linalg.svd(Gd)[2][np.linalg.matrix_rank(Gd):]  # rows span G's nullspace
    assert np.linalg.norm(null @ x) <= 1e-9 * np.linalg.norm(x)


@pytest.mark.parametrize("route", ["small system", "failed factorisation"])
def test_lsqr_routes(monkeypatch, route):
    """Below LSQR_MAX_COLUMNS the factorisation is not reached (one that raises AssertionError is never
    called); above it, a factorisation that fails ("exactly singular") falls back to LSQR.  Both equal
    pinv(G) r to 1e-9."""
    error = AssertionError if route == "small system" else RuntimeError
    if route == "failed factorisation":
        monkeypatch.setattr(lstsq, "LSQR_MAX_COLUMNS", 0)

    def factorise(*a, **k):
        raise error("Factor is exactly singular")

    monkeypatch.setattr(lstsq.spla, "splu", factorise)
    rng = np.random.default_rng(1)
    G = _chain(rng, 10)
    r = rng.standard_normal(G.shape[0])
    x = min_norm_lstsq(G, r)
    assert np.linalg.norm(x - np.linalg.pinv(G.toarray()) @ r) <= 1e-9 * np.linalg.norm(x)


def test_empty_system():
    assert min_norm_lstsq(sp.csr_array((0, 3)), np.zeros(0)).tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("consistent", [True, False])
def test_equilibrated_solution_is_the_least_squares_solution_of_least_column_weighted_norm(monkeypatch, consistent):
    """Columns scaled by factors from 1e-4 to 1e4 (as multipliers of constraints on entries of very different
    size): the solution equals C⁻¹ pinv(G C⁻¹) r (C: column norms) to 1e-8 relative, and its residual is
    the least-squares residual."""
    monkeypatch.setattr(lstsq, "LSQR_MAX_COLUMNS", 0)
    rng = np.random.default_rng(1)
    G0 = _chain(rng, 40)
    G = sp.csr_array(G0 @ sp.diags_array(10.0 ** rng.uniform(-4, 4, G0.shape[1])))
    Gd = G.toarray()
    r = Gd @ rng.standard_normal(G.shape[1]) if consistent else rng.standard_normal(G.shape[0])
    x = lstsq.equilibrated_lstsq(G, r)
    norms = np.linalg.norm(Gd, axis=0)
    ref = (np.linalg.pinv(Gd / norms) @ r) / norms
    assert np.linalg.norm(norms * (x - ref)) <= 1e-8 * np.linalg.norm(norms * ref)
    best = np.linalg.norm(Gd @ ref - r)
    assert np.linalg.norm(Gd @ x - r) <= best + 1e-9 * np.linalg.norm(r)

