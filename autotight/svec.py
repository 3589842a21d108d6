"""The one place that fixes the svec convention.

svec(X) of a symmetric n×n matrix X stacks its upper triangle column by column,
(0,0), (0,1), (1,1), (0,2), (1,2), (2,2), …, with the off-diagonal entries multiplied
by √2.  This is exactly the layout of Clarabel's ``PSDTriangleConeT(n)``, and it makes
svec an isometry: ⟨A, X⟩ = tr(AX) = svec(A) · svec(X).  ``smat`` is its inverse.

A monomial vector m(x) lists the products x_i x_j (i ≤ j) in the same order *without*
the √2, so a coefficient vector p with p · m(x) = 0 reads directly as a polynomial.
``poly_to_sym`` turns such coefficients into the symmetric A with xᵀAx = p · m(x).
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from functools import lru_cache
from typing import Iterator, Sequence

import numpy as np
import scipy.sparse as sp

SQRT2 = np.sqrt(2.0)


def svec_dim(n: int) -> int:
    """Length n(n+1)/2 of svec for an n×n matrix."""
    return n * (n + 1) // 2


@lru_cache(maxsize=64)
def triu_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices (i ≤ j) of the svec order, column-major upper triangle."""
    jj, ii = np.tril_indices(n)  # row-major lower (j, i) == column-major upper (i, j)
    return ii.astype(np.int64), jj.astype(np.int64)


def position_to_ij(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column (i ≤ j) of svec positions: the inverse of pos = j(j+1)/2 + i."""
    pos = np.asarray(pos, dtype=np.int64)
    j = ((np.sqrt(8 * pos + 1) - 1) // 2).astype(np.int64)
    j -= (j * (j + 1) // 2 > pos)  # guard the float square root
    return pos - j * (j + 1) // 2, j


def _scale(n: int) -> np.ndarray:
    i, j = triu_indices(n)
    return np.where(i == j, 1.0, SQRT2)


def svec(X: np.ndarray | sp.spmatrix) -> np.ndarray:
    """svec of a symmetric n×n matrix (dense or sparse) → (n(n+1)/2,)."""
    n = X.shape[0]
    i, j = triu_indices(n)
    if sp.issparse(X):
        vals = np.asarray(sp.csr_array(X)[i, j]).ravel()
    else:
        vals = np.asarray(X)[i, j]
    return vals * _scale(n)


def triu_entries(A: sp.spmatrix | sp.sparray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, values) of the stored upper-triangle entries (i ≤ j) of a sparse matrix."""
    if isinstance(A, (sp.coo_array, sp.coo_matrix)):  # no CSR (its index array has n + 1 entries)
        r, c = A.row.astype(np.int64), A.col.astype(np.int64)
        keep = r <= c
        return r[keep], c[keep], A.data[keep]
    A = A if isinstance(A, (sp.csr_array, sp.csr_matrix)) else sp.csr_array(A)
    r = np.repeat(np.arange(A.shape[0], dtype=np.int64), np.diff(A.indptr))
    c = A.indices.astype(np.int64)
    keep = r <= c
    return r[keep], c[keep], A.data[keep]


Entries = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: within ``reusing_entries``: {ids of the matrices: (the matrices, their ``stored_entries``)}
_REUSED: ContextVar[dict[tuple[int, ...], tuple[list, Entries]] | None] = ContextVar("reused_entries", default=None)


@contextmanager
def reusing_entries() -> Iterator[None]:
    """Within this block, ``stored_entries`` of the same matrices (the same objects, in the same order) is
    computed once and returned read-only.  The matrices must not change in place meanwhile.  Nested blocks
    share the outermost one's results; they are dropped when it ends."""
    token = _REUSED.set({}) if _REUSED.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _REUSED.reset(token)


def stored_entries(As: Sequence[sp.spmatrix | sp.sparray]) -> Entries:
    """Every stored entry of the matrices in one pass: (row, col, value, i) arrays, i the matrix holding the
    entry.  COO and CSR as they are (no N + 1 index array per COO matrix); other formats through COO.
    Inside ``reusing_entries``, the arrays are shared between calls and read-only."""
    if not len(As):
        z = np.zeros(0, dtype=np.int64)
        return z, z, np.zeros(0), z
    reused = _REUSED.get()
    if reused is None:
        return _stored_entries(As)
    key = tuple(map(id, As))  # the cache holds the matrices: their ids are not reused while it lives
    hit = reused.get(key)
    if hit is None:
        out = _stored_entries(As)
        for a in out:
            a.flags.writeable = False
        hit = reused[key] = (list(As), out)
    return hit[1]


def _stored_entries(As: Sequence[sp.spmatrix | sp.sparray]) -> Entries:
    rows, cols, vals, counts = [], [], [], []
    for A in As:
        if type(A) is sp.coo_array:  # the common case first: ``coords`` without the ``row``/``col`` properties
            r, c = A.coords
        elif isinstance(A, (sp.csr_array, sp.csr_matrix)):
            r, c = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr)), A.indices
        else:
            A = A if isinstance(A, (sp.coo_array, sp.coo_matrix)) else sp.coo_array(A)
            r, c = A.row, A.col
        rows.append(r)
        cols.append(c)
        vals.append(A.data)
        counts.append(A.data.size)
    owner = np.repeat(np.arange(len(As)), counts)  # one call, not one array per matrix
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals).astype(float), owner


