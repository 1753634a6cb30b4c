"""Training crops and targets (engine.train.crops, engine.train.batching) against hand-made TSDFs and an
analytic box room."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from engine.geometry.view_selection import select_keyframes
from engine.train.batching import RoomSampler
from engine.train.crops import CropSettings, crop_targets, crop_transform, make_crop, resample_tsdf
from fixtures_rooms import box_room


def _free(shape):
    return -torch.ones(shape)


def test_dilation_targets_single_surface_voxel():
    t = _free((8, 8, 8))
    t[3, 3, 3] = 0.0  # one surface voxel, everything else observed free
    tg = crop_targets(t)
    # fine: occupancy |t| < .999 only at (3,3,3); everything observed -> supervised
    assert tg.mask[2].all()
    # medium: dilate3 covers fine 2..4 per axis; strided pick keeps even fine indices 2, 4 -> medium 1, 2
    occ08 = tg.occ[1]
    expected = torch.zeros(4, 4, 4)
    expected[1:3, 1:3, 1:3] = 1
    assert torch.equal(occ08, expected)
    assert tg.mask[1].all()  # occupied or seen-and-not-dilated everywhere
    # coarse from medium: dilate medium 1..2 -> 0..3, strided pick 0, 2 -> coarse 0, 1 all occupied
    assert torch.equal(tg.occ[0], torch.ones(2, 2, 2))


def test_notocc_excludes_dilated_neighbourhood_and_unseen():
    t = _free((8, 8, 8))
    t[3, 3, 3] = 0.0
    t[6:, 6:, :4] = 1.0  # unobserved voxels (not whole columns)
    tg = crop_targets(t)
    occ08, mask08 = tg.occ[1], tg.mask[1]
    # medium (3,3,0) <- fine (6,6,0): unobserved, not occupied, its column is partly seen -> ignored
    assert not mask08[3, 3, 0] and occ08[3, 3, 0] == 0
    # medium (3,3,3) <- fine (6,6,6): observed free, far from the surface -> supervised empty
    assert mask08[3, 3, 3] and occ08[3, 3, 3] == 0
    # fine: unseen voxels in partly seen columns are ignored
    assert not tg.mask[2][6, 6, 0] and tg.mask[2][6, 6, 5]


def test_unobserved_columns_are_supervised_empty():
    t = _free((8, 8, 8))
    t[2, 2, 2] = 0.5
    t[0, 0, :] = 1.0  # a whole unobserved z-column
    t[5, 5, :3] = 1.0  # a partly unobserved column
    tg = crop_targets(t)
    assert tg.mask[2][0, 0, :].all() and (tg.tsdf[0, 0, :] == 1).all()
    assert not tg.mask[2][5, 5, :3].any()
    # medium column (0,0) <- fine (0,0): all unseen -> supervised with occupancy 0
    assert tg.mask[1][0, 0, :].all() and (tg.occ[1][0, 0, :] == 0).all()


def test_resample_identity_and_outside():
    rng = np.random.default_rng(0)
    vol = rng.uniform(-1, 1, size=(6, 5, 4)).astype(np.float32)
    vol[0, 0, 0] = 1.0
    origin = np.array([1.0, -2.0, 0.5])
    idx = np.argwhere(np.ones_like(vol, bool))
    pts = origin + idx * 0.04
    out = resample_tsdf(vol, origin, 0.04, pts)
    np.testing.assert_allclose(out, vol.reshape(-1), atol=1e-5)
    outside = resample_tsdf(vol, origin, 0.04, origin[None] - 0.5)
    assert outside[0] == 1.0
    # halfway between a +1 voxel and a value: nearest |v| > .999 wins over the interpolation
    p = origin + np.array([[0.4 * 0.04, 0, 0]])  # nearest is (0,0,0) = +1
    assert resample_tsdf(vol, origin, 0.04, p)[0] == 1.0


def test_crop_transform_keeps_anchor_and_mirrors():
    a = np.array([1.0, 2.0, 0.5])
    A = crop_transform(a, 0.7, True)
    np.testing.assert_allclose(A[:3, :3] @ a + A[:3, 3], a)
    assert np.linalg.det(A[:3, :3]) == pytest.approx(-1.0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_crop_geometry_consistent_with_depth(seed):
    """Surface voxels of the crop (GT resampled through rotation + mirror) project, through the
    crop-frame poses, onto pixels whose (mirrored) depth equals their camera depth."""
    room = box_room(n_frames=12, image_size=(64, 48))
    settings = CropSettings(crop_size=(32, 32, 24), n_views=6, photometric=False)
    rng = np.random.default_rng(seed)
    s = make_crop(room, settings, rng)
    assert s.images.shape == (6, 3, 48, 64) and s.poses.shape == (6, 4, 4)
    t = s.targets.tsdf
    surf = torch.nonzero(t.abs() < 0.2).double()
    assert len(surf) > 0
    pts = s.origin.double() + surf * 0.04
    checked = 0
    for v in range(6):
        w2c = torch.linalg.inv(s.poses[v].double())
        assert torch.det(s.poses[v][:3, :3].double()) == pytest.approx(1.0, abs=1e-5)
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
        uvw = cam @ s.K[v].double().T
        u, vv, z = uvw[:, 0] / cam[:, 2], uvw[:, 1] / cam[:, 2], cam[:, 2]
        ok = (z > 0.1) & (u >= 0) & (u < 64) & (vv >= 0) & (vv < 48)
        if ok.sum() == 0:
            continue
        d = s.depths[v][vv[ok].floor().long(), u[ok].floor().long()].double()
        err = (d - z[ok]).abs()
        # most visible surface voxels lie within the truncation band of the rendered depth
        assert (err < 0.12).float().mean() > 0.8, (v, s.info)
        checked += 1
    assert checked >= 2


def test_keyframes_and_view_selection():
    room = box_room(n_frames=24, image_size=(32, 24))
    # views 15 deg apart, pitched down (axis angle just under 15 deg), 8 cm apart: every other one is kept
    assert list(select_keyframes(room.poses)) == list(range(0, 24, 2))
    same = np.repeat(room.poses[:1], 5, 0)
    assert list(select_keyframes(same)) == [0]
    s = make_crop(room, CropSettings(crop_size=(16, 16, 16), n_views=8, photometric=True, noise=3.0),
                  np.random.default_rng(0))
    assert len(set(s.info["views"])) == 8
    assert s.images.min() >= 0 and s.images.max() <= 255


def test_room_sampler_shards_and_resumes():
    a, b = RoomSampler(5, seed=3, rank=0, world_size=2), RoomSampler(5, seed=3, rank=1, world_size=2)
    ea = [a.next() for _ in range(3)]
    eb = [b.next() for _ in range(3)]
    assert sorted(set(ea) | set(eb)) == [0, 1, 2, 3, 4]
    st = a.state_dict()
    nxt = [a.next() for _ in range(4)]
    c = RoomSampler(5, seed=3, rank=0, world_size=2)
    c.load_state_dict(st)
    assert [c.next() for _ in range(4)] == nxt
