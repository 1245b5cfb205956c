"""The ADD(S) AUC of a pooled set of errors, summed as `vintctl eval` sums it (docs/metrics.md:
the YCB-Video toolbox's VOCap, PoseCNN's), for the groups eval does not report itself (occlusion
ranges wider than one bucket, objects by hand). The errors come from `vintctl eval`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

AUC_MAX_MM = 100.0  # the accuracy–threshold curve runs from 0 to 10 cm


def auc(errors_mm: Sequence[float], max_mm: float = AUC_MAX_MM) -> float:
    """Area (percent) under the accuracy–threshold curve on [0, max_mm], each step of the curve
    taken at its right end: with n errors and d_1 ≤ … ≤ d_k those within max_mm,
    100/T · [1/n Σ_i max(0, T - e_i) + d_k/n]. NaN for no errors."""
    e = np.sort(np.asarray(errors_mm, dtype=np.float64))
    if len(e) == 0:
        return float("nan")
    within = e[e <= max_mm]
    last = float(within[-1]) if len(within) else 0.0
    return 100.0 / max_mm * (float(np.sum(max_mm - within)) + last) / len(e)
