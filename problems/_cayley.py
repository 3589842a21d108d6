"""Building blocks shared by the Cayley-paper problems (Barfoot, Holmes, Dümbgen 2024).

Kept for the problem modules that import it; the helpers now live in ``autotight.constraints``.
Rotation C = [c₁ c₂ c₃] is stored as three column blocks ``{p}c1, {p}c2, {p}c3``.
"""

from __future__ import annotations

from autotight.constraints import (COLS, H, draw_valid, measured_columns, orthonormality, rot_blocks,  # noqa: F401
                                   rotation_cayley, rotation_values, state_columns, weighted_norm)

__all__ = ["H", "orthonormality", "rotation_cayley", "measured_columns", "state_columns", "rotation_values",
           "weighted_norm", "rot_blocks", "draw_valid"]
