"""The Capture model: what every loader returns and every later stage consumes.

Conventions (see ../shared/design/architecture.md): metres, world Z up, OpenCV camera axes
(x right, y down, z forward); `pose` is camera-to-world 4x4 float64; `K` is 3x3 float64 in pixels
of the image as it is seen after EXIF orientation is applied.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np


@dataclass
class Frame:
    image_path: Path
    width: int
    height: int
    K: Optional[np.ndarray]  # (3, 3) float64, or None until intrinsics are known (plain photo folder)
    pose: Optional[np.ndarray] = None  # (4, 4) float64 camera-to-world, OpenCV axes, or None
    depth_path: Optional[Path] = None  # metric depth (ScanNet-style 16-bit mm PNG) when the capture has it

    @property
    def name(self) -> str:
        return self.image_path.name

    @property
    def has_pose(self) -> bool:
        return self.pose is not None


@dataclass
class Capture:
    root: Path
    format: str  # "images", "colmap", "transforms", "scannet", "video"
    frames: list[Frame]
    metric: bool = False  # True when poses are already in metres (ScanNet layout, metric transforms.json)
    warnings: list[str] = field(default_factory=list)  # problems the user should know of (skipped frames...)
    notes: list[str] = field(default_factory=list)  # what loading did that is no problem (where derived files went)
    skipped: list[str] = field(default_factory=list)  # file names of the photos left out as unusable (see warnings)
    # Sparse 3D points seen in the photos (a COLMAP model's points3D, an SfM result), in the same world
    # as the poses: they show the scene before reconstructing and let the floor be found. Whatever moves
    # the poses must move them too (`with_points`), so a transform that only replaces frames drops them.
    points: Optional[np.ndarray] = None  # (N, 3) float64, or None when the capture has none
    point_colors: Optional[np.ndarray] = None  # (N, 3) uint8 RGB, with `points`

    @property
    def posed_frames(self) -> list[Frame]:
        return [f for f in self.frames if f.pose is not None]

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) of the first frame; loaders refuse mixed resolutions."""
        return (self.frames[0].width, self.frames[0].height) if self.frames else (0, 0)

    def with_frames(self, frames: list[Frame], **changes) -> "Capture":
        return replace(self, frames=frames, **changes)

    def with_points(self, points: Optional[np.ndarray], colors: Optional[np.ndarray] = None) -> "Capture":
        """The capture with sparse `points` (N, 3) and their `colors` (N, 3) uint8 (grey when None)."""
        if points is None:
            return replace(self, points=None, point_colors=None)
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if colors is None:
            colors = np.full((len(points), 3), 128, dtype=np.uint8)
        colors = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)
        if len(colors) != len(points):
            raise ValueError(f"{len(points)} sparse points but {len(colors)} point colours")
        return replace(self, points=points, point_colors=colors)
