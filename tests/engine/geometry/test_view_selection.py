"""Keyframes and view selection (engine.geometry.view_selection): training crops and inference tiles
pick the same views for the same frames and voxels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.capture import Capture, Frame
from engine.geometry.cameras import project_points
from engine.geometry.view_selection import sample_views, select_keyframes, top_up_views, views_seeing_points
from engine.recon.plan import plan_reconstruction
from engine.recon.settings import ReconSettings
from engine.recon.tiles import tile_coarse_points
from engine.train.crops import choose_crop_views
from fixtures_rooms import box_room

VIEWS = 3


def _room_and_plan():
    room = box_room(n_frames=24, image_size=(64, 48))  # 12 keyframes (every other frame)
    H, W = room.image_hw
    frames = [Frame(image_path=Path(f"{i:03d}.png"), width=W, height=H, K=room.K[i], pose=room.poses[i])
              for i in range(len(room.poses))]
    capture = Capture(root=Path("box"), format="scannet", frames=frames, metric=True)
    settings = ReconSettings(views=VIEWS, tile_size=16, tile_height=16, frustum_depth=2.0)
    return room, plan_reconstruction(capture, settings), settings


def test_training_and_inference_pick_the_same_views_for_the_same_frames_and_voxels():
    room, plan, settings = _room_and_plan()
    assert plan.keyframe_ids == room.keyframes.tolist()  # one keyframe rule
    H, W = room.image_hw
    compared = topped_up = 0
    for tile in plan.active_tiles:
        points = tile_coarse_points(tile, plan.grid, plan.bounds)
        inference = [plan.keyframe_ids[v] for v in tile.views]
        # the training path, given the tile's voxels and the tile's generator
        training = choose_crop_views(room, points, VIEWS, np.random.default_rng([settings.seed, *tile.index])).tolist()
        u, v, z = project_points(points, room.K[room.keyframes], room.poses[room.keyframes])
        seeing = room.keyframes[((z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)).any(axis=1)]
        assert set(inference) <= set(seeing.tolist())  # independent check of "sees"
        if len(seeing) >= VIEWS:
            assert training == inference
            compared += 1
        else:  # training stacks exactly VIEWS views: the seeing ones plus other frames
            assert set(inference) == set(seeing.tolist()) <= set(training) and len(training) == VIEWS
            topped_up += 1
    assert compared >= 3


def test_keyframes_skip_non_finite_poses_and_views_need_a_point_inside_the_image():
    room = box_room(n_frames=8, image_size=(64, 48))
    poses = room.poses.copy()
    poses[0, 0, 0] = np.nan
    assert select_keyframes(poses).tolist() == list(range(1, 8))
    K, pose = room.K[:1], room.poses[:1]
    ahead = pose[0, :3, 3] + 2.0 * pose[0, :3, 2]  # on the optical axis: image centre
    behind = pose[0, :3, 3] - 2.0 * pose[0, :3, 2]
    sizes = np.array([[64, 48]])
    assert views_seeing_points(ahead[None], K, pose, sizes).tolist() == [True]
    assert views_seeing_points(behind[None], K, pose, sizes).tolist() == [False]
    assert views_seeing_points(ahead[None], K, pose, np.array([[32, 24]])).tolist() == [False]  # centre is the edge


def test_sampling_takes_all_when_few_and_top_up_fills_to_the_count():
    rng = np.random.default_rng(0)
    assert sample_views(np.array([7, 2, 5]), 8, rng).tolist() == [2, 5, 7]
    picked = sample_views(np.arange(20), 4, rng)
    assert len(set(picked.tolist())) == 4 and np.all(np.diff(picked) > 0)
    full = top_up_views(np.array([3]), 6, 4, rng)
    assert 3 in full and len(set(full.tolist())) == 4
    assert len(top_up_views(np.array([0, 1]), 2, 5, rng)) == 5  # fewer frames than views: repeats


def test_views_seeing_points_matches_projecting_every_point_for_boxes_inside_outside_and_across_views():
    """The bounding-box shortcut decides nothing the per-point projection would decide otherwise:
    60 cameras looking every way from inside a 6 m space, blocks of points of every size."""
    rng = np.random.default_rng(3)
    room = box_room(n_frames=4, image_size=(64, 48))
    K = np.repeat(room.K[:1], 60, axis=0)
    poses = np.repeat(np.eye(4)[None], 60, axis=0)
    for i in range(60):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        poses[i, :3, :3] = q * np.sign(np.linalg.det(q))
        poses[i, :3, 3] = rng.uniform(-3, 3, size=3)
    sizes = np.tile([64, 48], (60, 1))
    decided = 0
    for _ in range(40):
        centre, half = rng.uniform(-4, 4, size=3), rng.uniform(0.05, 2.0, size=3)
        points = centre + rng.uniform(-1, 1, size=(500, 3)) * half
        u, v, z = project_points(points, K, poses)
        expected = ((z > 0) & (u >= 0) & (u < 64) & (v >= 0) & (v < 48)).any(axis=1)
        assert views_seeing_points(points, K, poses, sizes).tolist() == expected.tolist()
        decided += int(expected.sum())
    assert decided > 100  # the draws put blocks both inside and across views
