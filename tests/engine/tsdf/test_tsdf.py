"""TSDF fusion against the analytic signed distance of a box room, and the target helpers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from engine.geometry.cameras import look_along as look_pose
from engine.tsdf import (
    TsdfVolume,
    frustum_bounds,
    fuse_ground_truth,
    fuse_tsdf,
    occupancy_targets,
    projective_occupancy,
    supervised_mask,
    voxel_positions,
)

ROOM = np.array([4.0, 3.0, 2.5])  # box room [0, 4] x [0, 3] x [0, 2.5]
VOXEL, TRUNC = 0.04, 0.12


def box_depth(pose: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Planar depth (H, W) of the inside of the box room, by ray-box exit intersection through pixel
    centres (pixel (0, 0) covers [0, 1)^2, the engine's K convention)."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], axis=-1)
    d = rays_cam @ pose[:3, :3].T  # world direction per pixel with camera-z component 1
    o = pose[:3, 3]
    with np.errstate(divide="ignore"):
        t_hi = np.where(d > 0, (ROOM - o) / d, np.where(d < 0, (0.0 - o) / d, np.inf))
    return t_hi.min(axis=-1)  # parameter along a ray whose camera z grows by 1 per unit = planar depth


def box_sdf(points: np.ndarray) -> np.ndarray:
    """Signed distance to the room's surface: positive inside the room (free space), negative in the walls."""
    inside = np.minimum(points, ROOM - points).min(axis=-1)
    outside = np.linalg.norm(np.maximum(np.maximum(-points, points - ROOM), 0), axis=-1)
    return np.where(inside >= 0, inside, -outside)


def test_axis_aligned_views_give_exact_tsdf_and_sign_convention():
    # Narrow cameras at the room centre, each looking straight at one wall, the floor or the ceiling:
    # the surface is perpendicular to the optical axis, so projective distance == true distance.
    W, H = 60, 40
    K = np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]])
    centre = ROOM / 2
    dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, -1), (0, 0, 1)]
    poses = np.stack([look_pose(centre, d, up=(0, 1, 0) if d[2] else (0, 0, 1)) for d in dirs])
    depths = [box_depth(p, K, W, H) for p in poses]
    origin = np.array([-0.4, -0.4, -0.4])
    dims = tuple(int(x) for x in np.round((ROOM + 0.8) / VOXEL))
    tsdf, weight = fuse_tsdf(depths, K, poses, origin, dims, VOXEL, TRUNC, depth_cap=None)
    tsdf, weight = tsdf.numpy(), weight.numpy()
    pts = voxel_positions(origin, dims, VOXEL).double().numpy()
    sdf = box_sdf(pts)
    observed = weight > 0

    near = observed & (np.abs(sdf) < TRUNC - 1e-6)
    assert near.sum() > 2000
    # Ground-truth convention: negative in front of the surface (sdf > 0), positive behind it.
    np.testing.assert_allclose(tsdf[near], -sdf[near] / TRUNC, atol=1e-4)
    # Observed free space far from the walls is exactly -1; never-observed voxels stay +1.
    far = observed & (sdf > TRUNC + 1e-6)
    assert far.sum() > 1000 and np.all(tsdf[far] == -1)
    assert np.all(tsdf[~observed] == 1)
    # Beyond the truncation band behind a wall nothing is observed.
    assert not np.any(observed & (sdf < -TRUNC - 1e-6))


