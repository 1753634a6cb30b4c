"""Evaluation: Atlas mesh metrics, 2D depth metrics, trimming, and the room-box baseline (never bpy)."""

from .depth_metrics import DEPTH_METRIC_NAMES, depth_metrics, mean_depth_metrics
from .mesh_metrics import MeshMetrics, evaluate_mesh, mesh_points, point_metrics
from .points import surface_points, voxel_down_sample
from .room_box import box_mesh, fit_room_box, room_box_from_tsdf
from .trim import observed_mask

__all__ = [
    "DEPTH_METRIC_NAMES", "MeshMetrics", "box_mesh", "depth_metrics", "evaluate_mesh", "fit_room_box",
    "mean_depth_metrics", "mesh_points", "observed_mask", "point_metrics", "room_box_from_tsdf",
    "surface_points", "voxel_down_sample",
]
