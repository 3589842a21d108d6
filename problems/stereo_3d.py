"""Stereo localisation in 3-D from N known landmarks (AutoTight's Stereo3DLifter); see ``_stereo``.

Lifting: u_j = [q_{<d}, 1]/q_d (level "no") and, at level "urT" (default, the peer's), w_j = u_j tᵀ.
"""

from __future__ import annotations

from autotight.problem import Param

from . import _stereo

NAME = "stereo_3d"
DESCRIPTION = "Stereo-camera localisation in 3-D from known landmarks, substitution u = q/q_z (AutoTight)."
PARAMS: dict[str, Param] = _stereo.params(3, "urT")
TRANSPORTS = {"stereo": _stereo.transport, "stereo_urT": _stereo.transport_urT}
(generate, build, lift, cost, sample, random_state, local_solve, recover,
 errors) = _stereo.module_parts(NAME, 3)
