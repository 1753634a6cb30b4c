"""Training crops from rendered rooms (vortx-spec.md section 2).

A room is a folder in the ScanNet layout written by `engine.data` (colour, metric depth, poses,
intrinsics, `mesh_gt.ply`). Its ground-truth TSDF at 4 cm is fused once by `precompute_room`
(`engine.tsdf`) and saved beside it as `tsdf_gt_04.npz` (unless the renderer already wrote
`tsdf_gt.npz`, fused from its exact float depth), so training never re-fuses.

One training sample is a random crop of `crop_size` fine voxels:
1. anchor = a random voxel with |tsdf| < 0.999; per-axis offset U(0.04, 0.04*size - 0.04);
   minbound = anchor - offset.
2. augmentation: z-rotation about the anchor, x-mirror (p = 0.5: poses mirrored, images flipped
   horizontally, camera x axis flipped so poses stay proper rotations), two of five photometric
   ops shared by all views (brightness, contrast, saturation, hue, blur) and optional sensor noise.
3. the ground truth is resampled trilinearly into the crop, except that the nearest value is used
   where |nearest| > 0.999; points outside the volume get +1 (unobserved).
4. occupancy targets by 3x3x3 dilation and strided pick; unobserved z-columns are supervised as
   empty (+1 / occupancy 0); other unseen voxels are ignored.
5. n views chosen as in the spec (keyframes that see at least one of every 100th crop voxel).

Everything about the crop is expressed in the *crop frame*: the world rotated (and mirrored) about
the anchor. The model gets voxel positions `origin + index * voxel_size` (corner convention) and
camera-to-crop-frame poses; it never needs to know about the augmentation.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ..data.room_folders import find_rooms, gt_path, precompute_room  # noqa: F401 (re-exported until the split)
from ..errors import VortxError
from ..geometry.cameras import look_along, project_points, scale_intrinsics

UNSEEN = 0.999  # |tsdf| at or above this counts as truncated / unobserved


# --------------------------------------------------------------------------------------------
# Rooms


@dataclass
class RoomData:
    """Everything a crop needs from one room, at training resolution.

    images (F, H, W, 3) uint8 RGB, depths (F, H, W) float32 metres (0 = none), K (F, 3, 3) in
    pixels of these images, poses (F, 4, 4) camera-to-world (OpenCV axes), tsdf (X, Y, Z) float32
    with the spec's sign convention, tsdf_origin (3,) world position of voxel (0, 0, 0)."""

    name: str
    images: np.ndarray
    depths: np.ndarray
    K: np.ndarray
    poses: np.ndarray
    tsdf: np.ndarray
    tsdf_origin: np.ndarray
    voxel_size: float = 0.04
    keyframes: Optional[np.ndarray] = None
    _candidates: Optional[np.ndarray] = field(default=None, repr=False)

    def __post_init__(self):
        if self.keyframes is None:
            self.keyframes = select_keyframes(self.poses)

    @property
    def image_hw(self) -> tuple[int, int]:
        return self.images.shape[1], self.images.shape[2]

    def anchor_candidates(self) -> np.ndarray:
        if self._candidates is None:
            self._candidates = np.argwhere(np.abs(self.tsdf) < UNSEEN).astype(np.int32)
            if len(self._candidates) == 0:
                raise VortxError(f"room {self.name}: the ground-truth TSDF has no surface voxel")
        return self._candidates


def select_keyframes(poses: np.ndarray, min_translation: float = 0.1, min_angle_deg: float = 15.0) -> np.ndarray:
    """Indices of keyframes: kept when, against the last kept frame, the camera moved > 0.1 m or
    the optical axis turned > 15 degrees (NeuralRecon rule, spec section 2)."""
    kept = []
    cos_limit = math.cos(math.radians(min_angle_deg))
    for i, pose in enumerate(poses):
        if not np.all(np.isfinite(pose)):
            continue
        if not kept:
            kept.append(i)
            continue
        last = poses[kept[-1]]
        moved = np.linalg.norm(pose[:3, 3] - last[:3, 3]) > min_translation
        turned = float(np.dot(pose[:3, 2], last[:3, 2])) < cos_limit
        if moved or turned:
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)


