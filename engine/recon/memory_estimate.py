"""How much memory a reconstruction needs, before running it.

Peak memory is reached at one level's 3D CNN (usually the fine one) or during fusion, on top of the
process baseline and the 2D feature cache:

    peak = baseline + feature cache + max over levels of
           [level-resident tensors + max(tile views + one fusion chunk, 3D CNN working set)]

Per-voxel constants were measured on CPU with the official widths (engine.model VortxConfig()
defaults) by sampling RSS around single calls (`python -m engine bench` re-checks the model against
measured runs):
- fusion: bytes per (voxel x view) in one `fuse` call, 2048 voxels x 60 views;
- 3D CNN: bytes per voxel of one `level_step` on a surface-like voxel set (~9 neighbours each).
Voxel counts are the uncertain part: they depend on what the weights keep. Two models are offered:
`keep_fractions` (fraction of voxels with logit > 0 at coarse and medium, e.g. measured with random
weights) and `surface_band_voxels` (trained weights keep a band around the surfaces as thick as the
training targets: 3 coarse voxels = 0.48 m, 4 medium voxels = 0.32 m at the default 4 cm).

`estimate_capture_memory` applies the model to one capture under a run's settings and adds the
Blender process and the VR texture bake: the memory a batch run declares per capture on a Ray
cluster (engine/batch/ray_cluster.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ..capture.images import resized_size
from ..geometry.view_selection import select_keyframes
from ..poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from ..poses.prepare import SFM_NEVER, prepare_capture
from .scene_bounds import scene_bounds

FUSION_BYTES_PER_VOXEL_VIEW = (3500, 2100, 1400)  # coarse, medium, fine (C = 80, 40, 24)
CNN_BYTES_PER_VOXEL = (3300, 2400, 1600)  # coarse, medium, fine UNet + head, inference
IMAGE_STRIDES = (16, 8, 4)
FEATURE_CHANNELS = (80, 40, 24)
UNET_BASE_WIDTHS = (32, 16, 8)
BASELINE_BYTES = 650 * 2**20  # python + torch + numpy + the network's weights, measured RSS before a run
# coords int64 x4, points float32 x3, tile ownership/order int64 x2, per voxel
BOOKKEEPING_BYTES_PER_VOXEL = 32 + 12 + 16
BAND_VOXELS = (3, 4)  # occupied band thickness in voxels of the coarse / medium targets (spec section 2)


@dataclass
class MemoryEstimate:
    voxels: tuple[int, int, int]  # voxels fused per level
    components: dict[str, int] = field(default_factory=dict)  # bytes

    @property
    def total(self) -> int:
        return self.components["total"]

    def to_dict(self) -> dict:
        return {"voxels": list(self.voxels), **{k + "_bytes": v for k, v in self.components.items()}}


def box_room_surface_area(size: tuple[float, float, float], furniture_factor: float = 1.25) -> float:
    """Floor + ceiling + walls of a box room (m^2), times a factor for furniture."""
    w, d, h = size
    return (2 * w * d + 2 * (w + d) * h) * furniture_factor


def coarse_voxels(size: tuple[float, float, float], voxel_size: float) -> int:
    """Coarse voxels covering a box of `size` metres (the driver fuses only voxels inside the bounds)."""
    return int(np.prod(np.ceil(np.asarray(size) / (4 * voxel_size))))


def keep_fraction_voxels(coarse: int, keep: tuple[float, float]) -> tuple[int, int, int]:
    """Voxels per level when a fraction keep[l] of level l is kept and upsampled x8."""
    medium = int(8 * keep[0] * coarse)
    return coarse, medium, int(8 * keep[1] * medium)


def surface_band_voxels(coarse: int, area: float, voxel_size: float) -> tuple[int, int, int]:
    """Voxels per level when the weights keep a band of BAND_VOXELS around `area` m^2 of surface."""
    kept_coarse = min(coarse, area * BAND_VOXELS[0] / (4 * voxel_size) ** 2)
    medium = int(8 * kept_coarse)
    kept_medium = min(medium, area * BAND_VOXELS[1] / (2 * voxel_size) ** 2)
    return coarse, medium, int(8 * kept_medium)


def estimate_memory(
    voxels: tuple[int, int, int],
    keyframes: int,
    image_size: tuple[int, int],
    views: int,
    fusion_chunk: int = 2048,
    fp16_features: bool = True,
    baseline: int = BASELINE_BYTES,
) -> MemoryEstimate:
    """Peak bytes of a CPU run (see module doc). image_size = (w, h) fed to the network."""
    w, h = image_size
    per_frame = [c * -(-h // s) * -(-w // s) for c, s in zip(FEATURE_CHANNELS, IMAGE_STRIDES)]
    cache = keyframes * sum(per_frame) * (2 if fp16_features else 4)
    per_level = []
    for level, n in enumerate(voxels):
        if n == 0:  # the run stopped before this level
            per_level.append(0)
            continue
        previous = 0 if level == 0 else 3 * UNET_BASE_WIDTHS[level - 1] + 1
        resident = n * (4 * (FEATURE_CHANNELS[level] + previous) + BOOKKEEPING_BYTES_PER_VOXEL)
        fusion = views * per_frame[level] * 4 + min(fusion_chunk, n) * views * FUSION_BYTES_PER_VOXEL_VIEW[level]
        cnn = n * (CNN_BYTES_PER_VOXEL[level] + 4 * (3 * UNET_BASE_WIDTHS[level] + 1))
        per_level.append(resident + max(fusion, cnn))
    components = {"baseline": baseline, "feature_cache": cache}
    for name, value in zip(("coarse_level", "medium_level", "fine_level"), per_level):
        components[name] = int(value)
    components["total"] = int(baseline + cache + max(per_level))
    return MemoryEstimate(tuple(int(v) for v in voxels), components)  # type: ignore[arg-type]


# --- one capture's batch run (scripts/vortx_batch.py --ray declares it per task) ---------------------

# bpy and the mounted extension beside the engine's BASELINE_BYTES: the batch process on the 8-frame
# test capture (160 x 120, 16 cm, 3 views) peaked at 1.43-1.50 GB RSS, while the estimate above puts
# that reconstruction at ~0.7 GB.
BLENDER_PROCESS_BYTES = 800 * 2**20
# The VR preset's bake (docs/settings.md, texture bench): 1.9 GB at 4096 px and 6.7 GB at 8192 px on the demo
# room, +384 MB over the start at 2048 px: 90-115 bytes per texel, whatever the room.
TEXTURE_BYTES_PER_TEXEL = 115
DEFAULT_IMAGE_LONG_SIDE = 640  # VortxConfig.image_long_side of the shipped (official) weights


def estimate_capture_memory(capture: Any, settings: Any, texture: bool = False,
                            camera_height: Optional[float] = None) -> MemoryEstimate:
    """Peak bytes of one capture's batch run (Blender process, reconstruction, and with `texture` the
    VR preset's bake), planned as Reconstruct plans it, before anything heavy runs.

    A posed capture is put in metres and Z up (`prepare_capture` without structure from motion) and
    its keyframes and scene bounds are the reconstruction's own; an unposed one (structure from
    motion will pose it) counts every frame as a keyframe and the whole `max_room_size` box, the
    most it can become. Voxels follow the trained weights' surface band (`surface_band_voxels`).
    The stereo method is costed as VoRTX: the bench holds its peak within VoRTX's + 1 GiB on the
    same capture (measured +10 MB).
    """
    frames = capture.frames
    if not frames:
        raise ValueError(f"{capture.root}: a capture without frames has no memory estimate")
    if capture.posed_frames and all(f.K is not None for f in capture.posed_frames):
        height = DEFAULT_CAMERA_HEIGHT_M if camera_height is None else camera_height
        prepared = prepare_capture(capture, camera_height=height, sfm=SFM_NEVER).capture
        posed = prepared.posed_frames
        poses = np.stack([f.pose for f in posed]).astype(np.float64)
        kept = select_keyframes(poses, settings.keyframe_translation, settings.keyframe_angle_deg)
        Ks = np.stack([posed[int(k)].K for k in kept]).astype(np.float64)
        sizes = np.array([[posed[int(k)].width, posed[int(k)].height] for k in kept])
        bounds = scene_bounds(Ks, poses[kept], sizes, settings.frustum_depth, settings.max_room_size,
                              points=prepared.points)  # as plan_reconstruction bounds it
        room, keyframes = tuple(float(s) for s in bounds.size), len(kept)
    else:
        room, keyframes = tuple(float(s) for s in settings.max_room_size), len(frames)
    coarse = coarse_voxels(room, settings.voxel_size)  # type: ignore[arg-type]
    voxels = surface_band_voxels(coarse, box_room_surface_area(room), settings.voxel_size)  # type: ignore[arg-type]
    width, height_px = frames[0].width, frames[0].height
    image = resized_size(width, height_px, settings.image_long_side or DEFAULT_IMAGE_LONG_SIDE)
    estimate = estimate_memory(voxels, keyframes, image, min(settings.views, keyframes), settings.fusion_chunk,
                               settings.fp16_features)
    bake = BASELINE_BYTES + TEXTURE_BYTES_PER_TEXEL * settings.texture_size ** 2 if texture else 0
    estimate.components["reconstruction"] = estimate.components["total"]
    estimate.components["texture_bake"] = bake
    estimate.components["blender"] = BLENDER_PROCESS_BYTES
    estimate.components["total"] = BLENDER_PROCESS_BYTES + max(estimate.components["reconstruction"], bake)
    return estimate
