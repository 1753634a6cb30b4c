"""Plane-sweep multi-view stereo: a depth and a confidence per keyframe pixel, no learning.

The depths are the domain-independent geometric evidence of the reconstruction
(../shared/design/stereo-evidence.md): fused into a TSDF they are the classical `stereo` method, and
they are the extra input of VoRTX with geometric evidence.
"""

from .depth_maps import DepthMap, estimate_depth_maps, stereo_references
from .fused_tsdf import fuse_depth_maps
from .options import StereoOptions
from .source_views import select_sources
from .sweep import sweep_depth

__all__ = ["DepthMap", "StereoOptions", "fuse_depth_maps", "estimate_depth_maps", "select_sources", "stereo_references", "sweep_depth"]