def load_room(room: Path, image_size: tuple[int, int]) -> RoomData:
    """Load a rendered room at training resolution `image_size` = (W, H)."""
    import cv2

    from ..capture import load_capture, load_depth, load_image

    room = Path(room)
    gt = gt_path(room)
    if gt is None:
        raise VortxError(f"room {room} has no ground-truth TSDF; run `python -m engine train CONFIG --precompute-only` first")
    from ..tsdf.volume import TsdfVolume

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
    )


# --------------------------------------------------------------------------------------------
# Targets


def dilate3(mask: torch.Tensor) -> torch.Tensor:
    """3x3x3 binary dilation of a (X, Y, Z) bool grid (outside counts as False)."""
    return F.max_pool3d(mask[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0


def unobserved_columns(seen: torch.Tensor) -> torch.Tensor:
    """(X, Y, Z) bool: voxels whose whole z-column is unobserved (Atlas heads3d rule)."""
    return (~seen.any(dim=2, keepdim=True)).expand_as(seen)


@dataclass
class CropTargets:
    """Per-level targets of one crop. Level 0 = coarse 16 cm, 1 = medium 8 cm, 2 = fine 4 cm.

    occ[l] (float, 1 = occupied) and mask[l] (bool, supervised) for l = 0, 1; tsdf (fine, float) and
    mask[2]. Unsupervised voxels hold an arbitrary target and must be ignored through the mask."""

    tsdf: torch.Tensor
    occ: list[torch.Tensor]
    mask: list[torch.Tensor]


def make_targets(tsdf_04: torch.Tensor) -> CropTargets:
    """Occupancy and TSDF targets from a crop's fine TSDF (spec section 2, steps 4-5)."""
    occ_04 = tsdf_04.abs() < UNSEEN
    seen_04 = tsdf_04 < UNSEEN
    fine_mask = seen_04 | unobserved_columns(seen_04)
    fine_tsdf = torch.where(seen_04, tsdf_04, torch.ones_like(tsdf_04))

    occs, masks = [], []
    occ, seen = occ_04, seen_04
    for _ in range(2):  # 08 from 04, then 16 from 08
        dil = dilate3(occ)
        occ_next = dil[::2, ::2, ::2]
        notocc_next = (seen & ~dil)[::2, ::2, ::2]
        seen_next = seen[::2, ::2, ::2] | occ_next
        mask = occ_next | notocc_next | unobserved_columns(seen_next)
        occs.append(occ_next.float())
        masks.append(mask)
        occ, seen = occ_next, seen_next
    # occs/masks are [08, 16]; store coarse first
    return CropTargets(tsdf=fine_tsdf, occ=[occs[1], occs[0]], mask=[masks[1], masks[0], fine_mask])


# --------------------------------------------------------------------------------------------
# Crop geometry


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
    out = torch.where(near.abs() > UNSEEN, near, lin)
    inside = torch.from_numpy(np.all((idx >= -1e-6) & (idx <= dims - 1 + 1e-6), axis=1))
    out = torch.where(inside, out, torch.ones_like(out))
    return out.numpy()


def select_views(
    room: RoomData, points_world: np.ndarray, n: int, rng: np.random.Generator
) -> np.ndarray:
    """n frame indices (spec section 2): n keyframes sampled uniformly without replacement among
    those whose frustum (0 < u < W, 0 < v < H, z > 0) holds at least one of every 100th crop point;
    topped up with random other frames when too few qualify."""
    keyframes = room.keyframes
    n_frames = len(room.poses)
    H, W = room.image_hw
    if len(keyframes) < n:
        chosen = list(keyframes)
    else:
        pts = points_world[::100]
        u, v, z = project_points(pts, room.K[keyframes], room.poses[keyframes])
        inside = ((u > 0) & (u < W) & (v > 0) & (v < H) & (z > 0)).any(axis=1)
        ok = keyframes[inside]
        chosen = list(rng.choice(ok, size=min(n, len(ok)), replace=False)) if len(ok) else []
    if len(chosen) < n:
        rest = np.setdiff1d(np.arange(n_frames), np.asarray(chosen, dtype=np.int64))
        extra = rng.choice(rest, size=min(n - len(chosen), len(rest)), replace=False)
        chosen += list(extra)
    if len(chosen) < n:  # a room with fewer than n frames: repeat some
        chosen += list(rng.choice(np.asarray(chosen), size=n - len(chosen), replace=True))
    return np.sort(np.asarray(chosen, dtype=np.int64))


# --------------------------------------------------------------------------------------------
# Photometric augmentation (the same for every view of a crop)

PHOTOMETRIC_OPS = ("brightness", "contrast", "saturation", "hue", "blur")


def sample_photometric(rng: np.random.Generator, noise: float = 0.0) -> list[tuple[str, float]]:
    """Two of the five ops with their parameters, plus sensor noise with p = 0.5 when enabled."""
    ops = []
    for i in rng.choice(len(PHOTOMETRIC_OPS), size=2, replace=False):
        name = PHOTOMETRIC_OPS[int(i)]
        if name in ("brightness", "contrast", "saturation"):
            ops.append((name, float(rng.uniform(0.5, 1.5))))
        elif name == "hue":
            ops.append((name, float(rng.uniform(-0.05, 0.05))))
        else:
            ops.append((name, float(rng.choice([1.0, 2.0, 3.0]))))
    if noise > 0 and rng.random() < 0.5:
        ops.append(("noise", float(rng.uniform(0.0, noise))))
    return ops


def apply_photometric(images: np.ndarray, ops: list[tuple[str, float]], rng: np.random.Generator) -> np.ndarray:
    """Apply ops to (V, H, W, 3) uint8 RGB; returns float32 0-255."""
    import cv2

    x = images.astype(np.float32)
    for name, p in ops:
        gray = (x @ np.array([0.299, 0.587, 0.114], dtype=np.float32))[..., None]
        if name == "brightness":
            x = x * p
        elif name == "contrast":
            x = (x - gray.mean(axis=(1, 2, 3), keepdims=True)) * p + gray.mean(axis=(1, 2, 3), keepdims=True)
        elif name == "saturation":
            x = gray + (x - gray) * p
        elif name == "hue":
            out = []
            for img in np.clip(x, 0, 255).astype(np.uint8):
                hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV_FULL).astype(np.int32)
                hsv[..., 0] = (hsv[..., 0] + int(round(p * 256))) % 256
                out.append(cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB_FULL))
            x = np.stack(out).astype(np.float32)
        elif name == "blur":
            x = np.stack([cv2.GaussianBlur(img, (7, 7), p) for img in x])
        elif name == "noise":
            x = x + rng.normal(0.0, p, size=x.shape).astype(np.float32)
        x = np.clip(x, 0, 255)
    return x


