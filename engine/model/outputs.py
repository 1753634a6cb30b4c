"""Inputs and outputs of `VortxNet`, as plain dataclasses of tensors.

Shapes: V views, M points/voxels in a fusion call, N voxels at a level, B samples in a batch.
Voxel coordinates are (N, 4) int64 `[batch, x, y, z]` in units of the level's own voxels.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

import numpy as np
import torch

# Fine-level TSDF from the logit: 1.05 * tanh(logit), so the network can reach +-1 exactly.
TSDF_SCALE = 1.05


def tsdf_from_logits(logits: torch.Tensor) -> torch.Tensor:
    """Fine-level logits (N,) -> TSDF in truncation units, range (-1.05, 1.05)."""
    return TSDF_SCALE * torch.tanh(logits)


@dataclass
class FusionOutput:
    """Result of fusing one level's views at M points.

    features:        (M, C) fused features after LayerNorm (input to the 3D CNN).
    proj_occ_logits: (M, V) per-view projective-occupancy logits; None for the averaging ablation
                     or when the call asked for no per-view outputs.
    valid:           (M, V) bool, the point projects inside view v and in front of it.
    depth:           (M, V) camera z of the point in view v (metres).
    pixels:          (M, V, 2) image-pixel position (u, v) of the point in view v.
    Per-view fields are None when `fuse(..., with_views=False)`.
    """

    features: torch.Tensor
    proj_occ_logits: Optional[torch.Tensor] = None
    valid: Optional[torch.Tensor] = None
    depth: Optional[torch.Tensor] = None
    pixels: Optional[torch.Tensor] = None


@dataclass
class LevelOutput:
    """One level's 3D CNN result, or the upsampled input to the next level.

    coords:   (N, 4) int64 [batch, x, y, z], level units.
    features: (N, 3 * base_width) 3D CNN output features.
    logits:   (N,) occupancy logits (coarse, medium) or TSDF logits (fine).
    """

    coords: torch.Tensor
    features: torch.Tensor
    logits: torch.Tensor

    def select(self, rows: torch.Tensor) -> "LevelOutput":
        """Subset by an index or bool mask over N."""
        return LevelOutput(self.coords[rows], self.features[rows], self.logits[rows])

    def __len__(self) -> int:
        return self.coords.shape[0]


@dataclass
class LevelPrediction:
    """Training-forward output of one level, everything a loss needs. N voxels of all samples.

    coords:          (N, 4) int64 [batch, x, y, z] in this level's voxels (crop-local indices).
    points:          (N, 3) world position of each voxel's corner, origin + index * voxel_size.
    logits:          (N,) occupancy logits (coarse, medium) or TSDF logits (fine; see tsdf()).
    proj_occ_logits: (N, V) per-view projective-occupancy logits; view v is view v of the voxel's
                     own sample. None for the averaging ablation.
    valid:           (N, V) bool, the voxel projects inside view v and in front of it.
    depth:           (N, V) camera z of the voxel in view v.
    pixels:          (N, V, 2) image-pixel position (u, v) of the voxel in view v (for sampling the
                     view's depth map: the projective-occupancy target is |depth - depth_map| < 3 res).
    voxel_size:      this level's voxel edge in metres.
    """

    coords: torch.Tensor
    points: torch.Tensor
    logits: torch.Tensor
    proj_occ_logits: Optional[torch.Tensor]
    valid: torch.Tensor
    depth: torch.Tensor
    pixels: torch.Tensor
    voxel_size: float

    def tsdf(self) -> torch.Tensor:
        """(N,) TSDF from the logits (meaningful at the fine level)."""
        return tsdf_from_logits(self.logits)


@dataclass
class StereoEvidence:
    """A scene's (or a training crop's) stereo depth maps, in the frame the voxels are given in.

    depth:        (S, h, w) float32 metres (planar z), 0 = no depth.
    confidence:   (S, h, w) float32 in [0, 1].
    K:            (S, 3, 3) float32 intrinsics in pixels of the depth maps.
    cam_to_world: (S, 4, 4) float32 camera-to-world (OpenCV axes).
    """

    depth: torch.Tensor
    confidence: torch.Tensor
    K: torch.Tensor
    cam_to_world: torch.Tensor

    def __post_init__(self) -> None:
        s = self.depth.shape[0]
        if self.depth.dim() != 3 or self.confidence.shape != self.depth.shape:
            raise ValueError(f"stereo depth and confidence must both be (S, h, w), got {tuple(self.depth.shape)} "
                             f"and {tuple(self.confidence.shape)}")
        if tuple(self.K.shape) != (s, 3, 3) or tuple(self.cam_to_world.shape) != (s, 4, 4):
            raise ValueError(f"stereo K must be ({s}, 3, 3) and cam_to_world ({s}, 4, 4), got "
                             f"{tuple(self.K.shape)} and {tuple(self.cam_to_world.shape)}")

    def __len__(self) -> int:
        return self.depth.shape[0]

    @classmethod
    def from_depth_maps(cls, maps, device: torch.device | str = "cpu") -> "StereoEvidence":
        """From a list of engine.stereo.DepthMap (all of one size)."""
        if not maps:
            raise ValueError("no stereo depth maps")
        return cls(
            depth=torch.as_tensor(np.stack([m.depth for m in maps]), dtype=torch.float32, device=device),
            confidence=torch.as_tensor(np.stack([m.confidence for m in maps]), dtype=torch.float32, device=device),
            K=torch.as_tensor(np.stack([m.K for m in maps]), dtype=torch.float32, device=device),
            cam_to_world=torch.as_tensor(np.stack([m.pose for m in maps]), dtype=torch.float32, device=device),
        )

    def views(self, index: torch.Tensor) -> "StereoEvidence":
        """The maps of V views, `index` (V,) int64 into the maps; -1 = the view has no depth map (an
        all-zero map, so its evidence is invalid everywhere)."""
        index = torch.as_tensor(index, dtype=torch.int64, device=self.depth.device)
        missing = index < 0
        safe = index.clamp(min=0)
        depth = self.depth[safe]
        confidence = self.confidence[safe]
        if bool(missing.any()):
            keep = (~missing).to(depth.dtype)[:, None, None]
            depth, confidence = depth * keep, confidence * keep
        return StereoEvidence(depth, confidence, self.K[safe], self.cam_to_world[safe])

    def to(self, device: torch.device | str) -> "StereoEvidence":
        return StereoEvidence(self.depth.to(device), self.confidence.to(device), self.K.to(device),
                              self.cam_to_world.to(device))


@dataclass
class VortxBatch:
    """A training batch of B crops, each with V views.

    images:       (B, V, 3, H, W) float RGB in 0-255.
    K:            (B, V, 3, 3) intrinsics in pixels of these images.
    cam_to_world: (B, V, 4, 4) camera-to-world poses (OpenCV camera axes, world Z up).
    origin:       (B, 3) world position of the corner of the crop's fine voxel (0, 0, 0); every level
                  shares it (voxel i of level l sits at origin + i * voxel_size_l).
    crop_shape:   (X, Y, Z) crop size in fine voxels, each divisible by 4, e.g. (96, 96, 48); the
                  coarse level starts from the dense (X/4, Y/4, Z/4) grid.
    stereo:       with stereo evidence: per sample, the stereo depth maps fused into its TSDF (all of
                  the room's, in the crop frame); None otherwise.
    stereo_views: (B, V) int64, the map in `stereo[b]` of each view (-1 = none); with `stereo`.
    """

    images: torch.Tensor
    K: torch.Tensor
    cam_to_world: torch.Tensor
    origin: torch.Tensor
    crop_shape: tuple[int, int, int]
    stereo: Optional[list[StereoEvidence]] = None
    stereo_views: Optional[torch.Tensor] = None

    def __post_init__(self) -> None:
        b, v = self.images.shape[:2]
        if self.images.dim() != 5 or self.images.shape[2] != 3:
            raise ValueError(f"images must be (B, V, 3, H, W), got {tuple(self.images.shape)}")
        expected = {"K": (b, v, 3, 3), "cam_to_world": (b, v, 4, 4), "origin": (b, 3)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"{name} must be {shape}, got {tuple(getattr(self, name).shape)}")
        self.crop_shape = tuple(int(c) for c in self.crop_shape)  # type: ignore[assignment]
        if len(self.crop_shape) != 3 or any(c <= 0 or c % 4 for c in self.crop_shape):
            raise ValueError(f"crop_shape must be 3 positive multiples of 4, got {self.crop_shape}")
        if (self.stereo is None) != (self.stereo_views is None):
            raise ValueError("stereo and stereo_views go together")
        if self.stereo is not None and (len(self.stereo) != b or tuple(self.stereo_views.shape) != (b, v)):
            raise ValueError(f"stereo needs one entry per sample ({b}) and stereo_views shape ({b}, {v})")

    @property
    def batch_size(self) -> int:
        return self.images.shape[0]

    def to(self, device: torch.device | str) -> "VortxBatch":
        moved = {f.name: getattr(self, f.name) for f in fields(self)}
        for name, value in moved.items():
            if isinstance(value, torch.Tensor):
                moved[name] = value.to(device)
        if self.stereo is not None:
            moved["stereo"] = [e.to(device) for e in self.stereo]
        return VortxBatch(**moved)
