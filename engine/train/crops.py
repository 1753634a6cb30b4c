"""Training crops from rooms (vortx-spec.md section 2).

A room (rooms.py) holds the frames at training resolution and the 4 cm ground-truth TSDF.
One training sample is a random crop of `crop_size` fine voxels:
1. anchor = a random voxel with |tsdf| < 0.999; per-axis offset U(0.04, 0.04*size - 0.04);
   minbound = anchor - offset.
2. augmentation: z-rotation about the anchor, x-mirror (p = 0.5: poses mirrored, images flipped
   horizontally, camera x axis flipped so poses stay proper rotations), two of five photometric
   ops shared by all views (augmentation.py) and optional sensor noise.
3. the ground truth is resampled trilinearly into the crop, except that the nearest value is used
   where |nearest| > 0.999; points outside the volume get +1 (unobserved).
4. occupancy targets by 3x3x3 dilation and strided pick; unobserved z-columns are supervised as
   empty (+1 / occupancy 0); other unseen voxels are ignored (engine/tsdf/targets.py).
5. n views: keyframes that see at least one of every 100th crop voxel, by the rule inference tiles
   use (engine/geometry/view_selection.py), topped up with other frames to exactly n.

Everything about the crop is expressed in the *crop frame*: the world rotated (and mirrored) about
the anchor. The model gets voxel positions `origin + index * voxel_size` (corner convention) and
camera-to-crop-frame poses; it never needs to know about the augmentation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ..geometry.view_selection import select_views, top_up_views
from ..tsdf.targets import SEEN_LIMIT, occupancy_targets
from ..model.outputs import StereoEvidence
from .augmentation import apply_photometric, sample_photometric
from .rooms import RoomData


@dataclass
class CropSettings:
    crop_size: tuple[int, int, int] = (32, 32, 24)
    n_views: int = 8
    rotate: bool = True
    mirror: bool = True
    photometric: bool = True
    noise: float = 0.0
    stereo: bool = False  # give the crop the room's stereo depth maps (the model takes stereo evidence)
    depth_scale: float = 0.1  # FineRecon: half the stereo maps scaled by U(1 - s, 1 + s); 0 = off


@dataclass
class CropTargets:
    """Per-level targets of one crop. Level 0 = coarse 16 cm, 1 = medium 8 cm, 2 = fine 4 cm.

    occ[l] (float, 1 = occupied) and mask[l] (bool, supervised) for l = 0, 1; tsdf (fine, float) and
    mask[2]. Unsupervised voxels hold an arbitrary target and must be ignored through the mask."""

    tsdf: torch.Tensor
    occ: list[torch.Tensor]
    mask: list[torch.Tensor]


def crop_targets(tsdf_04: torch.Tensor) -> CropTargets:
    """Occupancy and TSDF targets from a crop's fine TSDF (X, Y, Z) (engine.tsdf.targets; unseen
    fine voxels get TSDF +1, which only unobserved columns supervise)."""
    levels = occupancy_targets(tsdf_04)
    fine = levels["fine"]
    return CropTargets(
        tsdf=torch.where(fine.seen, tsdf_04, torch.ones_like(tsdf_04)),
        occ=[levels["coarse"].occupied.float(), levels["medium"].occupied.float()],
        mask=[levels["coarse"].supervised, levels["medium"].supervised, fine.supervised],
    )


def crop_transform(anchor: np.ndarray, theta: float, mirror: bool) -> np.ndarray:
    """4x4 world -> crop frame: rotate by theta about the vertical line through the anchor, then
    mirror x about the anchor when `mirror`."""
    c, s = math.cos(theta), math.sin(theta)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)
    if mirror:
        R = np.diag([-1.0, 1.0, 1.0]) @ R
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = anchor - R @ anchor
    return A


def crop_points(origin: np.ndarray, size: Sequence[int], voxel: float, stride: int = 1) -> np.ndarray:
    """(X*Y*Z, 3) corner positions `origin + index * voxel` of a grid, x slowest, z fastest."""
    axes = [np.arange(0, n, stride) * voxel for n in size]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return g + origin


def resample_tsdf(tsdf: np.ndarray, tsdf_origin: np.ndarray, voxel: float, points_world: np.ndarray) -> np.ndarray:
    """TSDF at world points: trilinear, except the nearest value where |nearest| > 0.999;
    points outside the volume get +1 (unobserved)."""
    vol = torch.from_numpy(np.ascontiguousarray(tsdf, dtype=np.float32))[None, None]
    idx = (points_world - tsdf_origin) / voxel  # fractional index (x, y, z)
    dims = np.array(tsdf.shape, dtype=np.float64)
    norm = 2.0 * idx / np.maximum(dims - 1, 1) - 1.0
    # grid_sample wants (x=W=last dim, y=H, z=D=first dim) ordering of the volume (D, H, W) = (X, Y, Z)
    grid = torch.from_numpy(norm[:, ::-1].copy()).float().view(1, -1, 1, 1, 3)
    lin = F.grid_sample(vol, grid, mode="bilinear", padding_mode="border", align_corners=True).view(-1)
    near = F.grid_sample(vol, grid, mode="nearest", padding_mode="border", align_corners=True).view(-1)
    out = torch.where(near.abs() > SEEN_LIMIT, near, lin)
    inside = torch.from_numpy(np.all((idx >= -1e-6) & (idx <= dims - 1 + 1e-6), axis=1))
    out = torch.where(inside, out, torch.ones_like(out))
    return out.numpy()


VIEW_POINT_STRIDE = 100  # a crop's views must see one of every 100th of its voxels (spec section 2)


def choose_crop_views(room: RoomData, points_world: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly n frame indices, sorted: up to n keyframes that see one of `points_world` (the shared
    rule, engine.geometry.view_selection.select_views), topped up with random other frames."""
    H, W = room.image_hw
    sizes = np.broadcast_to(np.array([W, H]), (len(room.poses), 2))
    chosen = select_views(points_world, room.K, room.poses, sizes, room.keyframes, n, rng)
    return top_up_views(chosen, len(room.poses), n, rng)


