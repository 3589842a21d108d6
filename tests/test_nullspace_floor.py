"""The rank rule ignores spectral gaps below the roundoff floor (relations that hold bit-exactly)."""

from __future__ import annotations

import numpy as np

from autotight.discovery.nullspace import RANK_FLOOR, basic_solutions, free_monomials, nullspace, spectrum
from autotight.svec import triu_indices

U0 = np.array([0.3, -0.5, 0.8])


def _binary_data(rng: np.random.Generator, S: int) -> np.ndarray:
    """x = [h, w, u, z] with w = ±1, u a unit 3-vector near U0 (uᵀu = 1 only to roundoff), z = w·u
    (bit-exact); rows = the 36 monomials x_i x_j.

    Distinct functions among the monomials: 1, w, u (3), w·u (3), u_k u_l (6), w·u_k u_l (6) = 20, less
    the two relations uᵀu = 1 and w·uᵀu = w: rank 18.  The other 16 relations (w² = h², z·h = w·u,
    z_k z_l = u_k u_l, …) hold bit-exactly and put singular values far below roundoff."""
    X = []
    for _ in range(S):
        w = rng.choice([-1.0, 1.0])
        u = U0 + 0.3 * rng.standard_normal(3)
        u /= np.linalg.norm(u)
        X.append(np.concatenate([[1.0, w], u, w * u]))
    X = np.array(X)
    i, j = triu_indices(8)
    return X[:, i] * X[:, j]


def test_floor_constant_is_about_1e_12():
    assert 5e-13 < RANK_FLOOR < 2e-12


def test_exact_sub_roundoff_gap_is_ignored_and_reported():
    rng = np.random.default_rng(0)
    Y = _binary_data(rng, 60)
    Yn = Y / np.linalg.norm(Y, axis=0)
    spec = spectrum(Yn, 6.0)
    assert spec.rank == 18 and spec.nullity == 18
    # the sub-roundoff gap is larger than the true one: without the floor the rank would be wrong
    assert spec.ignored_gap_decades is not None and spec.ignored_gap_decades > spec.gap_decades
    assert spec.ignored_gap_rank > 18 and spec.rel[spec.ignored_gap_rank - 1] < RANK_FLOOR
    unfloored = spectrum(Yn, 6.0, floor=0.0)
    assert unfloored.rank == spec.ignored_gap_rank and unfloored.ignored_gap_decades is None
    assert spec.gaps()["ignored"]["rank"] == spec.ignored_gap_rank
    # the 18 relations read off at the floored rank hold on fresh samples
    V = basic_solutions(nullspace(Yn, spec.rank), free_monomials(nullspace(Yn, spec.rank)))
    P = V / np.linalg.norm(Y, axis=0)[:, None]
    fresh = _binary_data(np.random.default_rng(1), 40)
    assert np.abs(fresh @ P).max() / np.abs(P).max() < 1e-12


def test_a_true_gap_above_the_floor_still_decides():
    """Columns 1, a, a² and a bit-exact copy of a²: the gap below a² (upper end far above the floor)
    gives rank 3 of 4."""
    rng = np.random.default_rng(2)
    a = rng.standard_normal(30)
    Y = np.column_stack([np.ones(30), a, a * a])
    Y = np.column_stack([Y, Y[:, 2]])  # an exact duplicate column: a relation that holds bit-exactly
    Yn = Y / np.linalg.norm(Y, axis=0)
    spec = spectrum(Yn, 6.0)
    assert spec.rank == 3 and spec.gap_decades > 10


def test_refit_on_support_zeroes_roundoff_terms_and_keeps_a_column_whose_support_misses_a_term():
    """x² + y² − 1 = 0 on the unit circle, monomials [1, x, y, x², xy, y²] normalised by column: a basic solution
    with a 1e-9 stray on xy is refitted to the exact relation (xy exactly 0, the rest to 1e-12); with a support
    threshold that drops a true term the refit fits worse, and the column is kept as it was."""
    from autotight.discovery.nullspace import refit_on_support

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, 40)
    x, y = np.cos(a), np.sin(a)
    Y = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    D = np.linalg.norm(Y, axis=0)
    Yn = Y / D
    exact = np.array([-1.0, 0, 0, 1.0, 0, 1.0]) * D / D[5]  # normalised frame, y² (free) coefficient 1
    v = exact.copy()
    v[4] = 1e-9
    free = np.array([5])
    sigma = float(np.linalg.svd(Yn, compute_uv=False)[0])
    got = refit_on_support(Yn, v[:, None], free, sigma)[:, 0]
    assert got[4] == 0.0 and got[1] == 0.0 and got[2] == 0.0 and got[5] == 1.0
    assert np.max(np.abs(got - exact)) <= 1e-12 * np.max(np.abs(exact))
    kept = refit_on_support(Yn, v[:, None], free, sigma, rtol=0.7)[:, 0]  # keeps the constant alone: drops x²
    assert np.array_equal(kept, v)


def _with_spectrum(rng: np.random.Generator, s: np.ndarray, rows: int = 40) -> np.ndarray:
    """A rows × s.size matrix with singular values s (random orthogonal factors)."""
    U = np.linalg.qr(rng.standard_normal((rows, s.size)))[0]
    V = np.linalg.qr(rng.standard_normal((s.size, s.size)))[0]
    return (U * s) @ V.T


def test_a_half_gap_decides_only_above_an_exact_nullspace():
    """Ill-conditioned data whose true values reach 1e-10.4 above a nullspace at roundoff (1e-16.2): a 5.8-decade
    gap, whose lower end lies below the floor, decides the rank; the same gap above values at 1e-11.2
    (near-relations above the floor, not roundoff) does not, and neither does a gap under half the required width."""
    import pytest

    from autotight.errors import LearningError

    rng = np.random.default_rng(3)
    true = np.logspace(0, -10.4, 12)
    exact = _with_spectrum(rng, np.concatenate([true, np.full(4, 10 ** -16.2)]))
    spec = spectrum(exact, 6.0)
    assert spec.rank == 12 and 5.6 < spec.gap_decades < 6.0
    near = _with_spectrum(rng, np.concatenate([np.logspace(0, -5.4, 12), np.full(4, 10 ** -11.2)]))
    with pytest.raises(LearningError, match=r"need ≥ 6\)"):
        spectrum(near, 6.0)  # the same 5.8 decades, its lower end 1e-11.2 above the floor: not exact
    narrow = _with_spectrum(rng, np.concatenate([np.logspace(0, -11.5, 12), np.full(4, 10 ** -14.2)]))
    with pytest.raises(LearningError, match=r"need ≥ 3\)"):
        spectrum(narrow, 6.0)  # 2.7 decades above an exact nullspace: less than half
