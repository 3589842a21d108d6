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

Argument (bounded shift, ``bounded_shift``).  Where H has null directions besides Θ̂'s (the relaxation's
optimal X is not unique there, so no H has Θ̂ alone in its null space), lift a set S of columns instead of h:
if tr X_SS ≤ T_S for every feasible X of cost ≤ f̄ (f̄ ≥ p*, a trace bound on S alone,
``certificate.trace_groups``) and H + δ·E_S ⪰ 0 (E_S: the identity on S), then p* ≥ bᵀy − δ·T_S.
  Proof: for such X, ⟨Q,X⟩ = bᵀy + ⟨H,X⟩ ≥ bᵀy − δ·tr X_SS ≥ bᵀy − δ·T_S; the minimiser has cost p* ≤ f̄.
S = {h} is the strict dual (T_S = d).  S grows by the trace groups in increasing order of their bounds, so only
columns that exact relations bound tightly (h, rotations) are lifted first; T_S stays small where the trace over
all columns (or over some) has no useful bound.

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


def first_shift(H: sp.csc_array, Th: np.ndarray) -> tuple[float, float]:
    """(τ, δ₀): the inertia margin ``MARGIN``·n·ε and the first δ tried (module docstring: what makes Θ̂'s own
    directions positive in the Jacobi frame, at least 2τ·Σ_j H_jj‖Θ̂_j‖² and 1e-15·max|H|).  Θ̂: (d, N)."""
    tau = MARGIN * H.shape[0] * np.finfo(float).eps
    quad = float(np.sum(Th * (H @ Th.T).T))  # ⟨H, X̂⟩
    weight = float(np.clip(H.diagonal(), 0.0, None) @ np.sum(Th * Th, axis=0))
    scale = float(abs(H).max()) if H.nnz else 1.0
    return tau, max(2.0 * (tau * weight - quad), 2.0 * tau * weight, 1e-15 * scale)


def strict_dual(H: sp.sparray, E: sp.sparray, Theta: np.ndarray, *, delta_max: float = np.inf) -> StrictDual:
    """Search δ ≤ ``delta_max`` with H + (δ/d)·E ⪰ 0 proved by ``psd_by_inertia`` (module docstring).
    E: Σ Aᵢ over the d constraints (X_hh)_ii = 1 (E_h); Θ̂: (d, N) the lifted candidate."""
    H = sp.csc_array(H)
    Th = np.atleast_2d(np.asarray(Theta, dtype=float))
    d = Th.shape[0]
    tau, delta = first_shift(H, Th)
    ok, low, why = psd_by_inertia(H)
    if ok:
        return StrictDual(True, 0.0, low, tau, 1)
    ok, delta, low, why, tries = grow_shift(H, sp.csc_array(E), delta, d, 1.0, delta_max, "δ", low, why)
    if ok:
        return StrictDual(True, delta, low, tau, tries + 1)
    return StrictDual(False, np.inf, low, tau, tries + 1, f"no δ made H + δ·E_h ⪰ 0 provable: {why}")


def grow_shift(H: sp.csc_array, E: sp.sparray, delta: float, div: float, loss_per_delta: float, loss_max: float,
               label: str, low: float, why: str) -> tuple[bool, float, float, str, int]:
    """(proved, δ, smallest pivot, reason, factorisations): the first δ = δ₀·GROWTHᵏ (k < ``MAX_TRIES``) for which
    ``psd_by_inertia`` proves H + (δ/div)·E ⪰ 0, while its loss δ·loss_per_delta stays ≤ ``loss_max`` (the search
    of the strict dual and of the bounded shift; ``label`` names the loss in the reason, ``why`` is the reason so
    far, ``low`` the smallest pivot so far)."""
    tries = 0
    for _ in range(MAX_TRIES):
        if delta * loss_per_delta > loss_max:
            return False, delta, low, f"{label} would exceed {loss_max:.2e} ({why})", tries
        ok, low, why = psd_by_inertia(H + (delta / div) * E)
        tries += 1
        if ok:
            return True, delta, low, why, tries
        delta *= GROWTH
    return False, delta, low, why, tries


@dataclass
class BoundedShift:
    """Outcome of ``bounded_shift``: ok when H + δ·E_S ⪰ 0 was proved, S the columns ``columns`` with
    tr X_SS ≤ ``trace`` (T_S); the bound is then bᵀy − δ·T_S (``loss``); min_pivot, margin, tries, message:
    as ``StrictDual``'s."""

    ok: bool
    delta: float
    columns: np.ndarray
    trace: float
    min_pivot: float
    margin: float
    tries: int
    message: str = ""

    @property
    def loss(self) -> float:
        return self.delta * self.trace if self.ok else np.inf


#: ``bounded_shift`` tries at most this many sets S (prefixes of the trace groups by bound)
MAX_SHIFT_SETS = 4


def bounded_shift(H: sp.sparray, group_of: np.ndarray, groups: list[float], Theta: np.ndarray, *,
                  loss_max: float) -> BoundedShift:
    """Search S and δ with δ·T_S ≤ ``loss_max`` and H + δ·E_S ⪰ 0 proved by ``psd_by_inertia`` (module docstring,
    bounded shift).  group_of: each column's trace group (−1: unbounded; ``certificate.trace_groups``),
    groups: their bounds; S is the union of the groups of bound ≤ B for the smallest distinct bounds B
    (``MAX_SHIFT_SETS`` of them), δ starts as ``strict_dual``'s and grows by ``GROWTH``.  Θ̂: (d, N)."""
    H = sp.csc_array(H)
    tau, start = first_shift(H, np.atleast_2d(np.asarray(Theta, dtype=float)))
    bounds = np.asarray(groups, dtype=float)
    tries, low, why = 0, 0.0, "no column has a trace bound"
    for B in np.unique(bounds)[:MAX_SHIFT_SETS]:
        on = (group_of >= 0) & (bounds[np.maximum(group_of, 0)] <= B)
        T_S = float(bounds[bounds <= B].sum())
        E = sp.diags_array(on.astype(float), format="csc")
        ok, delta, low, why, n = grow_shift(H, E, start, 1.0, T_S, loss_max, "δ·T_S", low, why)
        tries += n
        if ok:
            return BoundedShift(True, delta, np.flatnonzero(on), T_S, low, tau, tries)
    return BoundedShift(False, np.inf, np.zeros(0, dtype=np.int64), np.inf, low, tau, tries,
                        f"no δ made H + δ·E_S ⪰ 0 provable: {why}")
