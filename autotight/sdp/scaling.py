"""A diagonal scaling of the lifted variable, for ``sdp.solve(..., scale=D)``.

The lifted blocks can differ in magnitude by orders: rotation entries are O(1), residual blocks
(ξ, ρ, φ) are O(σ).  An interior-point solver stops at a relative accuracy of the whole X, so at
σ = 1e-3 the small blocks are resolved only to ~tol/σ.  The congruence X = D X' D with D = the
blocks' typical magnitudes makes every block of X' O(1); ``sdp.solve`` solves for X' and maps back.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..model import HOMOGENISING, Variables

#: smallest block scale, relative to the largest block's.  It keeps D invertible where a block
#: vanishes on the given states (zero noise), and it limits how far a block is blown up: a block's
#: value at the optimum can be far below its size elsewhere in the SDP's feasible set (continuous
#: time at σ = 0.1: measured residuals of 5e-4 against σ), and scaling it by that value alone made
#: Clarabel stall (K = 5: NumericalError at a floor of 1e-4; Solved, log SVR 6–7.5, at 1e-2 for
#: σ = 0.1 and σ = 0.001 alike).  cond(D) ≤ 1/FLOOR_REL = 100.
FLOOR_REL = 1e-2


def block_scale(variables: Variables, theta_samples: Sequence[np.ndarray], floor_rel: float = FLOOR_REL) -> np.ndarray:
    """The positive scale vector D (N,) for ``sdp.solve(..., scale=D)``: on each variable block's
    columns, the RMS magnitude of that block's entries over the lifted states ``theta_samples``
    (each Θ of shape (N,) or (d, N), e.g. ``lift`` of the local solution or of samples), floored at
    ``floor_rel`` × the largest block's; 1 on the h block.  ValueError on bad shapes or no states."""
    if not theta_samples:
        raise ValueError("block_scale needs at least one lifted state")
    if not 0 < floor_rel <= 1:
        raise ValueError(f"floor_rel must be in (0, 1], got {floor_rel}")
    N, d = variables.N, variables.d
    Ts = [np.atleast_2d(np.asarray(t, float)) for t in theta_samples]
    if any(t.shape != (d, N) for t in Ts):
        raise ValueError(f"each lifted state must have shape ({N},) or ({d}, {N}); got {[t.shape for t in Ts]}")
    T = np.concatenate(Ts, axis=0)  # (d · samples, N)
    if not np.all(np.isfinite(T)):
        raise ValueError("the lifted states must be finite")
    names = [n for n in variables.names if n != HOMOGENISING]
    rms = {n: float(np.sqrt(np.mean(T[:, variables.slice(n)] ** 2))) for n in names}
    top = max(rms.values(), default=1.0)
    floor = floor_rel * top if top > 0 else 1.0
    D = np.ones(N)
    for n in names:
        D[variables.slice(n)] = max(rms[n], floor)
    return D