def prepended_entries(A: sp.spmatrix | sp.sparray, As: Sequence[sp.spmatrix | sp.sparray]) -> Entries:
    """``stored_entries([A, *As])``, with the entries of ``As`` read through ``stored_entries(As)`` (shared
    within ``reusing_entries``)."""
    r0, c0, v0, _ = _stored_entries([A])
    r, c, v, k = stored_entries(As)
    return (np.concatenate([r0, r]), np.concatenate([c0, c]), np.concatenate([v0, v]),
            np.concatenate([np.zeros(v0.size, dtype=k.dtype), k + 1]))


def svec_columns(As: Sequence[sp.spmatrix | sp.sparray], n: int, entries: Entries | None = None) -> sp.csc_array:
    """[svec A₁ … svec A_m] of sparse symmetric n×n matrices as one sparse (n(n+1)/2 × m) array,
    assembled in one pass from their upper triangles (no dense n×n).  entries: ``stored_entries(As)``
    when known."""
    r, c, v, k = stored_entries(As) if entries is None else entries
    r, c = r.astype(np.int64), c.astype(np.int64)  # c(c + 1)/2 overflows int32 from n ≈ 46 000
    keep = r <= c
    r, c, v, k = r[keep], c[keep], v[keep], k[keep]
    return sp.csc_array((v * np.where(r == c, 1.0, SQRT2), (c * (c + 1) // 2 + r, k)), shape=(svec_dim(n), len(As)))


def svec_sparse(A: sp.spmatrix | sp.sparray) -> sp.csc_array:
    """svec of one sparse symmetric matrix as an (n(n+1)/2, 1) sparse column."""
    return svec_columns([A], A.shape[0])


def smat(v: np.ndarray, n: int | None = None) -> np.ndarray:
    """Inverse of svec: (n(n+1)/2,) → symmetric n×n."""
    v = np.asarray(v, dtype=float)
    if n is None:
        n = int(round((np.sqrt(8 * v.size + 1) - 1) / 2))
    if svec_dim(n) != v.size:
        raise ValueError(f"svec length {v.size} is not n(n+1)/2 for any n")
    i, j = triu_indices(n)
    X = np.zeros((n, n))
    vals = v / _scale(n)
    X[i, j] = vals
    X[j, i] = vals
    return X


def as_theta(x: np.ndarray) -> np.ndarray:
    """A lifted point as a (d, N) array: a vector x (N,) becomes (1, N)."""
    T = np.asarray(x, dtype=float)
    if T.ndim == 1:
        return T[None, :]
    if T.ndim != 2:
        raise ValueError(f"a lifted point must be (N,) or (d, N), got shape {T.shape}")
    return T


def monomials(Thetas: np.ndarray) -> np.ndarray:
    """Monomials of a batch of liftings.

    Thetas: (S, d, N).  Returns the entries of ΘᵀΘ in svec order *without* √2,
    shape (S, N(N+1)/2).  For d = 1 these are the products x_i x_j.
    """
    T = np.asarray(Thetas, dtype=float)
    if T.ndim != 3:
        raise ValueError(f"expected a batch (S, d, N), got shape {T.shape}")
    i, j = triu_indices(T.shape[-1])
    return np.einsum("sdk,sdk->sk", T[:, :, i], T[:, :, j])


def poly_to_sym(p: np.ndarray, n: int) -> sp.csr_array:
    """Monomial coefficients p (svec order, no √2) → sparse symmetric A with ⟨A, ΘᵀΘ⟩ = p·m."""
    p = np.asarray(p, dtype=float)
    i, j = triu_indices(n)
    nz = np.flatnonzero(p)
    ii, jj, pp = i[nz], j[nz], p[nz]
    off = ii != jj
    rows = np.concatenate([ii, jj[off]])
    cols = np.concatenate([jj, ii[off]])
    vals = np.concatenate([np.where(off, pp / 2.0, pp), pp[off] / 2.0])
    return sp.csr_array((vals, (rows, cols)), shape=(n, n))


def polys_to_syms(P: np.ndarray, n: int) -> np.ndarray:
    """``poly_to_sym`` for a batch, dense: coefficient vectors P (…, n(n+1)/2) → symmetric (…, n, n)."""
    i, j = triu_indices(n)
    S = np.zeros((*P.shape[:-1], n, n))
    S[..., i, j] = np.where(i != j, P / 2.0, P)
    S[..., j, i] = S[..., i, j]
    return S


def sym_to_poly(A: sp.spmatrix | sp.sparray | np.ndarray) -> np.ndarray:
    """Inverse of ``poly_to_sym``: symmetric A → monomial coefficients (dense, n(n+1)/2); a dense batch
    (…, n, n) → (…, n(n+1)/2)."""
    n = A.shape[-1]
    i, j = triu_indices(n)
    vals = np.asarray(sp.csr_array(A)[i, j]).ravel() if sp.issparse(A) else np.asarray(A)[..., i, j]
    return np.where(i == j, vals, 2.0 * vals)