@dataclass
class CropSample:
    images: torch.Tensor  # (V, 3, H, W) float32 RGB 0-255
    depths: torch.Tensor  # (V, H, W) float32 metres, 0 = none
    K: torch.Tensor  # (V, 3, 3) float32, pixels of `images`
    poses: torch.Tensor  # (V, 4, 4) float32 camera-to-crop-frame
    origin: torch.Tensor  # (3,) crop-frame position of fine voxel (0, 0, 0) (its corner)
    targets: CropTargets
    voxel_size: float  # fine voxel edge in metres (the room's ground-truth TSDF's)
    info: dict = field(default_factory=dict)
    stereo: Optional[StereoEvidence] = None  # all the room's stereo maps, crop frame
    stereo_views: Optional[torch.Tensor] = None  # (V,) int64 map of each view, -1 = none


def make_crop(room: RoomData, settings: CropSettings, rng: np.random.Generator) -> CropSample:
    """One random training crop of `room` (see the module docstring)."""
    voxel = room.voxel_size
    size = np.array(settings.crop_size)
    cands = room.anchor_candidates()
    anchor = room.tsdf_origin + cands[rng.integers(len(cands))] * voxel
    offset = rng.uniform(voxel, voxel * size - voxel)
    minbound = anchor - offset
    theta = float(rng.uniform(0, 2 * math.pi)) if settings.rotate else 0.0
    mirror = bool(rng.random() < 0.5) if settings.mirror else False
    A = crop_transform(anchor, theta, mirror)
    A_inv = np.linalg.inv(A)

    pts_crop = crop_points(minbound, settings.crop_size, voxel)
    pts_world = pts_crop @ A_inv[:3, :3].T + A_inv[:3, 3]
    tsdf = resample_tsdf(room.tsdf, room.tsdf_origin, voxel, pts_world).reshape(tuple(settings.crop_size))
    targets = crop_targets(torch.from_numpy(tsdf))

    views = choose_crop_views(room, pts_world[::VIEW_POINT_STRIDE], settings.n_views, rng)
    images = room.images[views]
    depths = room.depths[views].copy()
    K = room.K[views].copy()
    poses = A[None] @ room.poses[views]
    if settings.photometric:
        images = apply_photometric(images, sample_photometric(rng, settings.noise), rng)
    elif settings.noise > 0:
        images = apply_photometric(images, [("noise", float(rng.uniform(0, settings.noise)))], rng)
    else:
        images = images.astype(np.float32)
    if mirror:
        W = images.shape[2]
        images = images[:, :, ::-1]
        depths = depths[:, :, ::-1]
        K[:, 0, 2] = W - K[:, 0, 2]  # pixel j covers [j, j+1): the flip maps u to W - u
        poses = poses @ np.diag([-1.0, 1.0, 1.0, 1.0])  # flip the camera x axis: det stays +1
    stereo, stereo_views = None, None
    if settings.stereo:
        if room.stereo is None:
            raise ValueError(f"room {room.name} was loaded without its stereo depth maps")
        stereo = crop_stereo(room, A, mirror, settings.depth_scale, rng)
        stereo_views = torch.from_numpy(room.stereo.map_of_frames(views))
    return CropSample(
        images=torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float(),
        depths=torch.from_numpy(np.ascontiguousarray(depths)).float(),
        K=torch.from_numpy(K).float(),
        poses=torch.from_numpy(poses).float(),
        origin=torch.from_numpy(minbound).float(),
        targets=targets,
        voxel_size=voxel,
        info={"room": room.name, "views": views.tolist(), "theta": theta, "mirror": mirror},
        stereo=stereo,
        stereo_views=stereo_views,
    )


def crop_stereo(room: RoomData, A: np.ndarray, mirror: bool, depth_scale: float, rng: np.random.Generator) -> StereoEvidence:
    """The room's stereo maps in the crop frame (world -> crop transform A, the crop's mirror), with
    FineRecon's depth-scale augmentation: each map with p = 0.5 scaled by U(1 - s, 1 + s), which
    teaches the network that stereo depth can be off by a few per cent, as on real photos."""
    st = room.stereo
    depth = st.depth.copy()
    if depth_scale > 0:
        scaled = rng.random(len(depth)) < 0.5
        factors = rng.uniform(1 - depth_scale, 1 + depth_scale, len(depth))
        depth[scaled] *= factors[scaled, None, None].astype(np.float32)
    confidence, K = st.confidence, st.K.copy()
    poses = A[None] @ room.poses[st.frames]
    if mirror:
        depth, confidence = depth[:, :, ::-1], confidence[:, :, ::-1]
        K[:, 0, 2] = depth.shape[2] - K[:, 0, 2]
        poses = poses @ np.diag([-1.0, 1.0, 1.0, 1.0])
    return StereoEvidence(torch.from_numpy(np.ascontiguousarray(depth)).float(),
                          torch.from_numpy(np.ascontiguousarray(confidence)).float(),
                          torch.from_numpy(K).float(), torch.from_numpy(poses).float())
