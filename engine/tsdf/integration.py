"""Ground-truth TSDF fusion, vectorised in torch (CPU or CUDA).

Rules (vortx-spec.md section 2, the NeuralRecon/VoRTX `TSDFVolume` with weight 1):
- depth above `depth_cap` (3 m) and non-finite depth count as missing (0);
- a voxel (corner position, see grid.py) projects to the pixel that contains K @ x_cam; it is updated
  when it lies in the image with z > 0, the depth d there is > 0 and d - z >= -trunc;
- the update is a running mean of min(1, (d - z) / trunc);
- afterwards values < 1 are negated and observed voxels still at exactly 1 become -1.
Result: -1 observed free space, negative in front of a surface, (0, 1] behind it, +1 never observed.

Pixel convention: the engine's K puts pixel (0, 0) over [0, 1)^2 (COLMAP's and Blender's convention,
engine/capture/geometry.py), so the pixel containing u is floor(u). The reference code rounds, which
is the same rule for K written with integer pixel centres (OpenCV's convention).
"""

from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np
import torch

from ..jobs import CancelToken, ProgressCallback, check, report
from ..geometry.cameras import frustum_corners, projection_matrix
from .volume_bounds import frustum_bounds, volume_from_bounds
from .grid import axis_positions
from .volume import TsdfVolume

Device = Union[str, torch.device, None]


