"""Multipliers for long chains by Douglas–Rachford splitting on the clique form (no Newton matrix).

Setting (``autotight.certifier``, step 1).  On the clique program of the data, w = (y, t) gives the
blocks S_k(w) = C_k − F_k w; x̂ (Θ̂, d × N) is certified by any w with S_k Θ̂_kᵀ = 0 (linear equalities
L w = l) and S_k ⪰ 0 for every clique k.  With U_k an orthonormal basis of Θ̂_k's rows and α = 1 (the
cost scaled to max|C| = 1), S̃_k = S_k + α U_kU_kᵀ is positive definite iff S_k ⪰ 0 with null space
exactly span U_k, on {L w = l}.

Method (``project_multipliers``): find a point of A ∩ C_μ, A = {s(w) = (S̃_k(w))_k : L w = l} (affine)
and C_μ = {S̃_k ⪰ μI for every k} (the cone shifted inwards), in the Frobenius metric of the stacked
blocks, by Douglas–Rachford: z ← z + P_A(2 P_C(z) − z) − P_C(z), with the projections

- P_C: each block's eigenvalues below μ are raised to μ (a batched eigendecomposition);
- P_A: w = argmin ‖S̃(w) − Z‖² + β‖D(Lw − l)‖² + ε‖w‖², one solve with the fixed matrix
  FᵀF + β LᵀD²L + εI (D: L's inverse row norms; β = ``PENALTY`` × FᵀF's mean diagonal, ε =
  ``RIDGE`` × the same), factored once by a symmetric sparse LU (its pattern couples the variables of
  neighbouring cliques only: linear on a chain), with one refinement step.

The point s(w) of A (to the penalty's accuracy) is tested every round; it stops "feasible" as soon as
every S̃_k(w) is positive definite, "stalled" when the smallest eigenvalue has not risen by
``PROGRESS`` in ``PATIENCE`` rounds, or after ``max_iter`` rounds.  Two choices matter (discrete
trajectory, the set learned at K = 5): μ well inside the cone pushes the iterates into the interior
(plain alternating projections at K = 100: 16 rounds with μ = 0.03, 37 with μ = 0.01, over 150 with
μ = 0.002), and Douglas–Rachford, unlike alternating projections, does not stall on the chain's ends
(at K = 1000, μ = 0.03: feasible in 22 rounds, where alternating projections still had 280 of 1000
blocks outside the cone after 60).  Rounds at K = 1000, seed 0 (seed 1): μ = 0.03: 22, μ = 0.06: 14,
μ = 0.1: 11 (9), μ = 0.2: (7), μ = 0.3: 6, μ = 0.4: (5), μ = 1: stalled at a margin of −0.1.  So
``CLIPS`` tries μ = 0.3 first and 0.03 where that does not end feasible.  Each round costs
one sparse solve and the small eigenproblems, so a round is linear in the number of cliques.

Soundness: the rounds only propose w; ``certifier.certify`` polishes its y onto stationarity and hands
it to the exact certificate (``autotight.certificate``: LDLᵀ inertia, strict dual), which decides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

#: μ of the cone C_μ the blocks are projected onto (scaled cost: max|C_ij| = 1), the next where one does not end
#: "feasible" (module docstring)
CLIPS = (0.3, 0.03)
#: weight of the stationarity penalty and of the ridge, relative to FᵀF's mean diagonal
PENALTY = 1e6
RIDGE = 1e-10
#: stop when the smallest eigenvalue has not risen by PROGRESS (absolute, scaled cost) in PATIENCE rounds
PROGRESS = 1e-6
PATIENCE = 20
MAX_ITER = 100


@dataclass
class Projection:
    """Outcome of ``project_multipliers``: w (scaled y, then t), the smallest eigenvalue of the S̃_k at w
    (``margin``, scaled cost), why it stopped ("feasible" | "stalled" | "max_iter" | "breakdown: …"),
    the rounds taken and the stationarity residual ‖D(Lw − l)‖ (relative rows)."""

    w: np.ndarray
    margin: float
    status: str
    iterations: int
    stationarity: float


def stationarity_rows(prog, Th: np.ndarray, blocks, Gv: sp.csr_array, cv: np.ndarray
                      ) -> tuple[sp.csr_array, np.ndarray, np.ndarray]:
    """(L, l, UU): S_k(w) Θ̂_kᵀ = 0 for every clique as L w = l (rows scaled to unit norm; vec row-major
    blocks, ``schur_ipm._Blocks``), and vec(U_kU_kᵀ) stacked (U_k: orthonormal basis of Θ̂_k's rows).
    Gv, cv: the program's F and c on those vec blocks (S(w) = cv − Gv w)."""
    d = Th.shape[0]
    UU = np.zeros(blocks.voff[-1])
    sizes = np.asarray(prog.sizes, dtype=np.int64)
    # Kb in CSR, row (k, i, a) of vec(S U) holding U_k[j, a] at vec(S) entry (i, j), j = 0 … n_k − 1 (sorted):
    # block k's rows and entries follow the earlier blocks'
    indptr = np.concatenate([[0], np.cumsum(np.repeat(sizes, d * sizes))])
    indices = np.empty(d * blocks.voff[-1], dtype=np.int64)
    data = np.empty(d * blocks.voff[-1])
    for n, ids, idx in blocks.groups:  # per size n: vec(S) (row-major) → vec(S U) (n × d, row-major), batched
        C = np.stack([prog.cliques[k] for k in ids])  # (B, n)
        U = np.linalg.qr(np.swapaxes(Th[:, C], 0, 1).transpose(0, 2, 1))[0]  # (B, n, d), orthonormal columns
        UU[idx.ravel()] = (U @ np.swapaxes(U, -1, -2)).reshape(-1)
        i, a, j = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(d), np.arange(n), indexing="ij"))
        at = d * blocks.voff[ids][:, None] + ((i * d + a) * n + j)[None, :]
        indices[at] = blocks.voff[ids][:, None] + (i * n + j)[None, :]
        data[at] = U[:, j, a]
    Kb = sp.csr_array((data, indices, indptr), shape=(d * int(sizes.sum()), blocks.voff[-1]))
    L = sp.csr_array(Kb @ Gv)
    lv = Kb @ cv
    nr = np.sqrt(np.asarray(L.multiply(L).sum(axis=1)).ravel())
    inv = np.where(nr > 0, 1.0 / np.where(nr > 0, nr, 1.0), 0.0)
    return sp.csr_array(sp.diags_array(inv) @ L), inv * lv, UU


