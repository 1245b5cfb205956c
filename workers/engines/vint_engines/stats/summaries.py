"""The summaries and histograms every statistic uses, written once: a summary is count, mean,
extremes and numpy's linear-interpolation quantiles; a histogram's bins are closed on the left,
the last also on the right. Floats rounded to DECIMALS, as stats.json holds them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

QUANTILES = {"p10": 0.10, "p25": 0.25, "p50": 0.50, "p75": 0.75, "p90": 0.90}
DECIMALS = 6  # stats.json's floats: far below any bin width, and stable across machines


def histogram(values: Sequence[float], edges: Sequence[float]) -> list[int]:
    counts = [0] * (len(edges) - 1)
    for x in values:
        k = int(np.searchsorted(edges, x, side="right")) - 1
        counts[min(max(k, 0), len(counts) - 1)] += 1
    return counts


def summary(values: Sequence[float]) -> dict[str, Any]:
    """Count, mean, extremes and quantiles (numpy's linear interpolation); None when empty."""
    if not values:
        return {"count": 0, "mean": None, "min": None, **dict.fromkeys(QUANTILES), "max": None}
    data = np.asarray(values, dtype=np.float64)
    quantiles = np.quantile(data, list(QUANTILES.values()))
    return {
        "count": len(values),
        "mean": round(float(data.mean()), DECIMALS),
        "min": round(float(data.min()), DECIMALS),
        **{name: round(float(q), DECIMALS) for name, q in zip(QUANTILES, quantiles, strict=True)},
        "max": round(float(data.max()), DECIMALS),
    }
