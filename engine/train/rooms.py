"""Rooms at training resolution: the rendered frames, cameras and ground-truth TSDF a crop is cut from.

A room is a folder in the ScanNet layout written by `engine.data` (colour, metric depth, poses,
intrinsics, `mesh_gt.ply`) with its 4 cm ground-truth TSDF (engine/data/room_folders.py). Loading
resizes the frames once; crops (crops.py) then read only memory. Keyframes follow the rule shared
with inference (engine/geometry/view_selection.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from ..capture import load_capture, load_depth, load_image
from ..data.room_folders import gt_path
from ..errors import VortxError
from ..geometry.cameras import scale_intrinsics
from ..geometry.view_selection import select_keyframes
from ..tsdf.targets import SEEN_LIMIT
from ..tsdf.volume import TsdfVolume
from .room_stereo import RoomStereo, load_or_compute_room_stereo


@dataclass
class RoomData:
    """Everything a crop needs from one room, at training resolution.

    images (F, H, W, 3) uint8 RGB, depths (F, H, W) float32 metres (0 = none), K (F, 3, 3) in
    pixels of these images, poses (F, 4, 4) camera-to-world (OpenCV axes), tsdf (X, Y, Z) float32
    with the spec's sign convention, tsdf_origin (3,) world position of voxel (0, 0, 0); stereo:
    the room's plane-sweep depth maps (room_stereo.py) when the model takes stereo evidence."""

    name: str
    images: np.ndarray
    depths: np.ndarray
    K: np.ndarray
    poses: np.ndarray
    tsdf: np.ndarray
    tsdf_origin: np.ndarray
    voxel_size: float = 0.04
    keyframes: Optional[np.ndarray] = None
    stereo: Optional[RoomStereo] = None
    _candidates: Optional[np.ndarray] = field(default=None, repr=False)

    def __post_init__(self):
        if self.keyframes is None:
            self.keyframes = select_keyframes(self.poses)

    @property
    def image_hw(self) -> tuple[int, int]:
        return self.images.shape[1], self.images.shape[2]

    def anchor_candidates(self) -> np.ndarray:
        if self._candidates is None:
            self._candidates = np.argwhere(np.abs(self.tsdf) < SEEN_LIMIT).astype(np.int32)
            if len(self._candidates) == 0:
                raise VortxError(f"room {self.name}: the ground-truth TSDF has no surface voxel")
        return self._candidates


def load_room(room: Path, image_size: tuple[int, int], stereo: bool = False) -> RoomData:
    """Load a rendered room at training resolution `image_size` = (W, H); with `stereo`, also its
    stereo depth maps (computed and cached on first use)."""
    room = Path(room)
    gt = gt_path(room)
    if gt is None:
        raise VortxError(f"room {room} has no ground-truth TSDF; run `python -m engine train CONFIG --precompute-only` first")

    volume = TsdfVolume.load(gt)
    capture = load_capture(room)
    frames = [f for f in capture.frames if f.pose is not None and f.depth_path is not None]
    if not frames:
        raise VortxError(f"room {room}: no frame has both a pose and a depth map")
    W, H = image_size
    images, depths, Ks, poses = [], [], [], []
    for f in frames:
        img = load_image(f.image_path)
        h0, w0 = img.shape[:2]
        images.append(cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA))
        d = load_depth(f.depth_path)
        depths.append(cv2.resize(d, (W, H), interpolation=cv2.INTER_NEAREST))
        Ks.append(scale_intrinsics(f.K, (w0, h0), (W, H)))
        poses.append(np.asarray(f.pose, dtype=np.float64))
    return RoomData(
        name=room.name,
        images=np.stack(images),
        depths=np.stack(depths),
        K=np.stack(Ks),
        poses=np.stack(poses),
        tsdf=volume.tsdf.astype(np.float32),
        tsdf_origin=np.asarray(volume.origin, np.float64),
        voxel_size=float(volume.voxel_size),
        stereo=load_or_compute_room_stereo(room, frames=frames) if stereo else None,
    )