def _row_stack(G: sp.csr_array, H: sp.csr_array, ridge: float) -> sp.csr_array:
    """[G; H; ridge·I] (I: the identity of G's columns; G, H without duplicate entries) as canonical CSR (each
    row's columns sorted, explicit zeros kept): the arrays of ``sp.vstack([G, H, ridge·I], format="csr")``, by
    concatenating the rows instead of passing through COO."""
    M = G.shape[1]
    G, H = G.sorted_indices(), H.sorted_indices()
    indptr = np.concatenate([G.indptr, G.nnz + H.indptr[1:], G.nnz + H.nnz + np.arange(1, M + 1)])
    indices = np.concatenate([G.indices, H.indices, np.arange(M)])
    data = np.concatenate([G.data, H.data, np.full(M, ridge)])
    return sp.csr_array((data, indices, indptr), shape=(G.shape[0] + H.shape[0] + M, M))


def project_multipliers(prog, Th: np.ndarray, *, clips: tuple[float, ...] = CLIPS, alpha: float = 1.0,
                        max_iter: int = MAX_ITER) -> Projection:
    """Douglas–Rachford (module docstring) on the clique program ``prog`` for Θ̂ (d × N), with μ = each of
    ``clips`` in turn until one ends "feasible" (each from the least-squares start; the best margin is
    returned, ``iterations`` counts all rounds)."""
    from .sdp.schur_ipm import _Blocks, svec_to_vec

    blocks = _Blocks(prog.sizes)
    P = svec_to_vec(prog.sizes)
    Gv = sp.csr_array(P @ prog.F)
    base = P @ prog.c
    DL, dl, UU = stationarity_rows(prog, Th, blocks, Gv, base)
    base = base + alpha * UU
    M = Gv.shape[1]
    GvT = Gv.T  # CSC view: the same sums in the same order as a CSR copy, without the copy
    scale = float(np.mean(np.asarray(Gv.multiply(Gv).sum(axis=0)))) or 1.0  # the mean diagonal of GvᵀGv
    # N = GvᵀGv + β LᵀD²L + ridge·I as BᵀB of one stack B = [Gv; √β DL; √ridge I]: one sparse product and
    # no sum of large sparse matrices
    B = _row_stack(Gv, DL * np.sqrt(PENALTY * scale), np.sqrt(RIDGE * scale))
    N = sp.csc_matrix(B.T @ B)
    del B  # the factorisation below is the peak of memory: B is not needed there
    try:
        lu = spla.splu(N, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    except RuntimeError as e:
        return Projection(np.zeros(M), -np.inf, f"breakdown: {e}", 0, np.inf)
    pen = (PENALTY * scale) * (DL.T @ dl)

    def onto_affine(Z: np.ndarray) -> np.ndarray:
        rhs = GvT @ (base - Z) + pen
        w = lu.solve(rhs)
        return w + lu.solve(rhs - N @ w)

    w0 = onto_affine(np.zeros_like(base))  # the least-squares fit S̃(w) ≈ 0 on {L w = l}: the first round
    best: tuple[np.ndarray, float, str] = (w0, -np.inf, "no μ given")
    total = 0
    for mu in clips:
        w, margin, status, rounds = _douglas_rachford(w0, mu, max_iter, Gv, base, blocks, onto_affine)
        total += rounds
        if margin > best[1]:
            best = (w, margin, f"{status} at μ = {mu:g}")
        if status == "feasible":
            break
    w, margin, status = best
    return Projection(w, margin, status, total, float(np.linalg.norm(DL @ w - dl)))


def _douglas_rachford(w: np.ndarray, clip: float, max_iter: int, Gv, base: np.ndarray, blocks,
                      onto_affine) -> tuple[np.ndarray, float, str, int]:
    """The rounds of the module docstring with μ = ``clip`` from w: (w, margin, status, rounds)."""

    def onto_cone(Z: np.ndarray) -> np.ndarray:
        out = blocks.split(Z)
        for g, Sg in enumerate(out):  # the blocks whose eigenvalues are all ≥ μ stay as they are
            ev, V = np.linalg.eigh(Sg)
            bad = ev[:, 0] < clip
            out[g][bad] = (V[bad] * np.maximum(ev[bad], clip)[:, None, :]) @ np.swapaxes(V[bad], -1, -2)
        return blocks.join(out)

    s = base - Gv @ w  # S̃(w), the point of A at w
    z = s
    best, last_gain, margin, status, it = -np.inf, 0, -np.inf, "max_iter", 0
    for it in range(1, max_iter + 1):
        lows = [np.linalg.eigvalsh(Sg)[:, 0] for Sg in blocks.split(s)]
        margin = min(float(low.min()) for low in lows)
        if not np.isfinite(margin):
            status = "breakdown: a block is not finite"
            break
        if margin > 0:
            status = "feasible"
            break
        if margin > best + PROGRESS:
            best, last_gain = margin, it
        elif it - last_gain >= PATIENCE:
            status = "stalled"
            break
        c = onto_cone(z)  # Douglas–Rachford: z ← z + P_A(2 P_C(z) − z) − P_C(z)
        w = onto_affine(2 * c - z)
        s = base - Gv @ w
        z = z + s - c
    return w, margin, status, it
