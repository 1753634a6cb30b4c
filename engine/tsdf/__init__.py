"""TSDF fusion for ground truth, trimming and training targets (torch, CPU or CUDA; never bpy).

Voxel positions are voxel CORNERS: `index * voxel_size + origin` (grid.py).
"""

from .volume_bounds import frustum_bounds, volume_from_bounds
from .integration import finalize_tsdf, fuse_ground_truth, fuse_tsdf
from .grid import voxel_positions, world_to_voxel
from .targets import (
    LevelTargets,
    dilate,
    occupancy_targets,
    projective_occupancy,
    projective_occupancy_at_pixels,
    supervised_mask,
    unobserved_columns,
)
from .volume import TsdfVolume

__all__ = [
    "LevelTargets", "TsdfVolume", "dilate", "finalize_tsdf", "frustum_bounds",
    "fuse_ground_truth", "fuse_tsdf", "occupancy_targets", "projective_occupancy", "projective_occupancy_at_pixels",
    "supervised_mask", "unobserved_columns", "volume_from_bounds", "voxel_positions", "world_to_voxel",
]
