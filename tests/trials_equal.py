"""Comparing saved sweep results: the same trials, sets and verdicts, numbers to roundoff."""

from __future__ import annotations

import numpy as np
import pandas as pd

from autotight.report.trial import TIME_COLUMNS

#: log SVR above this is λ_{d+1} at the SDP solver's accuracy floor (≈ 1e-8 of λ_d): its value there is
#: roundoff, which may differ between processes (BLAS kernels, memory alignment), so it is compared capped
LOG_SVR_FLOOR = 8.0


def deterministic(df: pd.DataFrame) -> pd.DataFrame:
    """The deterministic columns (all but times), in canonical row order; log SVR capped at its floor."""
    keep = [c for c in df.columns if c not in TIME_COLUMNS]
    out = df[keep].sort_values(["sigma_index", "trial", "constraint_set"]).reset_index(drop=True)
    out["log_svr"] = np.minimum(out["log_svr"].astype(float), LOG_SVR_FLOOR)
    return out


def assert_same_trials(a: pd.DataFrame, b: pd.DataFrame) -> None:
    """Equal trials, sets, statuses and verdicts; costs and other numbers to 1e-7 relative."""
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=False, rtol=1e-7, atol=1e-12)
