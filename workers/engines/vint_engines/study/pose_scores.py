"""Pose errors and their summaries for the touch-vs-vision study: ADD, ADD-S (PoseCNN's, as in
the BOP toolkit: mean distance over the model's vertices; ADD-S to the nearest transformed vertex),
ADD(S) AUC up to 10 cm and the share under 0.1 of the object's diameter.

The study's own scorer, on the dataset's model vertices; `vintctl eval` is the project's.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from vint_engines.study.icp import Surface, nearest

Array = npt.NDArray[np.float64]

SCORER = "the study's own ADD/ADD-S (`study/pose_scores.py`)"
AUC_MAX_MM = 100.0  # the accuracy–threshold curve runs from 0 to 10 cm (PoseCNN)


def add_mm(vertices: Array, R: Array, t: Array, R_gt: Array, t_gt: Array) -> float:
    """Mean distance between each model vertex under the estimate and under the truth."""
    return float(np.linalg.norm(vertices @ (R - R_gt).T + (t - t_gt), axis=1).mean())


def adds_mm(vertices: Array, R: Array, t: Array, R_gt: Array, t_gt: Array) -> float:
    """Mean distance from each vertex under the estimate to the nearest vertex under the truth."""
    truth = vertices @ R_gt.T + t_gt
    estimate = vertices @ R.T + t
    # nearest() only needs points; the normals are unused here.
    return float(nearest(estimate, Surface(points=truth, normals=truth, radius_mm=1.0))[1].mean())


def auc(errors_mm: Sequence[float], max_mm: float = AUC_MAX_MM) -> float:
    """Area under the accuracy–threshold curve on [0, max_mm], normalised to 1: the exact
    integral of the share of errors below each threshold, i.e. the mean of max(0, 1 - e/max)."""
    e = np.asarray(errors_mm, dtype=np.float64)
    if len(e) == 0:
        return float("nan")
    return float(np.mean(np.clip(1.0 - e / max_mm, 0.0, 1.0)))


def share_below(errors_mm: Sequence[float], thresholds_mm: Sequence[float]) -> float:
    """Share of errors strictly below their own threshold (0.1 × the object's diameter)."""
    e, th = np.asarray(errors_mm, dtype=np.float64), np.asarray(thresholds_mm, dtype=np.float64)
    return float(np.mean(e < th)) if len(e) else float("nan")