# --------------------------------------------------------------------------------------------
# Samples and batches


@dataclass
class CropSample:
    images: torch.Tensor  # (V, 3, H, W) float32 RGB 0-255
    depths: torch.Tensor  # (V, H, W) float32 metres, 0 = none
    K: torch.Tensor  # (V, 3, 3) float32, pixels of `images`
    poses: torch.Tensor  # (V, 4, 4) float32 camera-to-crop-frame
    origin: torch.Tensor  # (3,) crop-frame position of fine voxel (0, 0, 0) (its corner)
    targets: CropTargets
    info: dict = field(default_factory=dict)


@dataclass
class TrainBatch:
    """A batch of B crops with V views each (all crops share crop_size and image size).

    images (B, V, 3, H, W) RGB 0-255; depths (B, V, H, W) metres; K (B, V, 3, 3); poses (B, V, 4, 4)
    camera-to-crop-frame; origin (B, 3); crop_size (X, Y, Z) fine voxels; voxel_size (fine);
    tsdf (B, X, Y, Z) fine targets; occ[l] (B, X_l, Y_l, Z_l) for l = 0 coarse, 1 medium;
    mask[l] for l = 0, 1, 2 (bool, supervised)."""

    images: torch.Tensor
    depths: torch.Tensor
    K: torch.Tensor
    poses: torch.Tensor
    origin: torch.Tensor
    crop_size: tuple[int, int, int]
    voxel_size: float
    tsdf: torch.Tensor
    occ: list[torch.Tensor]
    mask: list[torch.Tensor]
    info: list[dict] = field(default_factory=list)

    @property
    def batch_size(self) -> int:
        return self.images.shape[0]

    def to(self, device) -> "TrainBatch":
        mv = lambda t: t.to(device, non_blocking=True)  # noqa: E731
        return TrainBatch(
            mv(self.images), mv(self.depths), mv(self.K), mv(self.poses), mv(self.origin), self.crop_size,
            self.voxel_size, mv(self.tsdf), [mv(o) for o in self.occ], [mv(m) for m in self.mask], self.info,
        )


