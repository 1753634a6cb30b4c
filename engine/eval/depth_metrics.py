"""2D depth metrics (VoRTX/Atlas `eval_depth`): AbsRel, AbsDiff, SqRel, RMSE, LogRMSE, r1-r3, complete."""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..capture import load_depth
from ..errors import VortxError
from ..geometry.depth_render import render_depth
from ..meshops import subdivide

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


def mesh_depth_metrics(
    vertices: np.ndarray,
    faces: np.ndarray,
    views: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
    max_depth: float = 10.0,
) -> dict[str, float]:
    """The 2D depth metrics of a mesh (Atlas `eval_depth`): the mesh is rendered into every view
    and compared with that view's true depth, then averaged over views.

    views: (K (3, 3) in pixels of the depth map, pose (4, 4) camera-to-world, true depth (H, W)
    metres with 0 = missing). Pixels the mesh does not cover count as missing predictions.
    """
    # The rasteriser drops triangles that cross a camera's near plane and caps the samples of huge
    # ones; metre-long triangles (a box room, a ground-truth wall) must be split first.
    vertices, faces = subdivide(vertices, faces, max_edge=0.1)
    rows = []
    for K, pose, true in views:
        h, w = np.shape(true)
        pred = render_depth(vertices, faces, np.asarray(K, np.float64), np.asarray(pose, np.float64), (w, h))
        rows.append(depth_metrics(np.where(np.isfinite(pred), pred, 0.0), true, max_depth))
    return mean_depth_metrics(rows)


def capture_depth_views(capture, every: int = 1) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(K, pose, depth) of every `every`-th posed frame with a depth map, K scaled to the depth map."""
    views = []
    frames = [f for f in capture.frames if f.pose is not None and f.depth_path is not None]
    if not frames:
        raise VortxError(f"{capture.root}: no frame has both a pose and a depth map; depth metrics need them")
    for frame in frames[::every]:
        depth = load_depth(frame.depth_path)
        K = np.array(frame.K, dtype=np.float64)
        K[0] *= depth.shape[1] / frame.width
        K[1] *= depth.shape[0] / frame.height
        views.append((K, np.asarray(frame.pose, np.float64), depth))
    return views
