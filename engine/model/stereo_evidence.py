"""Stereo depth as geometric evidence for VoRTX, per voxel (design: ../shared/design/stereo-evidence.md).

The maps themselves travel as `StereoEvidence` (engine/model/outputs.py, with the network's other
inputs); this module turns them into per-voxel features and priors.

Two inputs, both computed from the plane-sweep depth maps (engine/stereo), never from exact depth:

- per voxel and view, a token feature joined with the appearance features in the view transformer:
  `[clamp((d_view(u, v) - z_view) / trunc, -1, 1), confidence(u, v), valid]`, where (u, v) is the
  voxel's projection into the view's depth map, z_view its camera depth and valid says the view has
  a depth there (inside the map, in front of the camera, depth > 0). Invalid entries are all zero.
- per voxel, the TSDF fused from all depth maps of the scene (FineRecon): the project's integration
  rule (engine/tsdf/integration.py) evaluated at the voxel's position: mean over the maps that see
  the voxel no further than `trunc` behind their depth of min(1, (d - z) / trunc), then the
  ground-truth sign convention (negative in front of a surface, -1 free space, +1 never observed).

The truncation is `truncation_voxels` voxels of the level the voxel belongs to (16 / 8 / 4 cm).

The network starts exactly at the classical stereo method (its heads' last layers are zero): the fine
level outputs the classical fused TSDF (`FineFusion`, fused with the classical band,
engine/stereo/fused_tsdf.py CLASSICAL_TRUNCATION_VOXELS, from the same depth maps), and the coarse and
medium levels keep every voxel whose block holds a corner of a cell the classical surface passes through. Training then
learns corrections: completion where no map saw the surface, removal of what the maps got wrong.

A depth pixel (0, 0) covers [0, 1)^2 (the engine's K convention): a projection lands in pixel floor(u).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch

from ..geometry.cameras import project_points_torch
from .outputs import TSDF_SCALE, StereoEvidence

EVIDENCE_CHANNELS = 3  # projective signed distance, confidence, valid flag
POINT_CHUNK = 16384  # voxels per fused-TSDF pass: bounds the (chunk, maps) float64 work arrays
OCCUPANCY_PRIOR_GAIN = 5.0  # the start's occupancy logit of a block the classical surface passes: kept, but a head can overrule it
NEAR_SURFACE = 0.999  # a block value below this (0: the classical surface passes) is kept
# A predicted fine TSDF at or above this means "unobserved", as the +1 of the training targets: the
# mesh of an evidence network leaves out the voxels classical fusion did not observe either, as the
# stereo method does (a free voxel next to an unobserved one is not a surface).
UNOBSERVED_TSDF = 1.0
# The fine logit an untrained network gives a voxel no map observed: TSDF 1.01, just "unobserved", and
# not deep in tanh's flat tail (at TSDF 1.049 the gradient is 40x smaller), so training can still
# pull it down where the room has surface that stereo missed (completion).
UNOBSERVED_START_LOGIT = float(np.arctanh(1.01 / TSDF_SCALE))
# A trained network may keep coarse and medium blocks the classical surface does not pass through
# (completion), and every such block costs the finer levels voxels: at most this share of the
# classical blocks kept, the most confident first, holds the learned method to its cost budget (issue
# 19: 1.5x the classical method's CPU per keyframe, its peak memory + 1 GB).
MAX_ADDED_BLOCK_SHARE = 0.5


def cap_added_blocks(keep: torch.Tensor, logits: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    """keep (N,) bool of a coarse or medium level, limited to its classical blocks (start > 0, see
    `prior_logits`) plus at most MAX_ADDED_BLOCK_SHARE times as many other blocks, those of the highest
    logits (ties: the first rows)."""
    classical = start > 0
    added = keep & ~classical
    budget = int(MAX_ADDED_BLOCK_SHARE * int((keep & classical).sum()))
    if int(added.sum()) <= budget:
        return keep
    rows = torch.nonzero(added).flatten()
    best = rows[torch.argsort(logits[rows], descending=True, stable=True)[:budget]]
    capped = keep & classical
    capped[best] = True
    return capped


def meshable_voxels(predicted: torch.Tensor, classical_observed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Which fine voxels an evidence network's mesh is made of, and their values: (keep (N,) bool,
    tsdf (N,) in [-1.05, 1]) from the predicted TSDF and whether classical fusion observed the N voxels.

    A voxel classical fusion observed stays, whatever the network says: the targets' +1 also means "far
    behind a surface" (their band is 3 voxels, the classical one 4), and a surface's back-side corners
    predicted at >= 1 must not cut holes in it; its value is capped at 1. A voxel classical fusion did
    not observe joins only where the network says it is observed (< UNOBSERVED_TSDF): completion."""
    keep = classical_observed | (predicted < UNOBSERVED_TSDF)
    return keep, predicted.clamp(max=1.0)