def collate(samples: Sequence[CropSample], crop_size, voxel_size: float) -> TrainBatch:
    return TrainBatch(
        images=torch.stack([s.images for s in samples]),
        depths=torch.stack([s.depths for s in samples]),
        K=torch.stack([s.K for s in samples]),
        poses=torch.stack([s.poses for s in samples]),
        origin=torch.stack([s.origin for s in samples]),
        crop_size=tuple(crop_size),
        voxel_size=voxel_size,
        tsdf=torch.stack([s.targets.tsdf for s in samples]),
        occ=[torch.stack([s.targets.occ[l] for s in samples]) for l in range(2)],
        mask=[torch.stack([s.targets.mask[l] for s in samples]) for l in range(3)],
        info=[s.info for s in samples],
    )


@dataclass
class CropSettings:
    crop_size: tuple[int, int, int] = (32, 32, 24)
    n_views: int = 8
    rotate: bool = True
    mirror: bool = True
    photometric: bool = True
    noise: float = 0.0


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
    targets = make_targets(torch.from_numpy(tsdf))

    views = select_views(room, pts_world, settings.n_views, rng)
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
    return CropSample(
        images=torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float(),
        depths=torch.from_numpy(np.ascontiguousarray(depths)).float(),
        K=torch.from_numpy(K).float(),
        poses=torch.from_numpy(poses).float(),
        origin=torch.from_numpy(minbound).float(),
        targets=targets,
        info={"room": room.name, "views": views.tolist(), "theta": theta, "mirror": mirror},
    )


class RoomSampler:
    """Infinite, resumable stream of room indices for one rank (DistributedSampler-like): each
    epoch is a seeded permutation of all rooms, padded to a multiple of world_size and sharded
    as perm[rank::world_size]. The position is (epoch, index) and goes into checkpoints."""

    def __init__(self, n_rooms: int, seed: int = 0, rank: int = 0, world_size: int = 1):
        if n_rooms <= 0:
            raise VortxError("no training rooms")
        self.n_rooms, self.seed, self.rank, self.world_size = n_rooms, seed, rank, world_size
        self.epoch, self.index = 0, 0

    def _shard(self, epoch: int) -> np.ndarray:
        perm = np.random.default_rng([self.seed, epoch]).permutation(self.n_rooms)
        pad = (-len(perm)) % self.world_size
        perm = np.concatenate([perm, perm[:pad]])
        return perm[self.rank :: self.world_size]

    def next(self) -> int:
        shard = self._shard(self.epoch)
        if self.index >= len(shard):
            self.epoch, self.index = self.epoch + 1, 0
            shard = self._shard(self.epoch)
        room = int(shard[self.index])
        self.index += 1
        return room

    def state_dict(self) -> dict:
        return {"epoch": self.epoch, "index": self.index}

    def load_state_dict(self, state: dict) -> None:
        self.epoch, self.index = int(state["epoch"]), int(state["index"])


