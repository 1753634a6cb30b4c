"""The reconstruction plan: keyframes, scene bounds, tiles and each tile's views.

Everything here is numpy-only and cheap (no images are read), so Blender can build the plan first,
draw the tile overlay at once, and pass the same plan to `reconstruct`, whose tile states then
change in place as the run progresses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..capture import Capture, Frame
from ..errors import CaptureError, PoseError
from ..jobs import CancelToken, ProgressCallback, check, report
from ..geometry.view_selection import select_keyframes
from .scene_bounds import SceneBounds, scene_bounds
from .settings import ReconSettings
from .tiles import Tile, TileState, VoxelGrid, make_tiles, select_views_for_tile


@dataclass
class ReconPlan:
    keyframes: list[Frame]  # the frames fused, in capture order
    keyframe_ids: list[int]  # their positions in capture.frames
    Ks: np.ndarray  # (V, 3, 3) pixels of the images on disk
    poses: np.ndarray  # (V, 4, 4) camera-to-world
    sizes: np.ndarray  # (V, 2) (width, height) on disk
    bounds: SceneBounds
    grid: VoxelGrid
    tiles: list[Tile]  # tile.views index into `keyframes`
    warnings: list[str] = field(default_factory=list)

    @property
    def active_tiles(self) -> list[Tile]:
        return [t for t in self.tiles if len(t.views)]


def posed_frames(capture: Capture) -> tuple[list[int], list[str]]:
    """Positions of the usable frames and warnings about the rest; raises when none is usable."""
    if not capture.frames:
        raise CaptureError(f"{capture.root}: the capture has no frames")
    usable, warnings = [], []
    unposed = [f.name for f in capture.frames if f.pose is None]
    for i, frame in enumerate(capture.frames):
        if frame.pose is None or frame.K is None:
            continue
        if not (np.all(np.isfinite(frame.pose)) and np.all(np.isfinite(frame.K))):
            warnings.append(f"{frame.name}: pose or intrinsics are not finite; skipped")
            continue
        usable.append(i)
    if not usable:
        if unposed:
            raise PoseError(
                f"{capture.root}: none of the {len(capture.frames)} frames has a camera pose. "
                "Run pose estimation first (`python -m engine poses`, or Estimate Poses in Blender)."
            )
        raise PoseError(f"{capture.root}: no frame has camera intrinsics (K). Run pose estimation first, which estimates them.")
    if unposed:
        shown = ", ".join(unposed[:5]) + (" ..." if len(unposed) > 5 else "")
        warnings.append(f"{len(unposed)} of {len(capture.frames)} frames have no pose and are not used: {shown}")
    return usable, warnings


def plan_reconstruction(
    capture: Capture,
    settings: ReconSettings,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> ReconPlan:
    """Keyframes (spec section 2), bounds and tiles, and up to `settings.views` views per tile."""
    settings.validate()
    usable, warnings = posed_frames(capture)
    report(progress, "keyframes", 0, 1)
    all_poses = np.stack([capture.frames[i].pose for i in usable]).astype(np.float64)
    kept = select_keyframes(all_poses, settings.keyframe_translation, settings.keyframe_angle_deg)
    ids = [usable[int(k)] for k in kept]
    frames = [capture.frames[i] for i in ids]
    Ks = np.stack([f.K for f in frames]).astype(np.float64)
    poses = all_poses[kept]
    sizes = np.array([[f.width, f.height] for f in frames], dtype=np.int64)
    report(progress, "keyframes", 1, 1)

    # The sparse points (SfM's, a COLMAP model's, the refinement's) say how large the room is; the
    # frusta only say where the cameras could see (scene_bounds.py).
    bounds = scene_bounds(Ks, poses, sizes, settings.frustum_depth, settings.max_room_size, points=capture.points)
    grid, tiles = make_tiles(bounds, settings.voxel_size, settings.tile_size, settings.tile_height)
    for t, tile in enumerate(tiles):
        check(cancel)
        report(progress, "view selection", t, len(tiles))
        tile.views = select_views_for_tile(tile, grid, Ks, poses, sizes, settings.views, settings.seed, within=bounds)
        if len(tile.views) == 0:
            tile.state = TileState.EMPTY
    report(progress, "view selection", len(tiles), len(tiles))
    return ReconPlan(frames, ids, Ks, poses, sizes, bounds, grid, tiles, warnings)
