"""The README's worked toy: lifted monomials → nullspace → a named constraint → rank 1.

    python docs/toy_lifting.py

Minimise f(a) = (a³ − a − 0.2)² + 0.25 (a − 1.2)² over a ∈ ℝ.  Lift x = [h, a, b, c] = [1, a, a², a³]:
f = xᵀQx with Q = r₁r₁ᵀ + r₂r₂ᵀ, and the primary constraints h² = 1, hb = a², hc = ab define the lifting.
Prints the nullspace of the sampled monomials, the SDP with the primary constraints (not tight) and with
the one constraint the nullspace adds (tight: rank 1, the global minimum).
"""

from __future__ import annotations

import warnings

import cvxpy as cp
import numpy as np

NAMES = ["h", "a", "b", "c"]


def sym(i: int, j: int) -> np.ndarray:
    """The symmetric 4 × 4 matrix A with xᵀAx = x_i x_j."""
    A = np.zeros((4, 4))
    A[i, j] += 0.5
    A[j, i] += 0.5
    return A


def nullspace_of_samples(n: int = 20, seed: int = 0) -> tuple[np.ndarray, list[str]]:
    """Rows svec(xxᵀ) of n feasible samples → an orthonormal basis (k, 10) of their nullspace, the monomial names."""
    rng = np.random.default_rng(seed)
    iu = np.triu_indices(4)
    weight = np.where(iu[0] == iu[1], 1.0, np.sqrt(2))
    rows = [np.outer(x, x)[iu] * weight for x in ([1.0, s, s ** 2, s ** 3] for s in rng.standard_normal(n))]
    _, sv, Vt = np.linalg.svd(np.array(rows))
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    return Vt[rank:], [NAMES[i] + NAMES[j] for i, j in zip(*iu)]


def shor(Q: np.ndarray, constraints: list[tuple[np.ndarray, float]]) -> tuple[float, np.ndarray, str]:
    """min ⟨Q, X⟩ s.t. ⟨A, X⟩ = b, X ⪰ 0 → (cost, eigenvalues of X, descending, the solver's status)."""
    X = cp.Variable((4, 4), PSD=True)
    prob = cp.Problem(cp.Minimize(cp.trace(Q @ X)), [cp.trace(A @ X) == b for A, b in constraints])
    with warnings.catch_warnings():  # the status is printed instead
        warnings.simplefilter("ignore", UserWarning)
        prob.solve(solver="CLARABEL")
    return float(prob.value), np.linalg.eigvalsh(X.value)[::-1], str(prob.status)


def main() -> dict[str, float]:
    h, a, b, c = range(4)
    r1, r2 = np.array([-0.2, -1.0, 0.0, 1.0]), np.array([-0.6, 0.5, 0.0, 0.0])  # c − a − 0.2, 0.5 (a − 1.2)
    Q = np.outer(r1, r1) + np.outer(r2, r2)
    primary = [(sym(h, h), 1.0), (sym(h, b) - sym(a, a), 0.0), (sym(h, c) - sym(a, b), 0.0)]
    null, names = nullspace_of_samples()
    print(f"monomials {' '.join(names)}: nullspace of dimension {null.shape[0]}")
    cost0, eig0, status0 = shor(Q, primary)
    cost1, eig1, status1 = shor(Q, primary + [(sym(a, c) - sym(b, b), 0.0)])
    grid = np.linspace(-3, 3, 600_001)
    f = (grid ** 3 - grid - 0.2) ** 2 + 0.25 * (grid - 1.2) ** 2
    print(f"global minimum f = {f.min():.6f} at a = {grid[f.argmin()]:.4f}")
    print(f"primary only:  cost {cost0:.3g} ({status0}), eigenvalues {np.array2string(eig0, precision=2)}")
    print(f"with ac = b²:  cost {cost1:.6f} ({status1}), eigenvalues {np.array2string(eig1, precision=2)}, "
          f"log SVR {np.log10(eig1[0] / max(eig1[1], 1e-300)):.1f}")
    return {"null_dim": null.shape[0], "f_min": float(f.min()), "cost_primary": cost0, "cost_tight": cost1,
            "log_svr_tight": float(np.log10(eig1[0] / max(eig1[1], 1e-300)))}


if __name__ == "__main__":
    main()