class CropDataset:
    """Rooms (loaded lazily, kept in memory) + crop settings -> batches."""

    def __init__(self, rooms: Sequence[Path | RoomData], settings: CropSettings, image_size=(160, 120), voxel_size=0.04):
        self.sources = list(rooms)
        self.settings = settings
        self.image_size = tuple(image_size)
        self.voxel_size = voxel_size
        self._cache: dict[int, RoomData] = {}

    def __len__(self) -> int:
        return len(self.sources)

    def room(self, i: int) -> RoomData:
        if i not in self._cache:
            src = self.sources[i]
            self._cache[i] = src if isinstance(src, RoomData) else load_room(src, self.image_size)
        return self._cache[i]

    def batch(self, room_ids: Sequence[int], rng: np.random.Generator) -> TrainBatch:
        samples = [make_crop(self.room(i), self.settings, rng) for i in room_ids]
        return collate(samples, self.settings.crop_size, self.voxel_size)


def box_room(
    size=(3.0, 2.6, 2.4), n_frames: int = 12, image_size=(64, 48), voxel: float = 0.04, seed: int = 0,
    trunc: float = 0.12,
) -> RoomData:
    """An analytic box room (no Blender): textured RGB, exact depth, exact TSDF. For tests.

    The room spans [0, size] with walls at its faces; cameras at 1.2 m height on a circle look
    outward at the walls."""
    rng = np.random.default_rng(seed)
    W, H = image_size
    f = 0.8 * W
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    center = np.array(size) / 2
    poses, images, depths = [], [], []
    lo, hi = np.zeros(3), np.array(size)
    uu, vv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)  # pixel centres (pixel j covers [j, j+1))
    rays_cam = np.stack([(uu - K[0, 2]) / f, (vv - K[1, 2]) / f, np.ones_like(uu, dtype=float)], -1)
    for i in range(n_frames):
        a = 2 * math.pi * i / n_frames
        t = center + 0.3 * np.array([math.cos(a), math.sin(a), 0]) + np.array([0, 0, 1.2 - center[2]])
        pose = look_along(t, [math.cos(a), math.sin(a), -0.15])
        R = pose[:3, :3]
        dirs = rays_cam @ R.T  # world directions, z_cam = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            tl = np.where(dirs > 0, (hi - t) / dirs, (lo - t) / dirs)
        tl = np.where(np.isfinite(tl) & (tl > 0), tl, np.inf)
        depth = tl.min(-1)  # planar depth since rays have z_cam = 1
        hit = t + dirs * depth[..., None]
        checker = (np.floor(hit * 4).sum(-1) % 2).astype(np.float32)
        rgb = np.stack([120 + 80 * checker, 100 + 60 * np.sin(hit[..., 0] * 3), 90 + 50 * np.cos(hit[..., 1] * 5)], -1)
        rgb = rgb + rng.normal(0, 3, rgb.shape)
        poses.append(pose)
        images.append(np.clip(rgb, 0, 255).astype(np.uint8))
        depths.append(depth.astype(np.float32))
    # exact TSDF: -min(1, d/trunc) inside (free, observed), behind the walls up to trunc: +d/trunc, else +1
    origin = -np.array([0.2, 0.2, 0.2])
    dims = np.ceil((np.array(size) + 0.4) / voxel).astype(int) + 1
    p = crop_points(origin, dims, voxel).reshape(*dims, 3)
    inside = np.all((p > lo) & (p < hi), -1)
    d_in = np.minimum(p - lo, hi - p).min(-1)
    d_out = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0), axis=-1)
    tsdf = np.where(inside, -np.minimum(1, d_in / trunc), np.where(d_out < trunc, d_out / trunc, 1.0))
    return RoomData(
        name=f"box{seed}", images=np.stack(images), depths=np.stack(depths), K=np.repeat(K[None], n_frames, 0),
        poses=np.stack(poses), tsdf=tsdf.astype(np.float32), tsdf_origin=origin, voxel_size=voxel,
    )
