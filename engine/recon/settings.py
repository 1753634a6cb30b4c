"""ReconSettings: every knob of a reconstruction run, in one JSON-serialisable dataclass.

Defaults follow the official VoRTX inference (vortx-spec.md section 4): 4 cm finest voxels, 60 views
per tile, 96 x 96 x 48 fine-voxel tiles, seed 0, NeuralRecon keyframe thresholds. The engine-only
knobs (chunk sizes, colour views, room clipping) bound memory and time on a laptop CPU.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Optional

from ..errors import VortxError

# Each level is twice as coarse as the next: coarse / medium / fine = 4x / 2x / 1x the finest voxel.
LEVEL_SCALES: tuple[int, int, int] = (4, 2, 1)
COARSE_FACTOR = LEVEL_SCALES[0]


def level_voxel_sizes(voxel_size: float) -> tuple[float, float, float]:
    """(coarse, medium, fine) voxel sizes in metres for a finest voxel size."""
    return tuple(voxel_size * s for s in LEVEL_SCALES)  # type: ignore[return-value]


def level_label(voxel_size: float) -> str:
    """A level's name as the user reads it: 0.16 -> "16 cm"."""
    return f"{round(voxel_size * 100, 2):g} cm"


@dataclass
class ReconSettings:
    # "random" = randomly initialised network (seeded), None = the default weights shipped with the
    # extension, anything else = a path to a .safetensors file (with its JSON config beside it).
    weights: Optional[str] = None
    voxel_size: float = 0.04  # finest level, metres
    views: int = 60  # keyframes per tile (N)
    tile_size: int = 96  # tile width and depth in fine voxels
    tile_height: int = 48  # tile height in fine voxels (the training crop's height)
    device: str = "cpu"  # "cpu" or "cuda"
    seed: int = 0  # view sampling and random weights
    keyframe_translation: float = 0.1  # metres since the last kept keyframe
    keyframe_angle_deg: float = 15.0  # optical-axis angle since the last kept keyframe
    frustum_depth: float = 4.0  # scene bounds = camera frusta cut at this depth (official: 4 m)
    # Bounds larger than this (metres, x/y/z) are clipped around the median camera centre, so one
    # bad pose or a camera looking down a corridor cannot blow the voxel grid up to city size.
    max_room_size: tuple[float, float, float] = (20.0, 20.0, 6.0)
    # Long side in pixels the photos are resized to for the 2D CNN; None = the size the weights were
    # trained at (VortxConfig.image_long_side: 640 for the official model).
    image_long_side: Optional[int] = None
    feature_chunk: int = 4  # images per 2D CNN call (measured fastest on CPU, platform-notes section 4)
    fusion_chunk: int = 2048  # voxels per fusion call: fusion memory is O(chunk x views^2)
    fp16_features: bool = True  # cache 2D features as fp16 on the CPU (halves the cache; official does this)
    colour: bool = True  # colour the vertices from the photos
    colour_views: int = 40  # keyframes (evenly spaced) used for vertex colours

    @property
    def level_voxel_sizes(self) -> tuple[float, float, float]:
        return level_voxel_sizes(self.voxel_size)

    def validate(self) -> None:
        """Raise VortxError naming the setting at fault."""
        if not self.voxel_size > 0:
            raise VortxError(f"voxel size must be positive, got {self.voxel_size}")
        if self.views < 1:
            raise VortxError(f"views per tile must be at least 1, got {self.views}")
        for name in ("tile_size", "tile_height"):
            value = getattr(self, name)
            # Tiles must hold whole coarse voxels, so the coarse grid and every tile stay aligned.
            if value < COARSE_FACTOR or value % COARSE_FACTOR:
                raise VortxError(f"{name.replace('_', ' ')} must be a positive multiple of {COARSE_FACTOR} voxels, got {value}")
        if self.device not in ("cpu", "cuda") and not self.device.startswith("cuda:"):
            raise VortxError(f"device must be 'cpu' or 'cuda', got {self.device!r}")
        if self.image_long_side is not None and self.image_long_side < 32:
            raise VortxError(f"image long side must be at least 32 pixels, got {self.image_long_side}")
        if self.feature_chunk < 1 or self.fusion_chunk < 1:
            raise VortxError("feature and fusion chunk sizes must be at least 1")
        if self.keyframe_translation < 0 or self.keyframe_angle_deg < 0:
            raise VortxError("keyframe thresholds cannot be negative")
        if min(self.max_room_size) <= 0 or self.frustum_depth <= 0:
            raise VortxError("maximum room size and frustum depth must be positive")

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["max_room_size"] = list(self.max_room_size)
        return data
