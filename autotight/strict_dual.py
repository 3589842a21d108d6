"""A strictly feasible dual: a lower bound on the relaxation without any bound on tr X.

Argument (strict dual).  Let H = Q − Σ yᵢAᵢ and, for δ ≥ 0, y′ = y − (δ/d)·Σ_{i∈𝓗} eᵢ, where 𝓗 are
the d constraints (X_hh)_ii = 1.  Then H′ = H(y′) = H + (δ/d)·E_h (E_h: the identity on the h columns)
and bᵀy′ = bᵀy − δ.  If H′ ⪰ 0, then p* ≥ bᵀy − δ.
  Proof: for every feasible X, ⟨Q,X⟩ = Σ y′ᵢ⟨Aᵢ,X⟩ + ⟨H′,X⟩ = bᵀy′ + ⟨H′,X⟩ (⟨Aᵢ,X⟩ = bᵢ), and
  ⟨H′,X⟩ ≥ 0 since H′ ⪰ 0 and X ⪰ 0; minimise over X.
Hence f(x̂) − p* ≤ f(x̂) − bᵀy + δ, with no trace anywhere.  Why it works at a rank-1 solution: H's
(near) null space is spanned by Θ̂ᵀ, whose h block is I_d, so the shift lifts exactly those directions,
by δ/‖Θ̂‖²_F in the Rayleigh quotient; every other direction keeps H's own positive margin.

Argument (zero rows).  Columns j on which H′ vanishes (H′_{j,·} = 0, e.g. the columns set aside on a
face, ``autotight.face``) are left out: ⟨H′,X⟩ = ⟨H′_KK, X_KK⟩ for K the other columns, so H′_KK ⪰ 0
suffices.  Proof: every term H′_jk X_jk with j or k outside K is 0.

Argument (inertia, ``psd_by_inertia``).  H′_KK ⪰ τ·S⁻² (so ⪰ 0) when the LDLᵀ factorisation of
S H′_KK S − τI has no pivot ≤ 0, S = diag(H′_jj)^{−1/2} (the Jacobi frame, unit diagonal).
  Proof: Sylvester's law of inertia (LDLᵀ is a congruence, and so is the scaling by S); a negative
  diagonal entry already disproves H′ ⪰ 0, a zero one with a nonzero row too.
Assumption: the factorisation's roundoff.  For a positive definite matrix with unit diagonal the
computed LDLᵀ is exact for a perturbation of entries ≤ c·n·ε (Cholesky's componentwise backward error,
relative to √(H_jj H_kk)); the margin τ = ``MARGIN``·n·ε is that size, so a positive LDLᵀ of the shifted
matrix is not an artefact of roundoff of that order.  qdldl (AMD ordering, no pivoting) factors it.

The search for δ (``strict_dual``) only proposes; the inertia test decides.  It starts from the
Rayleigh quotient of Θ̂ (δ₀ = 2·(τ·Σ_j H_jj‖Θ̂_j‖² − ⟨H, X̂⟩)⁺, what makes Θ̂'s own directions positive
in the Jacobi frame) and grows by ``GROWTH`` a bounded number of times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

#: the inertia test's margin τ in the Jacobi frame, in units of n·ε (module docstring)
MARGIN = 1.0
#: growth of δ per failed inertia test, and the number of tests
GROWTH = 10.0
MAX_TRIES = 6
#: a row counts as zero when its entries are below this multiple of max|H| (roundoff of H's assembly)
ZERO_ROW_RTOL = 1e-14


@dataclass
class StrictDual:
    """Outcome of ``strict_dual``: ok when H + (δ/d)·E_h ⪰ 0 was proved on ``kept`` columns (the others
    vanish); delta: δ; min_pivot: the smallest pivot of the last factorisation (Jacobi frame, after the
    shift τ); margin: τ; tries: factorisations made; message: why not, when not ok."""

    ok: bool
    delta: float
    min_pivot: float
    margin: float
    tries: int
    message: str = ""


def psd_by_inertia(H: sp.sparray, margin: float | None = None) -> tuple[bool, float, str]:
    """(H ⪰ 0 proved, smallest pivot, reason if not): the inertia argument of the module docstring on
    the columns whose row of H is not zero (rows below ``ZERO_ROW_RTOL``·max|H| must be exactly
    removable: their diagonal is 0).  margin: τ (default ``MARGIN``·n·ε)."""
    import qdldl

    H = sp.csc_array(H)
    if H.nnz == 0:
        return True, 0.0, ""
    top = float(abs(H).max())
    diag = H.diagonal()
    rowmax = np.asarray(abs(H).max(axis=0).todense()).ravel()
    if np.any(diag < 0):
        j = int(np.argmin(diag))
        return False, float(diag[j] / top), f"a negative diagonal entry H_jj = {diag[j]:.2e} (column {j})"
    zero = rowmax <= ZERO_ROW_RTOL * top
    bad = (diag <= ZERO_ROW_RTOL * top) & ~zero
    if bad.any():
        return False, 0.0, f"{int(bad.sum())} column(s) with H_jj = 0 and a nonzero row"
    K = np.flatnonzero(~zero)
    s = 1.0 / np.sqrt(diag[K])
    Hs = sp.csc_array(sp.diags_array(s) @ H[K][:, K] @ sp.diags_array(s))
    tau = MARGIN * K.size * np.finfo(float).eps if margin is None else margin
    A = sp.triu(Hs - tau * sp.identity(K.size, format="csc"), format="csc")
    try:
        D = qdldl.Solver(A, upper=True).factors()[1]
    except (ValueError, RuntimeError) as e:  # a zero pivot: not positive definite at this shift
        return False, 0.0, f"the LDLᵀ factorisation broke down ({e})"
    low = float(np.min(D))
    if not (low > 0 and np.all(np.isfinite(D))):
        return False, low, f"{int(np.count_nonzero(~(D > 0)))} pivot(s) ≤ 0 of {K.size}"
    return True, low, ""


def strict_dual(H: sp.sparray, E: sp.sparray, Theta: np.ndarray, *, delta_max: float = np.inf) -> StrictDual:
    """Search δ ≤ ``delta_max`` with H + (δ/d)·E ⪰ 0 proved by ``psd_by_inertia`` (module docstring).
    E: Σ Aᵢ over the d constraints (X_hh)_ii = 1 (E_h); Θ̂: (d, N) the lifted candidate."""
    H = sp.csc_array(H)
    n = H.shape[0]
    Th = np.atleast_2d(np.asarray(Theta, dtype=float))
    d = Th.shape[0]
    tau = MARGIN * n * np.finfo(float).eps
    quad = float(np.sum(Th * (H @ Th.T).T))  # ⟨H, X̂⟩
    weight = float(np.clip(H.diagonal(), 0.0, None) @ np.sum(Th * Th, axis=0))
    scale = float(abs(H).max()) if H.nnz else 1.0
    delta = max(2.0 * (tau * weight - quad), 2.0 * tau * weight, 1e-15 * scale)
    ok, low, why = psd_by_inertia(H)
    if ok:
        return StrictDual(True, 0.0, low, tau, 1)
    tries = 1
    for _ in range(MAX_TRIES):
        if delta > delta_max:
            why = f"δ would exceed {delta_max:.2e} ({why})"
            break
        ok, low, why = psd_by_inertia(H + (delta / d) * sp.csc_array(E))
        tries += 1
        if ok:
            return StrictDual(True, delta, low, tau, tries)
        delta *= GROWTH
    return StrictDual(False, np.inf, low, tau, tries, f"no δ made H + δ·E_h ⪰ 0 provable: {why}")
