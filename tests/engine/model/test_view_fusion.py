"""View fusion: pooling rules, attention masking, and the invariances VoRTX fusion must have."""

from __future__ import annotations

import math

import pytest
import torch

from engine.geometry.cameras import look_at as camera_look_at
from engine.model import VortxConfig, VortxNet
from engine.model.view_fusion import ViewAttention, masked_mean_pool, softmax_null_pool

H, W = 48, 64
TINY = dict(backbone="mnasnet", feature_channels=(16, 8, 8), unet_base_widths=(4, 4, 4))


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def look_at(eye, target) -> torch.Tensor:
    return torch.from_numpy(camera_look_at(eye, target))


def scene(num_views: int = 4):
    """Cameras on a circle around the box [0, 0.64] x [0, 0.64] x [0, 0.32], plus voxel corners in it."""
    center = [0.32, 0.32, 0.16]
    poses = torch.stack(
        [look_at([0.32 + 1.5 * math.cos(a), 0.32 + 1.5 * math.sin(a), 1.0], center)
         for a in (2 * math.pi * i / num_views for i in range(num_views))]
    )
    K = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]]).expand(num_views, 3, 3).clone()
    g = torch.stack(torch.meshgrid(torch.arange(4), torch.arange(4), torch.arange(2), indexing="ij"), -1).reshape(-1, 3)
    points = g.float() * 0.16
    return poses, K, points


@pytest.fixture(scope="module")
def net() -> VortxNet:
    torch.manual_seed(0)
    return VortxNet(VortxConfig(**TINY)).eval()