def test_oblique_views_stay_close_to_true_distance():
    # A handheld-like ring of cameras: projective distances overestimate on oblique surfaces, so
    # only voxels right at the surface are compared, within one voxel.
    W, H = 80, 60
    K = np.array([[70.0, 0, W / 2], [0, 70.0, H / 2], [0, 0, 1]])
    rng = np.random.default_rng(0)
    poses = []
    for a in np.linspace(0, 2 * np.pi, 12, endpoint=False):
        c = ROOM / 2 + np.array([0.8 * np.cos(a), 0.6 * np.sin(a), -0.2])
        target = np.array([2 + 2.5 * np.cos(a + 0.3), 1.5 + 2 * np.sin(a + 0.3), rng.uniform(0.3, 1.5)])
        poses.append(look_pose(c, target - c))
    poses = np.stack(poses)
    depths = [box_depth(p, K, W, H) for p in poses]
    vol = fuse_ground_truth(depths, K, poses, VOXEL, TRUNC, depth_cap=3.0)
    sdf = box_sdf(vol.positions().astype(np.float64))
    at_surface = vol.observed & (np.abs(sdf) < 0.5 * VOXEL)
    assert at_surface.sum() > 500
    err = np.abs(vol.tsdf[at_surface] * TRUNC + sdf[at_surface])
    assert np.median(err) < 0.01 and np.quantile(err, 0.95) < VOXEL
    # Sign: observed voxels clearly inside the room are negative, clearly inside a wall positive.
    assert np.all(vol.tsdf[vol.observed & (sdf > 0.06)] < 0)
    assert np.all(vol.tsdf[vol.observed & (sdf < -0.06)] > 0)
    # Depth beyond the 3 m cap is dropped: the bounds come from capped frusta.
    lo, hi = frustum_bounds(depths, K, poses, depth_cap=3.0)
    assert np.all(vol.origin == lo) and np.all(hi - lo < 3.0 * 2 + 1e-9)


def test_volume_round_trip(tmp_path):
    vol = TsdfVolume(np.array([[[1.0, -0.5]]], np.float32), np.array([[[0.0, 2.0]]], np.float32),
                     np.array([0.1, 0.2, 0.3]), 0.04, 0.12)
    vol.save(tmp_path / "v.npz")
    back = TsdfVolume.load(tmp_path / "v.npz")
    assert back.dims == (1, 1, 2) and back.voxel_size == 0.04 and np.all(back.tsdf == vol.tsdf)
    np.testing.assert_allclose(back.positions()[0, 0, 1], [0.1, 0.2, 0.34], atol=1e-6)


def test_occupancy_targets_dilate_then_pick_every_other_voxel():
    t = torch.full((8, 8, 8), -1.0)  # all observed free
    t[2, 2, 2] = 0.5  # one surface voxel
    t[6:, 6:, :] = 1.0  # a 2x2 block of wholly unobserved columns
    lv = occupancy_targets(t)
    assert lv["fine"].occupied.sum() == 1 and lv["fine"].occupied[2, 2, 2]
    # Dilation covers 1..3 on each axis; the strided pick keeps index 2 -> medium voxel 1.
    med = lv["medium"]
    assert med.occupied.shape == (4, 4, 4)
    assert torch.nonzero(med.occupied).tolist() == [[1, 1, 1]]
    assert not med.free[1, 1, 1] and med.free[0, 0, 0]
    # Columns (6|7, 6|7, :) are unseen everywhere -> medium (3, 3, :) unseen but supervised.
    assert not med.seen[3, 3].any() and med.supervised[3, 3].all()
    # Coarse: dilating medium (1,1,1) covers 0..2 per axis -> picks 0 and 2 -> coarse {0,1}^3 (2x2x2 grid).
    assert lv["coarse"].occupied.shape == (2, 2, 2) and lv["coarse"].occupied.all()
    # Fine supervised set: seen voxels plus the unobserved columns; a partly seen column is not filled.
    t2 = t.clone()
    t2[0, 0, 4:] = 1.0
    mask = supervised_mask(t2)
    assert mask[6, 6].all() and not mask[0, 0, 4:].any() and mask[0, 0, :4].all()


def test_projective_occupancy_band_is_three_voxels():
    W, H = 20, 10
    K = torch.tensor([[10.0, 0, 10.0], [0, 10.0, 5.0], [0, 0, 1]])
    pose = torch.eye(4)  # camera at the origin looking along +z
    depth = torch.full((H, W), 2.0)
    depth[:, :5] = 0  # missing depth on the left
    pts = torch.tensor([[0.0, 0, 2.1], [0.0, 0, 1.5], [0.0, 0, -2.0], [-1.5, 0, 2.0], [0.0, 0, 2.2]])
    target, valid = projective_occupancy(pts, K[None], pose[None], depth[None], trunc=3 * 0.04)
    assert valid[:, 0].tolist() == [True, True, False, False, True]
    assert target[:, 0].bool().tolist() == [True, False, False, False, False]