def _depth_lookup(points: torch.Tensor, evidence: StereoEvidence) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """points (M, 3) -> camera z (M, S), map depth d (M, S) and confidence (M, S) at the pixel containing
    the projection, and `seen` (M, S): inside the map, z > 0 and d > 0 (d, confidence 0 elsewhere)."""
    u, v, z = project_points_torch(points, evidence.K.to(points.dtype), evidence.cam_to_world)
    s, h, w = evidence.depth.shape
    finite = torch.isfinite(u) & torch.isfinite(v)
    ui = torch.floor(torch.where(finite, u, torch.full_like(u, -1.0)))
    vi = torch.floor(torch.where(finite, v, torch.full_like(v, -1.0)))
    inside = (z > 0) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    flat = (vi.clamp(0, h - 1) * w + ui.clamp(0, w - 1)).long() + torch.arange(s, device=points.device) * (h * w)
    d = evidence.depth.reshape(-1)[flat].to(points.dtype)
    c = evidence.confidence.reshape(-1)[flat].to(points.dtype)
    seen = inside & (d > 0)
    zero = torch.zeros_like(d)
    return z, torch.where(seen, d, zero), torch.where(seen, c, zero), seen


def view_evidence(points: torch.Tensor, evidence: StereoEvidence, trunc: float) -> torch.Tensor:
    """Token evidence (M, V, 3) = [psdf, confidence, valid] of points (M, 3) in the V views of
    `evidence` (one map per view, see StereoEvidence.views); psdf = clamp((d - z) / trunc, -1, 1)."""
    z, d, c, seen = _depth_lookup(points.to(torch.float32), evidence)
    psdf = torch.where(seen, ((d - z) / trunc).clamp(-1.0, 1.0), torch.zeros_like(d))
    return torch.stack([psdf, c, seen.to(psdf.dtype)], dim=-1)


def fused_tsdf(points: torch.Tensor, evidence: StereoEvidence, trunc: float) -> torch.Tensor:
    """(M,) TSDF fused from every map of `evidence` at points (M, 3), ground-truth sign convention
    (see the module doc); float64 projection, as the dense integration, so both agree voxel for voxel."""
    out = []
    points = points.to(torch.float64)
    for start in range(0, max(len(points), 1), POINT_CHUNK):
        z, d, _, seen = _depth_lookup(points[start:start + POINT_CHUNK], evidence)
        diff = d - z
        update = seen & (diff >= -trunc)
        dist = torch.where(update, (diff / trunc).clamp(max=1.0), torch.zeros_like(diff))
        count = update.sum(dim=1)
        mean = dist.sum(dim=1) / count.clamp(min=1)
        # Running mean (+ in front) -> ground truth convention: negate values < 1, observed 1 -> -1.
        tsdf = torch.where(mean < 1, -mean, torch.full_like(mean, -1.0))
        out.append(torch.where(count > 0, tsdf, torch.ones_like(tsdf)).to(torch.float32))
    return torch.cat(out)


@dataclass
class FineFusion:
    """The classical stereo method's fused TSDF on a dense grid of fine voxels: where an evidence network
    starts (its heads' last layers are zero, so it outputs `LevelEvidence.start` until trained).

    tsdf:     (X, Y, Z) float32, ground-truth convention (+1 where no depth map reached the voxel).
    offset:   the fine-voxel index, in the frame of the network's voxel coordinates, of tsdf[0, 0, 0].
    observed: (X, Y, Z) bool, a depth map updated the voxel (classical fusion's weight > 0); None: tsdf < 1
              (the same but for the rare observed voxel whose every map puts it exactly +1 behind).
    Outside the grid every voxel counts as unobserved (+1): the classical method meshes nothing there.
    """

    tsdf: torch.Tensor
    offset: tuple[int, int, int]
    observed: Optional[torch.Tensor] = None
    _blocks: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.observed is None:
            self.observed = self.tsdf < UNOBSERVED_TSDF

    def tsdf_at(self, coords: torch.Tensor) -> torch.Tensor:
        """(N,) fused TSDF of fine voxels (N, 3) (+1 outside the grid)."""
        return _gather(self.tsdf, coords, 1.0, self.offset)

    def observed_at(self, coords: torch.Tensor) -> torch.Tensor:
        """(N,) bool: classical fusion observed the fine voxels (N, 3) (False outside the grid)."""
        return _gather(self.observed, coords, False, self.offset)

    def covers(self, scale: int, coords: torch.Tensor) -> torch.Tensor:
        """(N,) bool: voxels (N, 3) of a level `scale` fine voxels wide whose block overlaps the grid."""
        lo = coords.to(torch.int64) * scale
        first = torch.as_tensor(self.offset, dtype=torch.int64, device=lo.device)
        end = first + torch.as_tensor(self.tsdf.shape, dtype=torch.int64, device=lo.device)
        return ((lo + scale > first) & (lo < end)).all(dim=1)

    def block_surface(self, scale: int, coords: torch.Tensor) -> torch.Tensor:
        """(N,) for voxels (N, 3) of a level `scale` fine voxels wide: 0 where the block holds a corner of a
        marching-cubes cell through which the classical surface passes, else 1. Keeping exactly these
        blocks keeps every fine voxel the classical mesh needs and no more (a single corner sample per
        coarse voxel lost ~14 % of the surface, docs/experiments.md; the whole truncation band is 3x the voxels)."""
        if scale not in self._blocks:
            self._blocks[scale] = _blocks_without_surface(surface_cell_corners(self.tsdf, self.observed), self.offset, scale)
        pooled, first = self._blocks[scale]
        return _gather(pooled, coords, 1.0, first)


