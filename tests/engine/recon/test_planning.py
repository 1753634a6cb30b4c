"""Keyframes, scene bounds, tiles and view selection (numpy only, no model)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from engine.recon.scene_bounds import SceneBounds, scene_bounds
from engine.geometry.cameras import look_along as look_pose
from engine.geometry.view_selection import select_keyframes
from engine.recon.tiles import BOX_EDGES, TileState, make_tiles, select_views_for_tile, tile_coarse_points, tile_grid


def yaw_pose(x: float, yaw_deg: float) -> np.ndarray:
    a = np.deg2rad(yaw_deg)
    return look_pose(np.array([x, 0.0, 1.5]), np.array([np.cos(a), np.sin(a), 0.0]))


def test_keyframes_keep_translation_or_rotation_since_last_kept():
    poses = np.stack([
        yaw_pose(0.00, 0),   # 0 kept: first frame
        yaw_pose(0.06, 0),   # 1 dropped: 6 cm
        yaw_pose(0.12, 0),   # 2 kept: 12 cm from frame 0 (the last *kept*), though only 6 cm from frame 1
        yaw_pose(0.12, 10),  # 3 dropped: 10 deg
        yaw_pose(0.12, 20),  # 4 kept: 20 deg
        yaw_pose(0.20, 30),  # 5 dropped: 8 cm and 10 deg from frame 4
        yaw_pose(0.20, 36),  # 6 kept: 16 deg from frame 4
    ])
    assert select_keyframes(poses).tolist() == [0, 2, 4, 6]
    # Looser thresholds keep fewer; zero thresholds keep every distinct frame.
    assert select_keyframes(poses, 0.5, 45.0).tolist() == [0]
    assert select_keyframes(poses, 0.0, 0.0).tolist() == list(range(7))


def test_bounds_are_the_frusta_at_depth_and_clip_to_max_room_size():
    K = np.array([[100.0, 0, 100], [0, 100, 50], [0, 0, 1]])  # 200 x 100 image
    pose = look_pose(np.zeros(3), np.array([1.0, 0, 0]))  # looks +x: image right = -y, image down = -z
    b = scene_bounds(K[None], pose[None], np.array([[200, 100]]), depth=4.0)
    np.testing.assert_allclose(b.minimum, [0, -4, -2], atol=1e-9)
    np.testing.assert_allclose(b.maximum, [4, 4, 2], atol=1e-9)
    assert b.clipped == (False, False, False)
    clipped = scene_bounds(K[None], pose[None], np.array([[200, 100]]), depth=4.0, max_room_size=(20, 6, 3))
    np.testing.assert_allclose(clipped.minimum, [0, -3, -1.5], atol=1e-9)
    np.testing.assert_allclose(clipped.maximum, [4, 3, 1.5], atol=1e-9)
    assert clipped.clipped == (False, True, True)


def test_tiles_partition_the_grid_and_cover_the_bounds():
    bounds = SceneBounds(np.array([0.1, -1.0, 0.05]), np.array([2.3, 0.7, 1.3]), (False,) * 3)
    grid, tiles = make_tiles(bounds, voxel_size=0.04, tile_size=16, tile_height=12)
    coarse = 0.16
    assert np.allclose(grid.origin / coarse, np.round(grid.origin / coarse))  # aligned to the coarse grid
    assert np.all(grid.origin <= bounds.minimum) and np.all(grid.origin + grid.shape * 0.04 >= bounds.maximum)
    assert len(tiles) == grid.num_tiles == int(np.prod(grid.tiles_per_axis))
    # Every fine voxel of the grid belongs to exactly one tile, and tile_ids agrees with the tile list.
    owner = np.full(tuple(grid.shape), -1)
    for t, tile in enumerate(tiles):
        region = owner[tuple(slice(s, s + n) for s, n in zip(tile.start, tile.shape))]
        assert np.all(region == -1), "tiles overlap"
        region[...] = t
        for scale in (4, 2, 1):
            assert np.all(grid.tile_ids(grid.level_indices(tile, scale), scale) == t)
        assert tile.state is TileState.PENDING
    assert np.all(owner >= 0)
    # Cropping to the bounds keeps exactly the coarse voxels whose cells overlap them.
    lo = np.floor((bounds.minimum - grid.origin) / coarse + 1e-9)
    hi = np.ceil((bounds.maximum - grid.origin) / coarse - 1e-9)
    inside = [grid.level_indices(t, 4, within=bounds) for t in tiles]
    assert sum(len(i) for i in inside) == int(np.prod(hi - lo))
    stacked = np.concatenate(inside)
    assert np.all(stacked >= lo) and np.all(stacked < hi) and len(np.unique(stacked, axis=0)) == len(stacked)
    corners, edges, states = tile_grid(tiles)
    assert corners.shape == (len(tiles), 8, 3) and edges.shape == (12, 2) and np.array_equal(edges, BOX_EDGES)
    np.testing.assert_allclose(corners.min(axis=1), [t.minimum for t in tiles])
    np.testing.assert_allclose(corners.max(axis=1), [t.maximum for t in tiles])
    assert states == ["pending"] * len(tiles)
    # Every box edge joins corners that differ along exactly one axis.
    assert all(bin(a ^ b).count("1") == 1 for a, b in BOX_EDGES)


def test_tile_dimensions_must_be_multiples_of_four():
    bounds = SceneBounds(np.zeros(3), np.ones(3), (False,) * 3)
    with pytest.raises(ValueError):
        make_tiles(bounds, 0.04, tile_size=18, tile_height=48)


def test_view_selection_is_seeded_and_only_returns_views_that_see_the_tile():
    bounds = SceneBounds(np.array([0.0, 0.0, 0.0]), np.array([1.2, 1.2, 1.2]), (False,) * 3)
    grid, tiles = make_tiles(bounds, 0.04, tile_size=32, tile_height=32)
    assert len(tiles) == 1
    tile = tiles[0]
    centre = tile_coarse_points(tile, grid).mean(axis=0)
    K = np.array([[50.0, 0, 50], [0, 50, 50], [0, 0, 1]])
    poses, sees = [], []
    for i in range(30):
        angle = 2 * np.pi * i / 30
        position = centre + 4.0 * np.array([np.cos(angle), np.sin(angle), 0.0])
        towards = i % 3 != 0  # every third camera looks away from the tile
        poses.append(look_pose(position, (centre - position) * (1 if towards else -1)))
        sees.append(towards)
    poses, sees = np.stack(poses), np.array(sees)
    sizes = np.full((30, 2), 100)
    Ks = np.repeat(K[None], 30, axis=0)
    seeing = set(np.flatnonzero(sees))

    chosen = select_views_for_tile(tile, grid, Ks, poses, sizes, max_views=8, seed=0)
    assert len(chosen) == 8 and set(chosen) <= seeing and np.all(np.diff(chosen) > 0)
    again = select_views_for_tile(tile, grid, Ks, poses, sizes, max_views=8, seed=0)
    assert np.array_equal(chosen, again)
    others = [tuple(select_views_for_tile(tile, grid, Ks, poses, sizes, 8, seed)) for seed in range(1, 6)]
    assert any(o != tuple(chosen) for o in others)
    # With room for all, a tile takes exactly the views that see it.
    everything = select_views_for_tile(tile, grid, Ks, poses, sizes, max_views=60, seed=0)
    assert set(everything) == seeing


def test_planning_and_the_tile_overlay_data_do_not_import_torch():
    code = ("import sys, numpy as np; from engine.recon import tile_grid, plan_reconstruction; "
            "from engine.recon.tiles import make_tiles; from engine.recon.scene_bounds import SceneBounds; "
            "g, t = make_tiles(SceneBounds(np.zeros(3), np.ones(3), (False,) * 3), 0.04, 96, 48); tile_grid(t); "
            "assert 'torch' not in sys.modules, 'torch was imported'")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(Path(__file__).resolve().parents[3]))
