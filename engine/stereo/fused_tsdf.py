"""Stereo depth maps fused into a TSDF with the project's own integration (engine/tsdf/integration.py).

Fusion is the stereo outlier filter: a wrong depth in one view is outvoted by the free space the
other views see through it (stereo-evidence.md: with many overlapping views this beats a strict
cross-view consistency check). The truncation defaults to 3 voxels, as in the ground truth and
FineRecon; the stereo method fuses with its own wider band (CLASSICAL_TRUNCATION_VOXELS).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch

from ..jobs import CancelToken, ProgressCallback
from ..mesh_io import Mesh
from ..meshops import face_pieces, keep_faces
from ..tsdf.integration import FusionEvidence, fuse_tsdf
from .depth_filters import observation_weights
from .depth_maps import DepthMap

TRUNCATION_VOXELS = 3.0  # the ground truth's and FineRecon's; the stereo method fuses with its own
# The stereo method's band (engine/recon/stereo_fusion.py), and the fused TSDF an evidence network starts
# from: a wider band than 3 voxels averages more views into each surface voxel: +0.01 F on the demo
# sample at every stereo resolution tried (0.696 -> 0.704 at 160 px, 0.716 -> 0.726 at 200 px).
CLASSICAL_TRUNCATION_VOXELS = 4.0


def fuse_depth_maps(
    maps: Sequence[DepthMap],
    origin: np.ndarray,
    dims: Sequence[int],
    voxel_size: float,
    truncation_voxels: float = TRUNCATION_VOXELS,
    device: Optional[torch.device] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    start: Sequence[int] = (0, 0, 0),
) -> tuple[np.ndarray, np.ndarray]:
    """(tsdf, weight), each (X, Y, Z) float32, of the depth maps on the grid origin + index * voxel_size,
    for the voxels from index `start` on (a block of a larger grid: `fuse_tsdf`).

    tsdf follows the ground-truth convention (negative in front of surfaces, +1 unobserved);
    weight counts the depth maps that updated a voxel.
    """
    if not maps:
        dims = tuple(int(d) for d in dims)
        return np.ones(dims, np.float32), np.zeros(dims, np.float32)
    tsdf, weight = fuse_tsdf([m.depth for m in maps], np.stack([m.K for m in maps]), np.stack([m.pose for m in maps]),
                             origin, dims, voxel_size, truncation_voxels * voxel_size, depth_cap=None, device=device,
                             progress=progress, cancel=cancel, start=start)
    return tsdf.cpu().numpy(), weight.cpu().numpy()


@dataclass
class FusedStereo:
    """Depth maps fused with evidence weights (`fuse_stereo_evidence`); each array (X, Y, Z) float32."""

    tsdf: np.ndarray  # ground-truth convention: negative in front of surfaces, +1 unobserved
    observations: np.ndarray  # depth maps that updated the voxel (surface or free space)
    support: np.ndarray  # depth maps whose surface passes within the truncation band of the voxel

    def surface_voxels(self, min_support: int) -> np.ndarray:
        """(X, Y, Z) bool: observed voxels that may take part in a surface: free space, or a voxel
        near a surface that at least `min_support` views agree on (a surface seen by one view alone
        is matching noise more often than a real surface: it is not meshed)."""
        observed = self.observations > 0
        near_surface = np.abs(self.tsdf) < 1.0
        return observed & (~near_surface | (self.support >= min_support))


def fuse_stereo_evidence(
    maps: Sequence[DepthMap],
    origin: np.ndarray,
    dims: Sequence[int],
    voxel_size: float,
    truncation_voxels: float = TRUNCATION_VOXELS,
    device: Optional[torch.device] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    start: Sequence[int] = (0, 0, 0),
) -> FusedStereo:
    """The depth maps fused with each depth weighted by its evidence (`depth_filters.observation_weights`),
    bilinear depth lookups, and the per-voxel count of agreeing views; `start` as in `fuse_depth_maps`."""
    dims = tuple(int(d) for d in dims)
    if not maps:
        return FusedStereo(np.ones(dims, np.float32), np.zeros(dims, np.float32), np.zeros(dims, np.float32))
    evidence = FusionEvidence([observation_weights(m.depth, m.confidence, m.K, m.normal) for m in maps])
    tsdf, observations = fuse_tsdf([m.depth for m in maps], np.stack([m.K for m in maps]), np.stack([m.pose for m in maps]),
                                   origin, dims, voxel_size, truncation_voxels * voxel_size, depth_cap=None,
                                   device=device, progress=progress, cancel=cancel, evidence=evidence, start=start)
    return FusedStereo(tsdf.cpu().numpy(), observations.cpu().numpy(), evidence.support.cpu().numpy())


def vertex_support(mesh: Mesh, support: np.ndarray, origin: np.ndarray, voxel_size: float) -> np.ndarray:
    """Per vertex (V,) float32 the views that agree on a surface at its nearest voxel of `support` (X, Y, Z)."""
    index = np.clip(np.round((mesh.vertices - origin) / voxel_size).astype(np.int64), 0, np.array(support.shape) - 1)
    return support[index[:, 0], index[:, 1], index[:, 2]]


def piece_support(mesh: Mesh, vertex_views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face the connected piece it belongs to, and per piece the most views that agree on any of
    its vertices (`vertex_views` (V,)): (face_piece (F,) int64, piece_views (P,) float32)."""
    pieces, _ = face_pieces(mesh.faces, len(mesh.vertices))
    face_views = vertex_views[mesh.faces].max(axis=1)
    piece_views = np.zeros(int(pieces.max()) + 1 if len(pieces) else 0, np.float32)
    np.maximum.at(piece_views, pieces, face_views)
    return pieces, piece_views


def drop_unsupported_pieces(mesh: Mesh, vertex_views: np.ndarray, min_views: int) -> tuple[Mesh, dict]:
    """The mesh without the connected pieces that fewer than `min_views` views agree on anywhere
    (`vertex_views` (V,): per vertex): pieces go by evidence, not by size (a small real object seen by
    many views stays)."""
    if len(mesh.faces) == 0:
        return mesh, {"pieces": 0, "dropped_pieces": 0, "dropped_faces": 0}
    pieces, piece_views = piece_support(mesh, vertex_views)
    keep = piece_views[pieces] >= min_views
    return keep_faces(mesh, keep), {"pieces": int(len(piece_views)), "dropped_pieces": int((piece_views < min_views).sum()),
                                    "dropped_faces": int((~keep).sum())}