def surface_cell_corners(tsdf: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """(X, Y, Z) bool: the voxels that are a corner of a cell (2 x 2 x 2 voxels) whose corners are all
    observed and do not all have the same sign: the cells marching cubes puts the surface in."""
    X, Y, Z = tsdf.shape
    offsets = [(dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
    corners = torch.stack([tsdf[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz] for dx, dy, dz in offsets])
    seen = torch.stack([observed[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz] for dx, dy, dz in offsets]).all(dim=0)
    low, high = corners.min(dim=0).values, corners.max(dim=0).values
    cells = seen & (low <= 0) & (high >= 0) & (low < high)
    marked = torch.zeros_like(tsdf, dtype=torch.bool)
    for dx, dy, dz in offsets:
        marked[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz] |= cells
    return marked


def _gather(grid: torch.Tensor, index: torch.Tensor, fill: float, offset: tuple[int, int, int] = (0, 0, 0)) -> torch.Tensor:
    """grid (X, Y, Z) values at integer indices (N, 3), `offset` being the index of grid[0, 0, 0]; `fill`
    outside the grid."""
    local = index.to(grid.device, torch.int64) - torch.as_tensor(offset, dtype=torch.int64, device=grid.device)
    shape = torch.as_tensor(grid.shape, device=grid.device)
    inside = ((local >= 0) & (local < shape)).all(dim=1)
    local = torch.where(inside[:, None], local, torch.zeros_like(local))
    flat = (local[:, 0] * grid.shape[1] + local[:, 1]) * grid.shape[2] + local[:, 2]
    values = grid.reshape(-1)[flat]
    return torch.where(inside, values, torch.full_like(values, fill))


def _blocks_without_surface(marked: torch.Tensor, offset: tuple[int, int, int], scale: int) -> tuple[torch.Tensor, tuple[int, int, int]]:
    """Per level block of `scale`^3 fine voxels: 0 if it holds a marked voxel, else 1 -> (grid of blocks,
    level index of its first block). The grid is padded so its first voxel sits on a block boundary."""
    front = [o % scale for o in offset]  # fine voxels of padding before the grid, to a block boundary
    first = tuple((o - f) // scale for o, f in zip(offset, front))
    back = [(-(n + f)) % scale for n, f in zip(marked.shape, front)]
    empty = (~marked).to(torch.float32)
    padded = torch.nn.functional.pad(empty, (front[2], back[2], front[1], back[1], front[0], back[0]), value=1.0)
    pooled = -torch.nn.functional.max_pool3d(-padded[None, None], kernel_size=scale, stride=scale)[0, 0]
    return pooled, first


@dataclass
class LevelEvidence:
    """Stereo evidence of one level's N voxels, as `VortxNet.level_step` takes it.

    tsdf:  (N,) fused stereo TSDF at each voxel: the 3D CNN's extra input channel (the level's own
           truncation above the fine level; at the fine level the classical method's own value).
    start: (N,) the logits an untrained network outputs (`prior_logits`): classical fusion's answer.
    """

    tsdf: torch.Tensor
    start: torch.Tensor

    def __len__(self) -> int:
        return self.tsdf.shape[0]


def prior_logits(level_is_fine: bool, value: torch.Tensor) -> torch.Tensor:
    """The logits an untrained evidence model starts from (its heads' last layers are zero).

    Fine level, value = the classical fused TSDF of the voxel: the logit whose TSDF (1.05 tanh) is that
    TSDF, and for unobserved voxels (+1) UNOBSERVED_START_LOGIT (TSDF 1.01 >= UNOBSERVED_TSDF: no surface
    there, see `meshable_voxels`).
    Coarse and medium, value = the block's `FineFusion.block_surface` (0: it holds a corner of a classical
    surface cell, 1: not): an occupancy logit that keeps exactly those blocks (logit ~+5) and prunes the
    rest (logit just below 0, so a trained head adds a block easily), so the fine level sees every voxel
    the classical surface needs."""
    if level_is_fine:
        logits = torch.atanh((value / TSDF_SCALE).clamp(-0.999, 0.999))
        return torch.where(value >= 1, torch.full_like(logits, UNOBSERVED_START_LOGIT), logits)
    return OCCUPANCY_PRIOR_GAIN * (NEAR_SURFACE - value)
