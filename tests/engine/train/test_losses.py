"""Losses (engine.train.losses) and projective-occupancy targets (engine.tsdf.targets): masks, log-L1
TSDF, projective occupancy over the whole batch."""

from __future__ import annotations

import torch

from engine.geometry.cameras import project_points_torch
from engine.train import losses as L
from engine.tsdf.targets import projective_occupancy


def _cams(B, V, H=24, W=32):
    K = torch.tensor([[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]]).expand(B, V, 3, 3).clone()
    poses = torch.eye(4).expand(B, V, 4, 4).clone()  # cameras at the origin looking along +z
    depths = torch.full((B, V, H, W), 2.0)
    return K, poses, depths


def test_projective_occupancy_covers_every_sample():
    B, V, M = 2, 3, 50
    K, poses, depths = _cams(B, V)
    g = torch.Generator().manual_seed(0)
    points = [torch.cat([torch.rand(M, 2, generator=g) - 0.5, 1.8 + 0.4 * torch.rand(M, 1, generator=g)], 1)
              for _ in range(B)]
    logits = [torch.randn(M, V, generator=g) for _ in range(B)]
    projections = [project_points_torch(points[b], K[b], poses[b]) for b in range(B)]
    pixels = torch.cat([torch.stack([u, v], -1) for u, v, _ in projections])
    z = torch.cat([z for _, _, z in projections])
    sample = torch.arange(B).repeat_interleave(M)
    valid = torch.ones(B * M, V, dtype=torch.bool)

    def loss(lg):
        return L.projective_occupancy_loss_batch(torch.cat(lg), sample, pixels, z, valid, depths, 0.12)

    base = loss(logits)
    assert not torch.isclose(base, loss([logits[0], logits[1] + 3.0]))  # sample 1 counts too
    # and the loss is the BCE over the union of both samples' pairs
    t0, s0 = projective_occupancy(points[0], K[0], poses[0], depths[0], 0.12)
    t1, s1 = projective_occupancy(points[1], K[1], poses[1], depths[1], 0.12)
    ref = torch.nn.functional.binary_cross_entropy_with_logits(
        torch.cat([logits[0][s0], logits[1][s1]]), torch.cat([t0[s0], t1[s1]]))
    assert torch.allclose(base, ref)


def test_projective_targets():
    K, poses, depths = _cams(1, 1)
    pts = torch.tensor([[0.0, 0.0, 2.05], [0.0, 0.0, 1.5], [0.0, 0.0, -1.0], [0.0, 0.0, 2.0]])
    t, s = projective_occupancy(pts, K[0], poses[0], depths[0], 0.12)
    assert t[:, 0].tolist() == [1.0, 0.0, 0.0, 1.0]
    assert s[:, 0].tolist() == [True, True, False, True]
    depths[0, 0, 12, 16] = 0.0  # the centre pixel has no depth -> nothing there is supervised
    _, s = projective_occupancy(pts, K[0], poses[0], depths[0], 0.12)
    assert not s.any()


def test_voxel_losses_use_mask_and_log_l1():
    tsdf = torch.zeros(1, 2, 2, 2)
    tsdf[0, 0, 0, 0] = 0.5
    mask = torch.zeros(1, 2, 2, 2, dtype=torch.bool)
    mask[0, 0, 0, 0] = True
    coords = torch.tensor([[0, 0, 0, 0], [0, 1, 1, 1], [0, 5, 0, 0]])
    logits = torch.tensor([0.0, 10.0, 10.0])
    # only voxel 0 is supervised: pred 1.05*tanh(0) = 0 vs gt .5 -> |0 - log(1.5)|
    assert torch.isclose(L.tsdf_loss(logits, coords, tsdf, mask), torch.log(torch.tensor(1.5)))
    occ = torch.ones(1, 2, 2, 2)
    assert torch.isclose(L.occupancy_loss(logits, coords, occ, mask), torch.log(torch.tensor(2.0)))
    empty = L.occupancy_loss(logits, coords, occ, torch.zeros_like(mask))
    assert empty.item() == 0.0


def test_batch_projective_loss_covers_sample_1():
    """The network-prediction form: voxels of sample 1 contribute (perturbing only them changes the loss)."""
    g = torch.Generator().manual_seed(1)
    N, V, B, H, W = 40, 3, 2, 24, 32
    sample = torch.cat([torch.zeros(N // 2), torch.ones(N // 2)]).long()
    pixels = torch.stack([torch.rand(N, V, generator=g) * (W - 1), torch.rand(N, V, generator=g) * (H - 1)], -1)
    depth = 1.8 + 0.4 * torch.rand(N, V, generator=g)
    valid = torch.ones(N, V, dtype=torch.bool)
    maps = torch.full((B, V, H, W), 2.0)
    logits = torch.randn(N, V, generator=g)
    base = L.projective_occupancy_loss_batch(logits, sample, pixels, depth, valid, maps, 0.12)
    pert = logits.clone()
    pert[sample == 1] += 3.0
    assert not torch.isclose(base, L.projective_occupancy_loss_batch(pert, sample, pixels, depth, valid, maps, 0.12))
    # sample 1's depth map is the one used for sample 1's voxels
    maps2 = maps.clone()
    maps2[1] = 5.0
    assert not torch.isclose(base, L.projective_occupancy_loss_batch(logits, sample, pixels, depth, valid, maps2, 0.12))


def test_balanced_occupancy_weighs_the_rare_class():
    occ = torch.zeros(1, 4, 1, 1)
    occ[0, 0] = 1.0  # 1 occupied, 3 empty
    mask = torch.ones(1, 4, 1, 1, dtype=torch.bool)
    coords = torch.tensor([[0, i, 0, 0] for i in range(4)])
    logits = torch.full((4,), -2.0)
    plain = L.occupancy_loss(logits, coords, occ, mask)
    balanced = L.occupancy_loss(logits, coords, occ, mask, balanced=True)
    sp = torch.nn.functional.softplus
    assert torch.isclose(balanced, (3 * sp(torch.tensor(2.0)) + 3 * sp(torch.tensor(-2.0))) / 4)
    assert balanced > plain
