"""Atlas 3D mesh metrics (vortx-spec.md section 5): accuracy, completeness, precision, recall, F-score.

acc = mean d(pred -> gt), comp = mean d(gt -> pred), prec = mean[d(pred -> gt) < t],
recall = mean[d(gt -> pred) < t], F = 2 P R / (P + R), with t = 5 cm, on points down-sampled with a
2 cm voxel grid (points.py explains how meshes become points; trim.py how they are trimmed).
Naming follows VoRTX's `eval_utils.py` (Atlas's own evaluate.py swaps "prec"/"recall").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from ..mesh_io import Mesh
from ..tsdf.volume import TsdfVolume
from .points import surface_points, voxel_down_sample
from .trim import observed_mask


@dataclass
class MeshMetrics:
    acc: float  # metres
    comp: float  # metres
    prec: float  # 0..1
    recall: float  # 0..1
    fscore: float  # 0..1
    n_pred: int  # points compared after down-sampling and trimming
    n_gt: int

    def as_dict(self) -> dict:
        return asdict(self)


def point_metrics(pred: np.ndarray, gt: np.ndarray, threshold: float = 0.05) -> MeshMetrics:
    """Metrics between two point sets pred (N, 3) and gt (M, 3), by exact 1-NN distances.

    An empty side gives infinite distances and zero precision/recall/F (Atlas would give NaN).
    """
    pred = np.asarray(pred, np.float64).reshape(-1, 3)
    gt = np.asarray(gt, np.float64).reshape(-1, 3)
    if len(pred) == 0 or len(gt) == 0:
        return MeshMetrics(float("inf"), float("inf"), 0.0, 0.0, 0.0, len(pred), len(gt))
    d_pred_to_gt = cKDTree(gt).query(pred, k=1)[0]
    d_gt_to_pred = cKDTree(pred).query(gt, k=1)[0]
    prec = float(np.mean(d_pred_to_gt < threshold))
    recall = float(np.mean(d_gt_to_pred < threshold))
    fscore = 2 * prec * recall / (prec + recall) if prec + recall > 0 else 0.0
    return MeshMetrics(float(d_pred_to_gt.mean()), float(d_gt_to_pred.mean()), prec, recall, fscore,
                       len(pred), len(gt))


def mesh_points(mesh: Mesh, down_sample: Optional[float] = 0.02, spacing: float = 0.01) -> np.ndarray:
    """The point set a mesh is judged by: surface_points (faces) or voxel-down-sampled vertices (point clouds)."""
    if len(mesh.faces) == 0:
        return voxel_down_sample(mesh.vertices, down_sample) if down_sample else np.asarray(mesh.vertices, np.float64)
    return surface_points(mesh.vertices, mesh.faces, spacing=spacing, down_sample=down_sample)


def evaluate_mesh(
    pred: Mesh,
    gt: Mesh,
    observed: Optional[TsdfVolume] = None,
    threshold: float = 0.05,
    down_sample: float = 0.02,
    trim_gt: bool = True,
) -> MeshMetrics:
    """Atlas metrics of a predicted mesh against the ground truth, both in world metres.

    observed: the ground-truth TSDF; when given, the prediction is trimmed to its observed voxels,
    and so is the ground truth unless trim_gt is False. ScanNet's ground truth is itself a scan and
    only holds what was seen; our synthetic ground truth is the whole scene (ceiling, hidden faces),
    so trimming it too is what makes the numbers comparable.
    """
    p = mesh_points(pred, down_sample)
    g = mesh_points(gt, down_sample)
    if observed is not None:
        p = p[observed_mask(p, observed)]
        if trim_gt:
            g = g[observed_mask(g, observed)]
    return point_metrics(p, g, threshold)
