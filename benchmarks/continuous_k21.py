"""Continuous-time trajectory at the paper's K = 21 (issue 18): SDP paths side by side, and the
prototype of the fastest one (``solve_fast``) that reports/continuous_boundary also uses.

Every path solves the same optimum (problems/continuous_trajectory.py, module docstring):
- ``marginalised``: ϖ removed by the Schur complement (the paper), Clarabel's chordal decomposition;
- ``kept-clarabel``: ϖ kept, Clarabel on our clique cover (``solve --decompose``, 9–10 s in issue 18);
- ``kept-ipm``: ϖ kept, our IPM on its own cover;
- ``kept-ipm-scaled``: as kept-ipm, after the block congruence X = D X′ D of ``block_scale``;
- ``kept-ipm-scaled-indep``: as kept-ipm-scaled, with the paper constraints that are linear
  combinations of the others left out (``independent``: R7 at three measured states; a singular
  Schur matrix makes the IPM fall back from CHOLMOD to SuperLU).
Times: wall (the machine is shared, so also CPU time of the process, which with one BLAS thread is
what the solve costs on an idle core).  Log SVR on the marginalised X (``marginal_log_svr``).

    python benchmarks/continuous_k21.py [--seeds 0,1,2] [--methods …] [--sigmas 0.1] [--time-limit 120]
    python benchmarks/continuous_k21.py --sweep --seeds 0,1,2,3,4     # σ sweep, fastest path only
Writes benchmarks/results/continuous_k21.json.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from autotight import sdp  # noqa: E402
from autotight.io import jsonable, versions  # noqa: E402
from autotight.model import Constraint, Model  # noqa: E402
from autotight.problem import Instance, load  # noqa: E402
from autotight.run import CliqueCovers, solve_sdp  # noqa: E402
from autotight.sdp import SDPResult, SolverOptions  # noqa: E402
from autotight.threads import single_blas_thread  # noqa: E402
from problems import continuous_trajectory as ct  # noqa: E402

PROB = load("continuous_trajectory")
METHODS = ("marginalised", "kept-clarabel", "kept-ipm", "kept-ipm-scaled", "kept-ipm-scaled-indep")
#: relative size of a Gram-matrix pivot below which a constraint counts as a linear combination of
#: those before it (constraint vectors [svec A, b] normalised to unit length; rounding is ~1e-15)
INDEPENDENT_RTOL = 1e-9


def independent(constraints: Sequence[Constraint], rtol: float = INDEPENDENT_RTOL) -> list[Constraint]:
    """The constraints in order, leaving out each one whose [A, b] is a linear combination of those
    kept before it: a pivoted Cholesky of the Gram matrix of the normalised vectors (m × m, sparse
    products only).  The feasible set is unchanged; the SDP's Schur matrix becomes nonsingular."""
    rows = []
    for c in constraints:
        A = sp.coo_array(c.A)
        keep = A.row <= A.col
        v = np.concatenate([A.data[keep] * np.where(A.row[keep] == A.col[keep], 1.0, np.sqrt(2.0)), [c.b]])
        rows.append((A.row[keep], A.col[keep], v / np.linalg.norm(v)))
    N = constraints[0].A.shape[0]
    r = np.concatenate([np.full(len(v), i) for i, (_, _, v) in enumerate(rows)])
    col = np.concatenate([np.append(a * N + b, N * N) for a, b, _ in rows])
    M = sp.csr_array((np.concatenate([v for _, _, v in rows]), (r, col)), shape=(len(rows), N * N + 1))
    G = (M @ M.T).toarray()
    kept: list[int] = []
    L = np.zeros((len(rows), len(rows)))
    for i in range(len(rows)):  # Gram–Schmidt in the order given, on the Gram matrix
        li = np.linalg.solve(L[np.ix_(kept, kept)], G[kept, i]) if kept else np.zeros(0)
        resid = G[i, i] - li @ li
        if resid > rtol:
            L[i, kept] = li
            L[i, i] = np.sqrt(resid)
            kept.append(i)
    return [constraints[i] for i in kept]


@dataclass
class FastSolve:
    """A solve of the ϖ-kept SDP by ``solve_fast``: the result (X unscaled, cost in the original
    units), the cover it was solved on, and the log SVR of the marginalised X."""

    res: SDPResult
    cliques: list[np.ndarray]
    log_svr_marginal: float
    cost: float
    wall_s: float
    cpu_s: float


def solve_fast(inst: Instance, model: Model, constraints: Sequence[Constraint], *, scale: bool = True,
               drop_dependent: bool = False, options: SolverOptions | None = None) -> FastSolve:
    """The IPM on the ϖ-kept model (instance with marginalize=False), on its own cover, optionally after
    the congruence X = D X′ D (D = ``ct.block_scale``) and without linearly dependent constraints.
    When the IPM ends unusable, sdp.solve re-solves with Clarabel on Clarabel's cover (counted)."""
    t, c0 = time.perf_counter(), time.process_time()
    cons = independent(constraints) if drop_dependent else list(constraints)
    covers = CliqueCovers(model, cons)
    cl, fallback = covers.choose("ipm"), covers.choose("clarabel")
    D = ct.block_scale(inst) if scale else np.ones(model.variables.N)
    Dm = sp.diags(D)
    Q = sp.csr_array(Dm @ model.Q @ Dm)
    cs = [Constraint(sp.csr_array(Dm @ c.A @ Dm), c.b, name=c.name, family=c.family) for c in cons]
    res = sdp.solve(Q, cs, solver="ipm", cliques=cl, fallback_cliques=fallback, options=options)
    used = cl if res.solver.endswith("ipm") else fallback
    cost = float("nan")
    if res.X is not None:
        res.X = res.X * np.outer(D, D)
        cost = float(np.sum(model.Q.multiply(res.X)))
    wall, cpu = time.perf_counter() - t, time.process_time() - c0
    msvr = ct.marginal_log_svr(inst, res.X, used) if res.usable else float("nan")
    return FastSolve(res, used, msvr, cost, wall, cpu)
