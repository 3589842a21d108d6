"""A dual certificate for a candidate solution x̂ of the QCQP, from multipliers y.

For the Shor SDP  p* = min ⟨Q,X⟩ s.t. ⟨Aᵢ,X⟩ = bᵢ, X ⪰ 0  and any y, let H = Q − Σ yᵢAᵢ.  For every
feasible X,  ⟨Q,X⟩ = yᵀb + ⟨H,X⟩ ≥ yᵀb + min(λ_min(H), 0)·tr(X).  Let f̂ = ⟨Q,X̂⟩, X̂ = Θ̂ᵀΘ̂ (the lifted
candidate, cost offset excluded) and T a bound on tr(X) over the sublevel set S = {X feasible, ⟨Q,X⟩ ≤ f̄}
with f̄ ≥ p* (we take f̄ = 2|f̂| + ε, valid when x̂ is feasible, since then p* ≤ f̂).  The minimum over the
feasible set equals the minimum over S, so p* ≥ yᵀb − λ⁻·T with λ⁻ = max(−λ_min(H), 0), and

    f̂ − p*  ≤  f̂ − yᵀb + λ⁻·T  =  ⟨H, X̂⟩ + Σᵢ yᵢ(⟨Aᵢ,X̂⟩ − bᵢ) + λ⁻·T  =: bound.

Since p* ≤ q* (the QCQP's optimum), ``bound`` also bounds the suboptimality of x̂ for the QCQP (up to
x̂'s own constraint residual, reported as ``primal_residual``).  λ⁻ is a certified lower bound: the
smallest eigenvalue λ̂ (dense below ``DENSE_MAX`` columns, else shift-invert Lanczos, shifted as
``NEAR_SHIFT_MIN_N`` says), lowered by δ until
an LDLᵀ factorisation of H − (λ̂ − δ)I has no negative pivot (exact up to that factorisation's roundoff).

The trace bound T (``trace_bound``) is derived from the data, never assumed: columns are bounded one
group at a time, by a constraint ⟨A,X⟩ = b or by the cost ⟨Q,X⟩ ≤ f̄, whose part A_UU on the still
unbounded columns U it touches is definite (|A_UU| ⪰ a·I): with B the bounded columns it touches,
a·tr X_UU ≤ |b| + ‖A_BB‖_F·T_B + 2‖A_UB‖_F·√(tr X_UU·T_B)  (for X ⪰ 0, ‖X_UB‖_* ≤ √(tr X_UU·tr X_BB)),
a quadratic inequality in √tr X_UU.  h² = 1 and cᵢᵀcᵢ = h² bound h and rotation columns; the cost
bounds the residual blocks (tr over them ≤ f̄/λ_min(W) without cross terms); rᵀr = … (R2) then bounds
translations.  When some column stays unbounded, T is None and nothing is certified.

Strict dual (``autotight.strict_dual``), tried first where λ⁻ > 0: lower the multipliers of
(X_hh)_ii = 1 by δ/d each, so that H + (δ/d)·E_h ⪰ 0, proved by an LDLᵀ inertia count in the Jacobi
frame; then p* ≥ bᵀy − δ without any trace, and bound = f̂ − bᵀy + δ.  The trace bound below is the
fallback where that proves nothing (continuous time, K = 21: T ≈ 1e15–1e23 against tr X̂ ≈ 90, so only
the strict dual certifies).  ``Certificate.argument`` names the argument used, ``assumptions`` what it
assumed.  Multipliers on the face of the bounded columns: ``autotight.face``.

Recession columns (``recession_columns``).  A column j on which neither Q nor any Aᵢ has a diagonal
entry is a zero-cost recession direction: X + t·e_j e_jᵀ is feasible with the same cost for every t ≥ 0,
so tr X is unbounded and every dual feasible H(y) ⪰ 0 has H(y)e_j = 0 (H_jj = 0).  For such columns J
(K the others) the bound uses H_KK: if H's rows on J vanish, ⟨H,X⟩ = ⟨H_KK,X_KK⟩ ≥ −λ⁻(H_KK)·tr X_KK,
and T only has to bound the columns K.  ``polish_dual`` adds the equations H(y)_{J,·} = 0; their
residual max|H_{J,·}| must be below ``FREE_ATOL``·max|H| (roundoff of the polish; above it, nothing is
certified).  Example: robust pose averaging's gated lifting, where nothing bounds the translation r.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .ldl import SymmetricLDL
from .lstsq import min_norm_lstsq
from .model import Constraint
from .svec import stored_entries
from .validity import VALID_RTOL, relative_violations

#: below this many columns, eigenvalues are computed densely
DENSE_MAX = 200
#: iteration cap of the shift-invert Lanczos in ``lambda_min`` (ARPACK's default 10·n, kept up to n = 500;
#: twice this for the plain one).  With an indefinite H (relaxations that are not tight) ARPACK can use
#: all 10·n iterations, each a sparse solve: discrete K = 200, 2 × 48 000 solves, 115 of a 125 s run.
#: The lower bound is confirmed by LDLᵀ inertia whatever Lanczos returns.
LANCZOS_MAXITER = 5000
#: H's entries on recession columns count as zero up to this multiple of max|H| (module docstring)
FREE_ATOL = 1e-12
#: from this many columns on, ``lambda_min`` shifts to NEAR_SHIFT·max|H| below zero and factors H − σI
#: symmetrically (``symmetric_ldl``) instead of σ = −1e-3·max|H| with SuperLU's pivoting.  At a tight
#: relaxation λ_min(H) ≈ 0 and on a long chain λ₂ is tiny (discrete K = 1000: λ₂ ≈ 1e-4, max|H| ≈ 4.5e3),
#: so at σ = −1e-3·max|H| the shifted spectrum has no gap: 7 400 solves, 9.8 s per call, three calls per
#: solve.  At σ = −1e-8·max|H|: 21 solves and 0.2 s, λ̂ equal to 1e-13 absolute (and closer to the
#: value that every shift nearer zero gives).  Smaller problems, among them every committed report's,
#: keep the first shift, so their numbers stay as they were.
NEAR_SHIFT_MIN_N = 4000
NEAR_SHIFT = 1e-8


@dataclass
class Certificate:
    """What multipliers y prove about x̂.

    certified: bound ≤ tol·max(|f̂|, floor) (``rel_bound`` ≤ tol).  bound: f̂ − p* ≤ bound (absolute, in
    the cost's units); rel_bound = bound / max(|f̂|, floor).  lambda_min: λ_min(H) (estimate);
    lambda_lower: the certified lower bound on λ_min(H) used in the bound.  residual: ‖H Θ̂ᵀ‖_F /
    (‖Q Θ̂ᵀ‖_F + ‖H‖_max·‖Θ̂‖_F), the stationarity residual relative to the cost's own terms.
    primal_residual: max |⟨Aᵢ,X̂⟩ − bᵢ| (x̂'s infeasibility).  trace: the bound T on tr(X), None when the
    constraints imply none.  method: how y and λ_min were obtained.  recession: the number of recession
    columns J (module docstring), on which H must vanish; free_residual: max|H_{J,·}| / max|H|.
    argument: what proves the bound ("H ⪰ 0", "trace bound", "strict dual", or "" when nothing does);
    assumptions: what the argument assumed, in words; delta: the strict dual's δ (``strict_dual``);
    face: the columns set aside (H vanishes on them) and why, "" when none.
    """

    certified: bool
    bound: float
    rel_bound: float
    lambda_min: float
    lambda_lower: float
    residual: float
    primal_residual: float
    cost: float
    dual_value: float
    trace: float | None
    time_s: float
    method: str
    message: str = ""
    recession: int = 0
    free_residual: float = 0.0
    argument: str = ""
    assumptions: str = ""
    delta: float = 0.0
    face: str = ""

    def record(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def stack(constraints: Sequence[Constraint]) -> tuple[list[sp.coo_array], np.ndarray]:
    """The constraints' matrices as COO (memory ∝ nonzeros, no per-constraint CSR index array) and b."""
    return ([c.A if isinstance(c.A, sp.coo_array) else sp.coo_array(c.A) for c in constraints],
            np.array([c.b for c in constraints], dtype=float))


def entries(As: Sequence[sp.sparray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All entries of the Aᵢ in one pass: (row, col, value, i) arrays (``svec.stored_entries``)."""
    return stored_entries(As)


def dual_matrix(Q: sp.sparray, As: Sequence[sp.sparray], y: np.ndarray, *, stacked=None) -> sp.csc_array:
    """H = Q − Σ yᵢAᵢ, sparse (one sum over the stacked entries; ``stacked``: ``entries(As)`` when known)."""
    Q = sp.coo_array(Q)
    r, c, v, i = entries(As) if stacked is None else stacked
    H = sp.coo_array((np.concatenate([Q.data, -np.asarray(y, float)[i] * v]),
                      (np.concatenate([Q.row, r]), np.concatenate([Q.col, c]))), shape=Q.shape).tocsc()
    H.sum_duplicates()
    return H


def symmetric_ldl(H: sp.sparray, shift: float) -> SymmetricLDL:
    """LDLᵀ of H − shift·I without pivoting (``ldl.SymmetricLDL``); raises RuntimeError when a pivot is
    exactly zero."""
    n = H.shape[0]
    return SymmetricLDL(H - shift * sp.identity(n, format="csc"))


def negative_pivots(H: sp.sparray, shift: float) -> int | None:
    """Number of negative eigenvalues of H − shift·I, by Sylvester's law on a symmetric LDLᵀ
    (``symmetric_ldl``); None if the factorisation breaks down or a pivot is not finite."""
    try:
        D = symmetric_ldl(H, shift).pivots
    except RuntimeError:  # exactly singular
        return None
    if not np.all(np.isfinite(D)):
        return None
    return int(np.count_nonzero(D < 0))


def lambda_min(H: sp.sparray) -> tuple[float, float, str]:
    """(λ̂ ≈ λ_min(H), a lower bound on λ_min(H), method).  Dense below ``DENSE_MAX`` columns (the lower
    bound is λ̂ − n·ε·‖H‖); else shift-invert Lanczos near 0, then the lower bound λ̂ − δ is confirmed by
    an LDLᵀ without negative pivots (δ grows ×100 until it is; −inf when nothing is confirmed)."""
    n = H.shape[0]
    scale = float(abs(H).max()) if H.nnz else 0.0
    if scale == 0.0:
        return 0.0, 0.0, "zero"
    eps = np.finfo(float).eps * n * scale
    if n <= DENSE_MAX:
        lam = float(np.linalg.eigvalsh(H.toarray())[0])
        return lam, lam - eps, "dense"
    from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, eigsh

    method = "shift-invert Lanczos + LDLᵀ inertia"
    sigma, inverse = -1e-3 * scale, None
    if n >= NEAR_SHIFT_MIN_N:
        sigma = -NEAR_SHIFT * scale
        try:
            ldl = symmetric_ldl(H, sigma)
            if np.all(np.isfinite(ldl.pivots)):  # else: eigsh's own factorisation
                inverse = spla.LinearOperator((n, n), matvec=ldl.solve, dtype=float)
        except RuntimeError:  # exactly singular there: eigsh's own factorisation
            pass
    try:
        lam = float(eigsh(sp.csc_matrix(H), k=1, sigma=sigma, which="LM", v0=np.ones(n), OPinv=inverse,
                          return_eigenvectors=False, tol=1e-12, maxiter=min(10 * n, LANCZOS_MAXITER))[0])
    except (ArpackError, ArpackNoConvergence, RuntimeError):
        lam, method = 0.0, "LDLᵀ inertia"
    delta = max(eps, 1e-9 * abs(lam))
    searched = False
    while delta < 1e3 * scale:
        if negative_pivots(H, lam - delta) == 0:
            return lam, lam - delta, method
        if not searched:  # an eigenvalue below lam − delta: Lanczos found an interior one; look further down
            searched = True
            try:
                low = float(eigsh(sp.csc_matrix(H), k=1, which="SA", v0=np.ones(n), return_eigenvectors=False,
                                  tol=1e-10, maxiter=min(20 * n, 2 * LANCZOS_MAXITER))[0])
                lam = min(lam, low)
            except (ArpackError, ArpackNoConvergence):
                pass
        delta *= 100.0
    return lam, -np.inf, method + " (no lower bound confirmed)"


def trace_bound(Q: sp.sparray, As: Sequence[sp.sparray], b: np.ndarray, f_bar: float,
                max_passes: int = 8, columns: np.ndarray | None = None) -> float | None:
    """A bound on tr(X) over {X ⪰ 0 : ⟨Aᵢ,X⟩ = bᵢ, ⟨Q,X⟩ ≤ f_bar} (see the module docstring), or None
    when the constraints and the cost leave some column unbounded.  columns: bound only the trace over
    these columns (the others may stay unbounded)."""
    bound_of, groups = trace_groups(Q, As, b, f_bar, max_passes, columns)
    if (bound_of[slice(None) if columns is None else columns] >= 0).all():
        return float(sum(groups))
    return None


def trace_groups(Q: sp.sparray, As: Sequence[sp.sparray], b: np.ndarray, f_bar: float,
                 max_passes: int = 8, columns: np.ndarray | None = None,
                 cost_last: bool = False) -> tuple[np.ndarray, list[float]]:
    """(group of each column, −1 where none bounds it; each group's bound on tr X over its columns): the
    greedy of ``trace_bound`` (module docstring), which stops once every column of ``columns`` (default: all)
    is bounded or a pass bounds nothing more.  cost_last: each pass tries the constraints before the cost, so
    that exact relations (h² = 1, cᵢᵀcᵢ = 1) bound their columns alone, before the cost bounds them in one
    group with others (stereo-2D, N = 20: groups of 1 on h and each rotation column pair, instead of one of
    6e14 over every column the cost touches)."""
    n = Q.shape[0]
    bound_of = np.full(n, -1, dtype=np.int64)  # the group that bounds each column (−1: none yet)
    groups: list[float] = []
    # the items as given (COO: no N + 1 index array per constraint); CSR only for the few large ones below
    items = [(Q, f_bar, True)] + [(A, float(bi), False) for A, bi in zip(As, b)]
    dense = [_item_block(items[0][0])]  # per item: (support columns, the dense block on them or None)
    r, c, v, owner = entries(As)
    order = np.argsort(owner, kind="stable")
    cuts = np.searchsorted(owner[order], np.arange(len(As) + 1))
    for i in range(len(As)):
        sel = order[cuts[i]:cuts[i + 1]]
        dense.append(_item_block(None, r[sel], c[sel], v[sel]))
    if cost_last:
        items, dense = items[1:] + items[:1], dense[1:] + dense[:1]
    # per item, the free columns of its support when it was last found without a definite part: its part on
    # them is the same until one of them is bounded, so it is not decomposed again before that
    tried: list[np.ndarray | None] = [None] * len(items)
    for _ in range(max_passes):
        progress = False
        for k, ((A, rhs, is_cost), (sup, D)) in enumerate(zip(items, dense)):
            if sup.size == 0:
                continue
            free = bound_of[sup] < 0
            seen = tried[k]
            if not free.any() or (seen is not None and np.array_equal(seen, free)):
                continue
            U, B = sup[free], sup[~free]
            if D is not None:
                w = np.linalg.eigvalsh(D[np.ix_(free, free)])
                a = w[0] if is_cost else max(w[0], -w[-1])
            else:  # a large item (the cost): its definite part from its connected components
                A = sp.csr_array(A)
                Auu = sp.csr_array(A[U][:, U])
                a = _lambda_min_blocks(Auu)
                if not is_cost:
                    a = max(a, _lambda_min_blocks(-Auu))
            if not a > 0:
                tried[k] = free
                continue
            if D is not None:
                n_ub = float(np.linalg.norm(D[np.ix_(free, ~free)]))
                n_bb = float(np.linalg.norm(D[np.ix_(~free, ~free)]))
            else:
                n_ub, n_bb = float(sp.linalg.norm(A[U][:, B])) if B.size else 0.0, \
                    float(sp.linalg.norm(A[B][:, B])) if B.size else 0.0
            TB = float(sum(groups[g] for g in np.unique(bound_of[B]))) if B.size else 0.0
            beta = abs(rhs) + n_bb * TB
            alpha = n_ub * np.sqrt(TB)
            root = (alpha + np.sqrt(alpha ** 2 + a * beta)) / a
            groups.append(root ** 2)
            bound_of[U] = len(groups) - 1
            progress = True
        if (bound_of[slice(None) if columns is None else columns] >= 0).all() or not progress:
            break
    return bound_of, groups


def _item_block(A: sp.csr_array | None, r: np.ndarray | None = None, c: np.ndarray | None = None,
                v: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(support columns, the dense block of the item on them; None above 60 columns)."""
    if A is not None:
        A = sp.coo_array(A)
        r, c, v = A.row, A.col, A.data
    if r is None or c is None or v is None:
        raise ValueError("_item_block needs a matrix or its (r, c, v) triplets")
    sup = np.unique(np.concatenate([r, c]))
    if sup.size > 60:
        return sup, None
    D = np.zeros((sup.size, sup.size))
    np.add.at(D, (np.searchsorted(sup, r), np.searchsorted(sup, c)), v)
    return sup, D


def _lambda_min_blocks(A: sp.csr_array) -> float:
    """λ_min of a symmetric sparse matrix from its connected components (dense per component)."""
    from scipy.sparse.csgraph import connected_components

    k, lab = connected_components(A != 0, directed=False)
    sizes = np.bincount(lab, minlength=k)
    if sizes.max(initial=0) > 400:
        return -np.inf  # not worth it: no bound from this item
    # each column's position within its component, in column order; the components of one size are
    # gathered as a stack of dense blocks and decomposed at once
    order = np.argsort(lab, kind="stable")
    pos = np.empty(lab.size, dtype=np.int64)
    pos[order] = np.arange(lab.size) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    C = sp.coo_array(A)
    out = np.inf
    for s in np.unique(sizes):
        comps = np.flatnonzero(sizes == s)
        slot = np.full(k, -1, dtype=np.int64)
        slot[comps] = np.arange(comps.size)
        on = slot[lab[C.row]] >= 0  # an entry's two columns share a component
        B = np.zeros((comps.size, s, s))
        np.add.at(B, (slot[lab[C.row[on]]], pos[C.row[on]], pos[C.col[on]]), C.data[on])
        out = min(out, float(np.linalg.eigvalsh(B)[:, 0].min()))
    return out


def recession_columns(Q: sp.sparray, stacked: tuple[np.ndarray, ...]) -> np.ndarray:
    """Columns j with Q_jj = 0 and (Aᵢ)_jj = 0 for every i (``stacked`` = ``entries(As)``): zero-cost
    recession directions e_j e_jᵀ of the relaxation (module docstring), sorted."""
    Q = sp.coo_array(Q)
    r, c, v, _ = stacked
    diag = np.zeros(Q.shape[0], dtype=bool)
    diag[Q.row[(Q.row == Q.col) & (Q.data != 0)]] = True
    diag[r[(r == c) & (v != 0)]] = True
    return np.flatnonzero(~diag)


def stationarity_system(Q: sp.sparray, As: Sequence[sp.sparray], Th: np.ndarray,
                        free: np.ndarray | None = None) -> tuple[sp.csr_array, np.ndarray]:
    """(G, g) with G y = g ⟺ H(y)Θ̂ᵀ = 0 and H(y)_{J,·} = 0 on the columns J set aside (default: the
    recession columns; ``free``: J given, e.g. a face of ``autotight.face``).  The first N·d rows
    (row-major): column i of G is vec(AᵢΘ̂ᵀ); then one row per entry (j, k), j ∈ J, of some Aᵢ or Q."""
    d, N = Th.shape
    stacked = r, c, v, owner = entries(As)
    rows = (r[:, None] * d + np.arange(d)[None, :]).ravel()
    vals = (v[:, None] * Th[:, c].T).ravel()
    cols = np.repeat(owner, d)
    g = np.asarray(sp.csr_array(Q) @ Th.T).ravel()
    n_rows = N * d
    J = recession_columns(Q, stacked) if free is None else np.asarray(free, dtype=np.int64)
    if J.size:  # one more row per entry (j, k), j ∈ J: (Σ yᵢAᵢ)_jk = Q_jk
        Qc = sp.coo_array(Q)
        on_J, q_on_J = np.isin(r, J), np.isin(Qc.row, J)
        keys = np.concatenate([r[on_J] * N + c[on_J], Qc.row[q_on_J] * N + Qc.col[q_on_J]])
        uniq, inv = np.unique(keys, return_inverse=True)
        n_on = int(on_J.sum())
        rows = np.concatenate([rows, n_rows + inv[:n_on]])
        vals = np.concatenate([vals, v[on_J]])
        cols = np.concatenate([cols, owner[on_J]])
        gJ = np.zeros(uniq.size)
        np.add.at(gJ, inv[n_on:], Qc.data[q_on_J])
        g = np.concatenate([g, gJ])
        n_rows += uniq.size
    return sp.csr_array((vals, (rows, cols)), shape=(n_rows, len(As))), g


def polish_dual(Q: sp.sparray, As: Sequence[sp.sparray], y: np.ndarray, theta_hat: np.ndarray,
                free: np.ndarray | None = None,
                system: tuple[sp.csr_array, np.ndarray] | None = None, equilibrate: bool = False) -> np.ndarray:
    """y + δ, δ the least change (2-norm) that makes H(y + δ)Θ̂ᵀ = 0 (and H's rows on recession columns
    zero, ``stationarity_system``): the minimum-norm least-squares solution of G δ = g − G y
    (``lstsq.min_norm_lstsq``).  Θ̂: (d, N).  Where x̂ is stationary only to the local solver's
    accuracy, the system is consistent only to that accuracy, and so is H(y + δ)Θ̂ᵀ = 0.  Then
    bᵀ(y + δ) = f(x̂) − ⟨H, Θ̂ᵀΘ̂⟩ ≈ f(x̂), up to that and x̂'s constraint residual; whether y + δ
    proves anything is λ_min's to say.  The rows on recession columns, which must hold exactly (to
    roundoff) for a certificate, get a second least-change step of their own.  ``free``: the columns
    set aside instead of the recession columns (``stationarity_system``).  system: (G, g) of
    ``stationarity_system(Q, As, Θ̂, free)`` when the caller has it (its rows may be weighted).
    equilibrate: the least change in the metric of G's column norms (``lstsq.equilibrated_lstsq``)
    instead of the 2-norm, for a y that starts far from stationarity on a badly scaled G."""
    from .lstsq import equilibrated_lstsq

    lstsq = equilibrated_lstsq if equilibrate else min_norm_lstsq
    Th = np.atleast_2d(np.asarray(theta_hat, dtype=float))
    G, g = stationarity_system(Q, As, Th, free) if system is None else system
    y = np.asarray(y, dtype=float)
    y = y + lstsq(G, g - G @ y)
    n_stat = Th.size
    if G.shape[0] > n_stat:
        GJ, gJ = G[n_stat:], g[n_stat:]
        y = y + lstsq(GJ, gJ - GJ @ y, atol=1e-16)
    return y


def tolerance_scale(f_hat: float, q_max: float, trace_hat: float, floor: float) -> float:
    """What ``tol`` is relative to: max(|f̂|, floor·max|Q|·tr X̂) (``floor`` states the absolute tolerance of a
    zero-cost candidate relative to the cost's scale)."""
    return max(abs(f_hat), floor * q_max * trace_hat)


def certificate(Q: sp.sparray, constraints: Sequence[Constraint], y: np.ndarray, theta_hat: np.ndarray, *,
                d: int = 1, tol: float = 1e-6, floor: float = 1e-12, trace: float | None = None,
                method: str = "given y", free: np.ndarray | None = None,
                estimate_lambda: bool | None = None) -> Certificate:
    """What y proves about x̂ (Θ̂ = ``theta_hat``, (N,) or (d, N)): the bound of the module docstring.

    certified when the bound is finite and ≤ tol·max(|f̂|, floor·‖Q‖_max·tr X̂) (``floor`` states the
    absolute tolerance of a zero-cost candidate relative to the cost's scale).  ``trace``: a known
    bound on tr(X) (default: ``trace_bound``).  ``free``: columns to set aside besides the recession
    columns (a face, ``autotight.face``); H must vanish on their rows too, to ``FREE_ATOL``·max|H|.
    estimate_lambda: False tries the strict dual before estimating λ_min(H) (None, the default: False from
    ``NEAR_SHIFT_MIN_N`` columns on, where the estimate is a Lanczos run of seconds); when it proves
    H + (δ/d)·E_h ⪰ 0, λ_min is not estimated (a Lanczos run: 7 s at discrete K = 10 000) and both
    ``lambda_min`` and ``lambda_lower`` are its bound −(δ/d)·λ_max(E_h) (Weyl).  The verdict is the
    same either way: the strict dual is what proves the bound there.
    """
    t0 = time.perf_counter()
    As, b = stack(constraints)
    Q = sp.csr_array(Q)
    if estimate_lambda is None:
        estimate_lambda = Q.shape[0] < NEAR_SHIFT_MIN_N
    Th = np.asarray(theta_hat, dtype=float).reshape(d, -1)
    y = np.asarray(y, dtype=float)
    r, c, v, owner = stacked = entries(As)
    H = dual_matrix(Q, As, y, stacked=stacked)
    HT = H @ Th.T
    QT = Q @ Th.T
    Xhat_tr = float(np.sum(Th * Th))
    f_hat = float(np.sum(Th.T * QT))
    res_A = np.bincount(owner, weights=v * np.sum(Th[:, r] * Th[:, c], axis=0), minlength=len(As)) - b
    scale = float(abs(Q).max()) if Q.nnz else 1.0
    residual = float(np.linalg.norm(HT) / (np.linalg.norm(QT) + float(abs(H).max()) * np.sqrt(Xhat_tr) + 1e-300))
    J = recession_columns(Q, stacked)
    n_recession = J.size
    if free is not None:
        J = np.union1d(J, np.asarray(free, dtype=np.int64))
    free_res = 0.0
    where = ""
    if J.size:
        K = np.setdiff1d(np.arange(H.shape[0]), J)
        HJ = H[:, J]
        Hmax = float(abs(H).max()) if H.nnz else 1.0
        free_res = float(abs(HJ).max()) / Hmax if HJ.nnz else 0.0
        where = f" on the {K.size} columns off the {J.size} {'recession ' if J.size == n_recession else ''}columns"
        where += "" if J.size == n_recession else " set aside"
    else:
        K = None

    def estimated() -> tuple[float, float, str]:
        lam, lam_lo, how = lambda_min(H if K is None else sp.csc_array(H[K][:, K]))
        return lam, lam_lo, how + where

    E = homogenising_matrix(constraints)
    lam, lam_lo, how = estimated() if estimate_lambda or E is None else (np.nan, np.nan, "")
    T = trace
    neg = max(-lam_lo, 0.0) if np.isfinite(lam_lo) else np.nan
    msg, argument, delta, correction = "", "", 0.0, np.inf
    roundoff = "the LDLᵀ factorisation's roundoff (λ_min's lower bound)"
    assumptions = roundoff
    dual_value = float(b @ y)
    excess = float(np.sum(Th.T * HT) + y @ res_A)  # f(x̂) − bᵀy (exact identity)
    denom = tolerance_scale(f_hat, scale, Xhat_tr, floor)
    budget = tol * denom - excess  # the largest correction that can still certify
    f_bar = 2 * abs(f_hat) + floor * scale * Xhat_tr  # ≥ p*: the sublevel set the trace bounds hold on
    if free_res > FREE_ATOL:
        msg = (f"H does not vanish on the {J.size} {'recession ' if J.size == n_recession else ''}columns set aside "
               f"(max |H_J·| = {free_res:.1e} of max |H|)")
    elif neg == 0.0:
        correction, argument = 0.0, "H ⪰ 0"
    else:
        if budget > 0 and E is not None:  # the strict dual first: no trace bound needed
            from .strict_dual import bounded_shift, strict_dual

            Hk, Ek, Thk = (H, E, Th) if K is None else (H[K][:, K], sp.csc_array(E)[K][:, K], Th[:, K])
            sd = strict_dual(Hk, Ek, Thk, delta_max=budget)
            if not sd.ok:  # other null directions than Θ̂'s: lift tightly bounded columns too
                group_of, groups = trace_groups(Q, As, b, f_bar, columns=K, cost_last=True)
                bs = bounded_shift(Hk, group_of if K is None else group_of[K], groups, Thk, loss_max=budget)
                if bs.ok:
                    correction, delta, argument = bs.loss, bs.delta, "bounded shift"
                    assumptions = (f"LDLᵀ inertia of H + δ·E_S in the Jacobi frame with margin {bs.margin:.1e} "
                                   f"(smallest pivot {bs.min_pivot:.1e}, {bs.tries} factorisation(s)), S the "
                                   f"{bs.columns.size} column(s) of trace groups with tr X_SS ≤ {bs.trace:.3e} on "
                                   "the sublevel set of 2|f(x̂)|")
                    if not np.isfinite(lam_lo):  # Weyl: λ_min(H) ≥ −δ·λ_max(E_S) = −δ
                        lam = lam_lo = -bs.delta
                        how = "not estimated: H + δ·E_S ⪰ 0 (bounded shift) bounds it" + where
                else:
                    msg = f"strict dual: {sd.message}; bounded shift: {bs.message}"
            if sd.ok:
                correction, delta = sd.delta, sd.delta
                argument = "strict dual" if sd.delta > 0 else "H ⪰ 0 (LDLᵀ inertia)"
                assumptions = (f"LDLᵀ inertia of H + δ·E_h in the Jacobi frame with margin {sd.margin:.1e} "
                               f"(smallest pivot {sd.min_pivot:.1e}, {sd.tries} factorisation(s)): exact up to "
                               "roundoff of that size; no trace bound")
                if not np.isfinite(lam_lo):  # not estimated: the bound that H + (δ/d)·E_h ⪰ 0 gives
                    on = np.unique(sp.coo_array(E).row)  # E_h lives on the h block (d × d)
                    e_max = float(np.linalg.eigvalsh(sp.csr_array(E)[on][:, on].toarray())[-1]) if on.size else 0.0
                    lam = lam_lo = -(sd.delta / d) * max(e_max, 0.0) if sd.delta > 0 else 0.0
                    how = "not estimated: H + (δ/d)·E_h ⪰ 0 (strict dual) bounds it" + where
        if not np.isfinite(lam_lo):  # the strict dual proved nothing: λ_min after all
            lam, lam_lo, how = estimated()
            neg = max(-lam_lo, 0.0)
            if neg == 0.0:
                correction, argument, msg = 0.0, "H ⪰ 0", ""
        if not np.isfinite(correction):  # the trace bound, where the strict dual proved nothing
            if T is None:
                T = trace_bound(Q, As, b, f_bar, columns=K)
            if T is None:
                msg = "; ".join(filter(None, ["λ_min(H) < 0 and no trace bound follows from the constraints", msg]))
            else:
                correction, argument = neg * T, "trace bound"
                assumptions = f"{roundoff}; tr X ≤ {T:.3e} on the sublevel set of 2|f(x̂)|"
                msg = "" if excess + correction <= tol * denom else msg
    if not np.isfinite(lam_lo):  # nothing above needed it (H not vanishing where it must): for the record
        lam, lam_lo, how = estimated()
    bound = excess + correction
    rel = bound / denom if denom > 0 else (0.0 if bound <= 0 else np.inf)
    ok = bool(np.isfinite(bound) and rel <= tol)
    infeasible = relative_violations(constraints, [Th])[0] if len(constraints) else np.zeros(0)
    if infeasible.size and infeasible.max() > VALID_RTOL:  # p* then bounds nothing x̂ is a point of
        i = int(np.argmax(infeasible))
        ok, msg = False, "; ".join(filter(None, [msg, (
            f"x̂ violates constraint {constraints[i].name or i} by {infeasible[i]:.1e} relative (> "
            f"{VALID_RTOL:.0e}): it is not a point of this relaxation, so the bound says nothing about it "
            "(a constraint of the set that does not hold on the problem's feasible points?)")]))
    face = ""
    if J.size:
        face = (f"{J.size} column(s) set aside: neither the cost nor any constraint has a diagonal entry on them "
                f"(X can grow there at no cost); H vanishes on them to {free_res:.1e} of max |H|")
        assumptions += "; H vanishes on the columns set aside"
    return Certificate(ok, bound, float(rel), lam, lam_lo, residual, float(np.max(np.abs(res_A), initial=0.0)),
                       f_hat, dual_value, T, time.perf_counter() - t0, f"{method}; λ_min: {how}", msg,
                       int(J.size), free_res, argument if np.isfinite(bound) else "", assumptions, delta, face)


def homogenising_matrix(constraints: Sequence[Constraint]) -> sp.csc_array | None:
    """E_h = Σ Aᵢ over the constraints (X_hh)_ii = 1 (family "homogenisation", b = 1), None if there are
    none: lowering each of their d multipliers by δ/d adds (δ/d)·E_h to H and lowers bᵀy by δ."""
    rows = [c.A for c in constraints if c.family == "homogenisation" and c.b == 1.0]
    if not rows:
        return None
    return sp.csc_array(sum(sp.csc_array(A) for A in rows))
