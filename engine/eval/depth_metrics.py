"""2D depth metrics (VoRTX/Atlas `eval_depth`): AbsRel, AbsDiff, SqRel, RMSE, LogRMSE, r1-r3, complete."""

from __future__ import annotations

from typing import Iterable

import numpy as np

DEPTH_METRIC_NAMES = ("AbsRel", "AbsDiff", "SqRel", "RMSE", "LogRMSE", "r1", "r2", "r3", "complete")


def depth_metrics(pred: np.ndarray, true: np.ndarray, max_depth: float = 10.0) -> dict[str, float]:
    """Metrics of one predicted depth map against the true one, both (H, W) metres, 0 = missing.

    Compared where 0 < true < max_depth and pred > 0; `complete` is the fraction of ALL pixels with
    pred > 0 (the reference's definition). With no comparable pixel the error metrics are NaN.
    """
    pred = np.asarray(pred, np.float64)
    true = np.asarray(true, np.float64)
    if pred.shape != true.shape:
        raise ValueError(f"depth maps differ in shape: {pred.shape} vs {true.shape}")
    has_pred = pred > 0
    mask = has_pred & (true > 0) & (true < max_depth)
    p, t = pred[mask], true[mask]
    out = {"complete": float(has_pred.mean())}
    if len(p) == 0:
        out.update({k: float("nan") for k in DEPTH_METRIC_NAMES if k != "complete"})
        return out
    abs_diff = np.abs(p - t)
    ratio = np.maximum(t / p, p / t)
    out.update({
        "AbsRel": float(np.mean(abs_diff / t)),
        "AbsDiff": float(np.mean(abs_diff)),
        "SqRel": float(np.mean(abs_diff ** 2 / t)),
        "RMSE": float(np.sqrt(np.mean(abs_diff ** 2))),
        "LogRMSE": float(np.sqrt(np.mean((np.log(p) - np.log(t)) ** 2))),
        "r1": float(np.mean(ratio < 1.25)),
        "r2": float(np.mean(ratio < 1.25 ** 2)),
        "r3": float(np.mean(ratio < 1.25 ** 3)),
    })
    return out


def mean_depth_metrics(per_frame: Iterable[dict[str, float]]) -> dict[str, float]:
    """Average of per-frame metrics (frames are averaged, not pixels, as in the reference), NaNs skipped."""
    rows = list(per_frame)
    return {k: float(np.nanmean([r[k] for r in rows])) if rows else float("nan") for k in DEPTH_METRIC_NAMES}