def fine_features(net: VortxNet, num_views: int) -> torch.Tensor:
    """A random feature map shaped like encode_views' fine level."""
    return torch.randn(num_views, net.config.feature_channels[2], H // 4, W // 4)


# --- pooling functions ------------------------------------------------------------------------


def test_softmax_null_pool_gives_zero_for_a_voxel_no_view_sees():
    features = torch.randn(3, 5, 8) * 1e3
    logits = torch.randn(3, 5) * 10
    valid = torch.zeros(3, 5, dtype=torch.bool)
    valid[1, 2] = True
    pooled = softmax_null_pool(features, logits, valid)
    assert torch.equal(pooled[0], torch.zeros(8)) and torch.equal(pooled[2], torch.zeros(8))
    # One valid view with logit l: weight sigmoid(l) against the null view.
    torch.testing.assert_close(pooled[1], torch.sigmoid(logits[1, 2]) * features[1, 2])


def test_softmax_null_pool_ignores_invalid_views_even_if_not_finite():
    features = torch.randn(2, 4, 6)
    logits = torch.randn(2, 4)
    valid = torch.tensor([[True, False, True, True], [False, True, True, False]])
    reference = softmax_null_pool(features, logits, valid)
    features[~valid] = float("inf")
    logits[~valid] = 1e4
    torch.testing.assert_close(softmax_null_pool(features, logits, valid), reference)
    # Softmax over the valid views and the null logit 0.
    w = torch.softmax(torch.cat([logits[0, valid[0]], torch.zeros(1)]), 0)[:-1]
    torch.testing.assert_close(reference[0], (w[:, None] * features[0, valid[0]]).sum(0))


def test_masked_mean_pool():
    features = torch.randn(2, 3, 4)
    valid = torch.tensor([[True, False, True], [False, False, False]])
    features[0, 1] = float("nan")
    pooled = masked_mean_pool(features, valid)
    torch.testing.assert_close(pooled[0], (features[0, 0] + features[0, 2]) / 2)
    assert torch.equal(pooled[1], torch.zeros(4))


def test_view_attention_matches_torch_multihead_attention_with_the_official_mask():
    torch.manual_seed(1)
    m, v, c, heads = 7, 5, 8, 2
    ours = ViewAttention(c, heads)
    reference = torch.nn.MultiheadAttention(c, heads)  # sequence-first, as the official model uses it
    reference.load_state_dict(ours.state_dict())
    x = torch.randn(m, v, c)
    valid = torch.rand(m, v) > 0.4
    valid[0] = False  # a voxel no view sees: only the diagonal stays open
    # Official mask: [voxel, i, j] = ~valid[voxel, j], diagonal False, tiled per head (voxel-major).
    mask = (~valid)[:, None, :].repeat(1, v, 1)
    torch.diagonal(mask, dim1=1, dim2=2)[:] = False
    mask = mask.repeat(1, heads, 1).reshape(m * heads, v, v)
    expected, _ = reference(x.transpose(0, 1), x.transpose(0, 1), x.transpose(0, 1), attn_mask=mask, need_weights=False)
    allowed = valid[:, None, :] | torch.eye(v, dtype=torch.bool)
    torch.testing.assert_close(ours(x, allowed), expected.transpose(0, 1), atol=1e-5, rtol=1e-5)


# --- fusion inside the network -----------------------------------------------------------------


@pytest.mark.parametrize("use_proj_occ", [True, False])
def test_fused_feature_is_invariant_to_view_order(net, use_proj_occ):
    poses, K, points = scene(4)
    feats = fine_features(net, 4)
    net.set_use_proj_occ(use_proj_occ)
    with torch.no_grad():
        out = net.fuse(2, points, feats, K, poses, (H, W))
        perm = torch.tensor([2, 0, 3, 1])
        permuted = net.fuse(2, points, feats[perm], K[perm], poses[perm], (H, W))
    assert out.valid.any(dim=1).all(), "every test voxel should be seen"
    torch.testing.assert_close(permuted.features, out.features, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(permuted.proj_occ_logits, out.proj_occ_logits[:, perm], atol=1e-5, rtol=1e-5)
    assert torch.equal(permuted.valid, out.valid[:, perm])


@pytest.mark.parametrize("use_proj_occ", [True, False])
def test_an_invalid_view_has_no_influence(net, use_proj_occ):
    poses, K, points = scene(3)
    # A fourth camera looking away from the voxels: every voxel is behind it.
    away = look_at([0.32, -2.0, 1.0], [0.32, -5.0, 1.0])
    poses, K = torch.cat([poses, away[None]]), torch.cat([K, K[:1]])
    feats = fine_features(net, 4)
    net.set_use_proj_occ(use_proj_occ)
    with torch.no_grad():
        out = net.fuse(2, points, feats, K, poses, (H, W))
        changed = feats.clone()
        changed[3] = torch.randn_like(changed[3]) * 100
        out_changed = net.fuse(2, points, changed, K, poses, (H, W))
        changed_valid = feats.clone()
        changed_valid[0] = torch.randn_like(changed_valid[0]) * 100
        out_changed_valid = net.fuse(2, points, changed_valid, K, poses, (H, W))
    assert not out.valid[:, 3].any() and out.valid[:, 0].any()
    torch.testing.assert_close(out_changed.features, out.features, atol=1e-6, rtol=0)
    torch.testing.assert_close(out_changed.proj_occ_logits[:, :3], out.proj_occ_logits[:, :3], atol=1e-6, rtol=0)
    # Sanity: the same change to a valid view does change the result.
    assert not torch.allclose(out_changed_valid.features, out.features, atol=1e-3)


def test_a_voxel_no_view_sees_fuses_to_the_layer_norm_of_zero(net):
    poses, K, points = scene(3)
    far = torch.tensor([[0.32, 0.32, 20.0]])  # high above the cameras, outside every image
    feats = fine_features(net, 3)
    net.set_use_proj_occ(True)
    with torch.no_grad():
        out = net.fuse(2, torch.cat([points, far]), feats, K, poses, (H, W))
        seen_only = net.fuse(2, points, feats, K, poses, (H, W))
    assert not out.valid[-1].any()
    # The pooled feature is exactly 0, so LayerNorm returns its bias.
    torch.testing.assert_close(out.features[-1], net.layer_norms["fine"].bias.detach())
    # The unseen point does not disturb the others.
    torch.testing.assert_close(out.features[:-1], seen_only.features)
    torch.testing.assert_close(out.proj_occ_logits[:-1], seen_only.proj_occ_logits)


def test_fuse_chunking_does_not_change_the_result(net):
    poses, K, points = scene(4)
    feats = fine_features(net, 4)
    with torch.no_grad():
        whole = net.fuse(2, points, feats, K, poses, (H, W))
        net.fusion_chunk = 5
        try:
            chunked = net.fuse(2, points, feats, K, poses, (H, W))
        finally:
            net.fusion_chunk = 8192
    torch.testing.assert_close(chunked.features, whole.features)
    torch.testing.assert_close(chunked.proj_occ_logits, whole.proj_occ_logits)
    assert torch.equal(chunked.valid, whole.valid)


def test_averaging_ablation_is_a_masked_mean_without_projective_occupancy():
    torch.manual_seed(0)
    net = VortxNet(VortxConfig(**TINY, fusion="average")).eval()
    assert all(sum(p.numel() for p in m.parameters()) == 0 for m in net.mv_fusion.values())
    poses, K, points = scene(4)
    feats = fine_features(net, 4)
    with torch.no_grad():
        out = net.fuse(2, points, feats, K, poses, (H, W))
    assert out.proj_occ_logits is None
    # Pre-LayerNorm feature = mean of the bilinear samples over valid views.
    from engine.model.backprojection import project_to_feature_maps, sample_features

    projection = project_to_feature_maps(points, K, poses, 4, (H // 4, W // 4))
    expected = masked_mean_pool(sample_features(feats, projection.grid), projection.valid)
    torch.testing.assert_close(out.features, net.layer_norms["fine"](expected).detach())
