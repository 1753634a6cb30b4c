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


@dataclass(frozen=True)
class SensorDepth:
    """A depth sensor's map of one frame (a phone's LiDAR), registered to that frame's photo: the same
    camera, at any resolution of the photo's aspect ratio (K scales with it). An input of the
    reconstruction, unlike `Frame.depth_path`, which is ground truth for evaluation only.
    Read with `engine.capture.sensor_depth.read_sensor_depth`."""

    path: Path
    encoding: str  # one of sensor_depth.ENCODINGS: "png_mm" (16-bit millimetres), "r3d" (LZFSE float32 metres)
    confidence_path: Optional[Path] = None  # per-pixel confidence, ARKit's 0 low / 1 medium / 2 high
    size: Optional[tuple[int, int]] = None  # (width, height), for encodings that do not store it ("r3d")
    # The stored value of "high" confidence: 2 for ARKit's levels as most apps store them, 255 for
    # Polycam's 0 / 127 / 255; read back as ARKit's 0 / 1 / 2 either way.
    confidence_high: int = 2

    def to_dict(self) -> dict:
        """Plain JSON-able data (paths as strings), e.g. for a Blender camera's custom property."""
        return {"path": str(self.path), "encoding": self.encoding,
                "confidence_path": str(self.confidence_path) if self.confidence_path is not None else None,
                "size": list(self.size) if self.size is not None else None, "confidence_high": self.confidence_high}

    @classmethod
    def from_dict(cls, data: dict) -> "SensorDepth":
        """The inverse of `to_dict`."""
        return cls(Path(data["path"]), str(data["encoding"]),
                   Path(data["confidence_path"]) if data.get("confidence_path") else None,
                   tuple(int(v) for v in data["size"]) if data.get("size") else None,  # type: ignore[arg-type]
                   int(data.get("confidence_high", 2)))


@dataclass
class Frame:
    image_path: Path
    width: int
    height: int
    K: Optional[np.ndarray]  # (3, 3) float64, or None until intrinsics are known (plain photo folder)
    pose: Optional[np.ndarray] = None  # (4, 4) float64 camera-to-world, OpenCV axes, or None
    depth_path: Optional[Path] = None  # ground-truth metric depth (ScanNet-style 16-bit mm PNG), evaluation only
    sensor_depth: Optional[SensorDepth] = None  # the phone's own depth map, used by the reconstruction

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
    # Who made the poses, when the format says it: "ARKit (3D Scanner App)". Reports say it beside the
    # pose count; "" for formats that do not say (a COLMAP model, a transforms.json).
    pose_origin: str = ""

    @property
    def frames_with_sensor_depth(self) -> int:
        return sum(f.sensor_depth is not None for f in self.frames)

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
