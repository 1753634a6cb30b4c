"""Training crops with stereo evidence: the room's maps follow the crop's rotation and mirror (their
fused TSDF agrees with the crop's ground truth), views map to their own frame's depth map, and the
depth-scale augmentation scales about half of the maps by at most 10 %."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from fixtures_rooms import box_room  # noqa: E402

from engine.model.stereo_evidence import fused_tsdf  # noqa: E402
from engine.train.batching import collate  # noqa: E402
from engine.train.crops import CropSettings, make_crop  # noqa: E402
from engine.train.room_stereo import RoomStereo  # noqa: E402


def room_with_stereo():
    room = box_room(n_frames=12, image_size=(64, 48))
    frames = np.arange(0, 12, 2)
    # Exact depth stands in for stereo here: the test is about the geometry of the crop transform.
    room.stereo = RoomStereo(frames, room.depths[frames].copy(), np.full_like(room.depths[frames], 0.8), room.K[frames].copy())
    return room


def test_crop_stereo_maps_follow_rotation_and_mirror():
    room = room_with_stereo()
    settings = CropSettings(crop_size=(32, 32, 24), n_views=6, photometric=False, stereo=True, depth_scale=0.0)
    checked = 0
    for seed in range(4):
        s = make_crop(room, settings, np.random.default_rng(seed))
        index = torch.nonzero(torch.ones(settings.crop_size, dtype=torch.bool))
        points = s.origin + index.float() * 0.04
        fused = fused_tsdf(points, s.stereo, 0.12).reshape(settings.crop_size)
        near = (s.targets.tsdf.abs() < 0.5) & (fused.abs() < 1)
        assert near.sum() > 50, s.info
        # Same surface: where both see it, the fused stereo TSDF matches the ground truth closely.
        assert float((fused[near] - s.targets.tsdf[near]).abs().median()) < 0.15, s.info
        views = np.asarray(s.info["views"])
        expected = np.where(views % 2 == 0, views // 2, -1)
        np.testing.assert_array_equal(s.stereo_views.numpy(), expected)
        checked += 1
    assert checked == 4


def test_depth_scale_augmentation_scales_about_half_the_maps():
    room = room_with_stereo()
    settings = CropSettings(crop_size=(32, 32, 24), n_views=6, photometric=False, mirror=False, stereo=True, depth_scale=0.1)
    ratios = []
    for seed in range(20):
        s = make_crop(room, settings, np.random.default_rng(seed))
        depth = s.stereo.depth.numpy()
        valid = room.stereo.depth > 0
        ratios += [float(np.median(depth[i][valid[i]] / room.stereo.depth[i][valid[i]])) for i in range(len(depth))]
    ratios = np.array(ratios)
    scaled = np.abs(ratios - 1) > 1e-6
    assert 0.3 < scaled.mean() < 0.7
    assert ratios.min() >= 0.9 - 1e-6 and ratios.max() <= 1.1 + 1e-6


def test_collate_carries_stereo():
    room = room_with_stereo()
    settings = CropSettings(crop_size=(32, 32, 24), n_views=6, photometric=False, stereo=True)
    rng = np.random.default_rng(0)
    batch = collate([make_crop(room, settings, rng) for _ in range(2)], settings.crop_size)
    assert len(batch.stereo) == 2 and batch.stereo_views.shape == (2, 6)
    assert batch.to("cpu").stereo[1].depth.shape == (6, 48, 64)
