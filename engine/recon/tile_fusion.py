"""Back-project and fuse one tile's voxels with the tile's views, a chunk of voxels at a time.

The transformer attends over views per voxel, so its working memory is about
chunk x views x (a few x channels + heads x views) floats. Streaming fixed-size chunks through it
keeps that bound independent of tile size and scene size; only the fused (M, C) output is kept.

Weights with stereo evidence also get each view's stereo depth map (`SceneStereo`: the run's maps,
computed once, and which keyframe each belongs to).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch

from ..jobs import CancelToken, check
from ..model.outputs import StereoEvidence
from ..model.stereo_evidence import FineFusion
from .features import FeatureCache


@dataclass
class SceneStereo:
    """The run's stereo depth maps for weights that take them.

    maps: every map (StereoEvidence, on the run's device); keyframe_map (n_keyframes,) int64: the map
    of each keyframe, -1 for keyframes that got none (stereo gives maps to at most `stereo_views`);
    fine: the classical method's fused TSDF of the maps, where the network starts (set by the driver)."""

    maps: StereoEvidence
    keyframe_map: np.ndarray
    fine: Optional[FineFusion] = None

    @classmethod
    def from_depth_maps(cls, depth_maps: Sequence, n_keyframes: int, device: torch.device) -> "SceneStereo":
        """depth_maps: engine.stereo.DepthMap list whose `frame` indexes the plan's keyframes."""
        keyframe_map = np.full(n_keyframes, -1, np.int64)
        keyframe_map[[m.frame for m in depth_maps]] = np.arange(len(depth_maps))
        return cls(StereoEvidence.from_depth_maps(depth_maps, device), keyframe_map)

    def views(self, keyframes: np.ndarray) -> StereoEvidence:
        """The maps of keyframe positions `keyframes` (v,), all-zero for those without one."""
        return self.maps.views(torch.as_tensor(self.keyframe_map[np.asarray(keyframes, np.int64)]))


@torch.inference_mode()
def fuse_tile(
    model: torch.nn.Module,
    level: int,
    points: torch.Tensor,
    cache: FeatureCache,
    views: np.ndarray,
    device: torch.device,
    chunk: int,
    cancel: Optional[CancelToken] = None,
    stereo: Optional[SceneStereo] = None,
) -> torch.Tensor:
    """Fused features (M, C_level) float32 on the CPU.

    points: (M, 3) float32 world positions (voxel corners) of the tile's voxels at this level;
    views: keyframe positions (v,) in the cache; stereo: the run's maps, for weights that take them.
    """
    feats, K, poses = cache.views(level, views, device)
    evidence = stereo.views(views) if stereo is not None else None
    outputs = []
    for start in range(0, len(points), chunk):
        check(cancel)
        block = points[start:start + chunk].to(device)
        fused = model.fuse(level, block, feats, K, poses, cache.image_hw, with_views=False, evidence=evidence)
        outputs.append(fused.features.to("cpu", torch.float32))
    if not outputs:
        return torch.zeros((0, feats.shape[1]), dtype=torch.float32)
    return torch.cat(outputs)