def fuse_tsdf(
    depths: Sequence[np.ndarray],
    K: np.ndarray,
    cam_to_world: np.ndarray,
    origin: np.ndarray,
    dims: Sequence[int],
    voxel_size: float = 0.04,
    trunc: float = 0.12,
    depth_cap: Optional[float] = 3.0,
    device: Device = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    evidence: Optional["FusionEvidence"] = None,
    start: Sequence[int] = (0, 0, 0),
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fuse depth maps into a TSDF in the ground-truth sign convention.

    depths: N maps (H, W) in metres, 0 = missing (a sequence: frames are read one at a time, so a
    lazy loader works). K (3, 3) or (N, 3, 3) in pixels of the depth map, pixel centres at integer
    (0, 0) covering [0, 1)^2. cam_to_world (N, 4, 4) OpenCV axes; frames with non-finite poses are skipped.
    origin (3,) world position of voxel (0, 0, 0); dims (X, Y, Z). depth_cap None keeps all depth.
    start (3,): the first fused voxel's index on that lattice, so a block of a larger grid (dims from
    `start`) gets bit for bit the values the whole grid would give its voxels.
    Returns (tsdf, weight), each (X, Y, Z) float32 on `device`; weight counts the frames that updated a voxel.

    evidence: None for the ground-truth rule above (every observation weighs 1, nearest pixel). For
    measured depth, a `FusionEvidence` gives each observation a weight (its pixel's entry in
    `evidence.pixel_weights`: confidence, viewing angle, expected error), looks depth up bilinearly
    where the four neighbouring depths agree (nearest across depth edges), and fills
    `evidence.support`: per voxel, the number of frames whose surface passes within the truncation
    band of it (views that agree a surface is there; free-space observations carve without adding).
    """
    device = torch.device(device) if device is not None else torch.device("cpu")
    n = len(depths)
    Ks = np.broadcast_to(np.asarray(K, np.float64), (n, 3, 3)) if np.ndim(K) == 2 else np.asarray(K, np.float64)
    poses = np.asarray(cam_to_world, np.float64).reshape(n, 4, 4)
    dims = tuple(int(d) for d in dims)
    tsdf = torch.ones(dims, dtype=torch.float32, device=device)
    weight = torch.zeros(dims, dtype=torch.float32, device=device)
    if evidence is not None:
        evidence.start(dims, device)
    for i in range(n):
        check(cancel)
        if np.isfinite(poses[i]).all():
            _integrate(tsdf, weight, depths[i], Ks[i], poses[i], np.asarray(origin, np.float64), voxel_size,
                       trunc, depth_cap, evidence, i, start)
        report(progress, "TSDF fusion", i + 1, n)
    if evidence is None:
        return finalize_tsdf(tsdf, weight), weight
    return finalize_tsdf(tsdf, evidence.weight), weight


class FusionEvidence:
    """How measured depth is weighed in `fuse_tsdf`, and what it gathers.

    pixel_weights: one (H, W) float32 map per frame (the depth map's size), > 0 where the depth counts.
    bilinear_tolerance: relative depth spread of the four neighbours under which depth is interpolated.
    After fusion: `weight` (X, Y, Z) the summed observation weights; `support` (X, Y, Z) the frames
    whose surface lies within the truncation band of the voxel.
    """

    def __init__(self, pixel_weights: Sequence[np.ndarray], bilinear_tolerance: float = 0.03):
        self.pixel_weights = pixel_weights
        self.bilinear_tolerance = bilinear_tolerance
        self.weight: torch.Tensor = torch.zeros(0)
        self.support: torch.Tensor = torch.zeros(0)

    def start(self, dims: tuple[int, int, int], device: torch.device) -> None:
        self.weight = torch.zeros(dims, dtype=torch.float32, device=device)
        self.support = torch.zeros(dims, dtype=torch.float32, device=device)


def _bilinear_depth(depth: torch.Tensor, uf: torch.Tensor, vf: torch.Tensor, nearest: torch.Tensor,
                    tolerance: float) -> torch.Tensor:
    """Depth at continuous pixel positions (uf, vf) (pixel centres at integers + 0.5), interpolated from
    the four neighbouring pixels where all have depth within `tolerance` (relative) of the nearest
    one's; the nearest depth elsewhere (edges, holes), so no depth is invented across a discontinuity."""
    height, width = depth.shape
    x, y = uf - 0.5, vf - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    x0 = x0.long().clamp_(0, width - 1)
    y0 = y0.long().clamp_(0, height - 1)
    x1, y1 = (x0 + 1).clamp_(max=width - 1), (y0 + 1).clamp_(max=height - 1)
    flat = depth.reshape(-1)
    d00, d01 = flat[y0 * width + x0], flat[y0 * width + x1]
    d10, d11 = flat[y1 * width + x0], flat[y1 * width + x1]
    corners = torch.stack([d00, d01, d10, d11])
    agree = (corners > 0).all(0) & ((corners - nearest).abs() <= tolerance * nearest).all(0)
    value = (d00 * (1 - fx) + d01 * fx) * (1 - fy) + (d10 * (1 - fx) + d11 * fx) * fy
    return torch.where(agree, value, nearest)


def finalize_tsdf(tsdf: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Running-mean TSDF (+ in front of surfaces) -> ground-truth convention (- in front), in place."""
    observed = weight > 0
    front_or_behind = tsdf < 1
    tsdf[front_or_behind] *= -1
    tsdf[~front_or_behind & observed] = -1
    return tsdf


def fuse_ground_truth(
    depths: Sequence[np.ndarray],
    K: np.ndarray,
    cam_to_world: np.ndarray,
    voxel_size: float = 0.04,
    trunc: float = 0.12,
    depth_cap: float = 3.0,
    max_bound_frames: int = 200,
    device: Device = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> TsdfVolume:
    """Bounds from the frusta, then `fuse_tsdf`: the whole ground-truth recipe for one scene."""
    lo, hi = frustum_bounds(depths, K, cam_to_world, depth_cap=depth_cap, max_frames=max_bound_frames)
    origin, dims = volume_from_bounds(lo, hi, voxel_size)
    tsdf, weight = fuse_tsdf(depths, K, cam_to_world, origin, dims, voxel_size, trunc, depth_cap, device,
                             progress, cancel)
    return TsdfVolume(tsdf.cpu().numpy(), weight.cpu().numpy(), origin, voxel_size, trunc)


def _integrate(
    tsdf: torch.Tensor,
    weight: torch.Tensor,
    depth_np: np.ndarray,
    K: np.ndarray,
    pose: np.ndarray,
    origin: np.ndarray,
    voxel_size: float,
    trunc: float,
    depth_cap: Optional[float],
    evidence: Optional[FusionEvidence] = None,
    frame: int = 0,
    start: Sequence[int] = (0, 0, 0),
) -> None:
    """Update the running mean with one frame, touching only the voxels in its frustum's bounding box.
    The arrays hold the voxels from index `start` (3,) of the lattice origin + index * voxel_size."""
    device = tsdf.device
    start = np.asarray(start, np.int64)
    depth_np = np.nan_to_num(np.asarray(depth_np, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    if depth_cap is not None:
        depth_np = np.where(depth_np > depth_cap, 0.0, depth_np).astype(np.float32)
    height, width = depth_np.shape
    max_depth = float(depth_np.max())
    if max_depth <= 0:
        return
    depth = torch.as_tensor(depth_np, device=device)

    # Only voxels with z <= max_depth + trunc and inside the image can change; one voxel of slack
    # around the box keeps float error at the border from dropping any.
    corners = np.vstack([pose[:3, 3], frustum_corners(K, pose, width, height, max_depth + trunc)])
    lo = np.floor((corners.min(axis=0) - origin) / voxel_size).astype(np.int64) - 1 - start
    hi = np.ceil((corners.max(axis=0) - origin) / voxel_size).astype(np.int64) + 2 - start
    shape = np.array(tsdf.shape)
    lo, hi = np.clip(lo, 0, shape), np.clip(hi, 0, shape)
    if np.any(hi <= lo):
        return

    # P = K [R^T | -R^T t] maps a world point to (z*u, z*v, z). On a grid it is separable:
    # P @ (x, y, z, 1) = P[:, 0] x_i + P[:, 1] y_j + (P[:, 2] z_k + P[:, 3]), so three small outer
    # sums replace a per-voxel matrix product (this loop is the whole cost of ground-truth generation).
    P = torch.as_tensor(projection_matrix(K, pose), dtype=torch.float64, device=device)
    xs, ys, zs = (axis_positions(origin, start[a] + lo[a], hi[a] - lo[a], voxel_size, a, device=device) for a in range(3))

    def project(row: int) -> torch.Tensor:
        return (P[row, 0] * xs[:, None, None] + P[row, 1] * ys[None, :, None]
                + (P[row, 2] * zs + P[row, 3])[None, None, :]).float()

    z = project(2)
    in_front = z > 0
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    uf, vf = project(0) / z_safe, project(1) / z_safe
    u, v = torch.floor(uf), torch.floor(vf)
    inside = in_front & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    flat = (v.clamp_(0, height - 1) * width + u.clamp_(0, width - 1)).long()
    d = depth.reshape(-1)[flat]
    if evidence is not None:
        d = _bilinear_depth(depth, uf, vf, d, evidence.bilinear_tolerance)
    diff = d - z
    update = inside & (d > 0) & (diff >= -trunc)
    dist = torch.clamp(diff / trunc, max=1.0)

    sl = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))
    t_block, w_block = tsdf[sl], weight[sl]
    if evidence is None:
        w_new = w_block + update.float()
        mean = (t_block * w_block + dist) / torch.clamp(w_new, min=1.0)
        tsdf[sl] = torch.where(update, mean, t_block)
        weight[sl] = w_new
        return
    pixel_weight = torch.as_tensor(np.asarray(evidence.pixel_weights[frame], np.float32), device=device).reshape(-1)[flat]
    update &= pixel_weight > 0
    w_obs = torch.where(update, pixel_weight, torch.zeros_like(pixel_weight))
    e_block = evidence.weight[sl]
    e_new = e_block + w_obs
    mean = (t_block * e_block + dist * w_obs) / torch.clamp(e_new, min=1e-12)
    tsdf[sl] = torch.where(update, mean, t_block)
    evidence.weight[sl] = e_new
    weight[sl] = w_block + update.float()
    evidence.support[sl] += (update & (diff.abs() < trunc)).float()

