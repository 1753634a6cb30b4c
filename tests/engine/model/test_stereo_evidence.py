"""Stereo evidence for VoRTX: the per-view token values and the fused TSDF against independent
computations, an untrained evidence network = classical fusion at the fine level, and configs
without evidence (official checkpoint, shipped weights) loading and building as before."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from engine.model.config import StereoEvidenceConfig, VortxConfig
from engine.model.outputs import VortxBatch, tsdf_from_logits
from engine.model.outputs import StereoEvidence
from engine.model.stereo_evidence import MAX_ADDED_BLOCK_SHARE, FineFusion, cap_added_blocks, fused_tsdf, view_evidence
from engine.model.vortx import VortxNet
from engine.stereo.depth_maps import DepthMap
from engine.stereo.fused_tsdf import fuse_depth_maps
from engine.stereo.fused_tsdf import CLASSICAL_TRUNCATION_VOXELS

REPO = Path(__file__).resolve().parents[3]
K = np.array([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
H, W = 48, 64


def tiny_config(**changes) -> VortxConfig:
    return VortxConfig(feature_channels=(16, 8, 8), unet_base_widths=(8, 4, 4), **changes)


def one_view(depth: np.ndarray, confidence: np.ndarray) -> StereoEvidence:
    return StereoEvidence(torch.tensor(depth[None], dtype=torch.float32), torch.tensor(confidence[None], dtype=torch.float32),
                          torch.tensor(K[None], dtype=torch.float32), torch.eye(4)[None])


def test_view_evidence_in_front_behind_outside_and_missing():
    depth = np.full((H, W), 2.0, np.float32)
    depth[:, :8] = 0.0  # no stereo depth in the 8 left columns
    confidence = np.full((H, W), 0.7, np.float32)
    trunc = 0.12
    # Camera at the origin looking down +z (identity pose): pixel u = 50 x / z + 32.
    points = torch.tensor([
        [0.0, 0.0, 1.95],   # 5 cm in front of the depth 2.0 -> (2 - 1.95) / 0.12
        [0.0, 0.0, 2.06],   # 6 cm behind it -> -0.5
        [0.0, 0.0, 1.0],    # far in front: clamped to +1
        [0.0, 0.0, 3.0],    # far behind: clamped to -1
        [-1.0, 0.0, 2.0],   # u = 7: a pixel without depth -> invalid
        [5.0, 0.0, 2.0],    # u = 157: outside the map -> invalid
        [0.0, 0.0, -1.0],   # behind the camera -> invalid
    ])
    ev = view_evidence(points, one_view(depth, confidence), trunc).numpy()
    assert ev.shape == (7, 1, 3)
    expected_psdf = [0.05 / 0.12, -0.5, 1.0, -1.0, 0.0, 0.0, 0.0]
    np.testing.assert_allclose(ev[:, 0, 0], expected_psdf, atol=1e-5)
    np.testing.assert_allclose(ev[:, 0, 1], [0.7, 0.7, 0.7, 0.7, 0, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(ev[:, 0, 2], [1, 1, 1, 1, 0, 0, 0])


def test_view_evidence_uses_the_pixel_that_contains_the_projection():
    depth = np.full((H, W), 2.0, np.float32)
    depth[:, 40:] = 1.0  # a step: columns 40.. are nearer
    ev = one_view(depth, np.ones((H, W), np.float32))
    # u = 50 x / z + 32 at z = 1.5: x at u = 39.9 and u = 40.1 fall either side of the step.
    x = np.array([(39.9 - 32) * 1.5 / 50, (40.1 - 32) * 1.5 / 50])
    points = torch.tensor([[x[0], 0.0, 1.5], [x[1], 0.0, 1.5]], dtype=torch.float32)
    psdf = view_evidence(points, ev, 1.0)[:, 0, 0].numpy()
    np.testing.assert_allclose(psdf, [0.5, -0.5], atol=1e-5)


def test_missing_view_maps_are_invalid():
    depth = np.full((H, W), 2.0, np.float32)
    ev = one_view(depth, np.ones((H, W), np.float32)).views(torch.tensor([0, -1, 0]))
    out = view_evidence(torch.tensor([[0.0, 0.0, 1.9]]), ev, 0.12)
    np.testing.assert_array_equal(out[0, :, 2].numpy(), [1, 0, 1])


def tilted_maps() -> list[DepthMap]:
    """Three views of a tilted wall at about 2 m (depth varies across the image), one with a hole.
    Focal length and centre are not round, so no voxel projects exactly onto a pixel border (where
    float32 and float64 projections may pick different pixels)."""
    K_odd = np.array([[52.37, 0.0, 31.61], [0.0, 52.37, 23.83], [0.0, 0.0, 1.0]])
    maps = []
    for i, x in enumerate((-0.2, 0.0, 0.25)):
        pose = np.eye(4)
        pose[0, 3] = x
        v, u = np.mgrid[0:H, 0:W]
        depth = (2.0 + 0.01 * (u - 32) + 0.005 * i).astype(np.float32)
        if i == 1:
            depth[10:20, 10:30] = 0.0
        maps.append(DepthMap(i, depth, np.ones_like(depth), K_odd, pose, np.zeros(0, np.int64), (0.5, 4.0)))
    return maps


def test_fused_tsdf_at_points_equals_the_dense_classical_fusion():
    maps = tilted_maps()
    origin, dims, voxel = np.array([-0.813, -0.597, 1.5071]), (40, 30, 25), 0.04
    dense, weight = fuse_depth_maps(maps, origin, dims, voxel)
    index = np.argwhere(np.ones(dims, bool))
    points = torch.tensor(origin + index * voxel, dtype=torch.float32)
    at_points = fused_tsdf(points, StereoEvidence.from_depth_maps(maps), 3 * voxel).numpy().reshape(dims)
    assert (np.abs(dense) < 1).sum() > 1000  # the wall is in the grid
    np.testing.assert_allclose(at_points, dense, atol=1e-5)


def evidence_batch(maps: list[DepthMap], origin, crop) -> VortxBatch:
    evidence = StereoEvidence.from_depth_maps(maps)
    v = len(maps)
    return VortxBatch(
        images=torch.rand(1, v, 3, H, W) * 255, K=evidence.K[None].clone(), cam_to_world=evidence.cam_to_world[None].clone(),
        origin=torch.tensor(np.asarray(origin)[None], dtype=torch.float32), crop_shape=crop, stereo=[evidence],
        stereo_views=torch.arange(v)[None])


def test_untrained_evidence_network_reproduces_the_fused_tsdf_at_the_fine_level():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    net = VortxNet(tiny_config(stereo_evidence=StereoEvidenceConfig())).eval()
    maps = tilted_maps()
    origin, crop = np.array([-0.613, -0.397, 1.4071]), (24, 20, 24)
    with torch.no_grad():
        fine = net(evidence_batch(maps, origin, crop))["fine"]
    # The classical method's own field (its band, not the ground truth's 3 voxels), on the crop's grid
    # (whose origin the batch holds in float32).
    dense, weight = fuse_depth_maps(maps, origin.astype(np.float32).astype(np.float64), crop, 0.04,
                                    CLASSICAL_TRUNCATION_VOXELS)
    expected = dense[tuple(fine.coords[:, 1:].numpy().T)]
    predicted = tsdf_from_logits(fine.logits).numpy()
    observed = expected < 1
    np.testing.assert_allclose(predicted[observed], expected[observed], atol=1e-3)
    assert (predicted[~observed] >= 1).all()  # unobserved stays "unobserved" (no surface in the mesh)
    # Every corner of every marching-cubes cell where the classical surface passes survived the coarse
    # and medium pruning, so the untrained network's mesh is the classical one.
    corners = surface_cell_corners(dense, weight > 0)
    kept = np.zeros(crop, bool)
    kept[tuple(fine.coords[:, 1:].numpy().T)] = True
    assert len(corners) > 500
    assert kept[tuple(corners.T)].all()


def surface_cell_corners(tsdf: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(M, 3) the distinct corner voxels of the cells whose 8 corners are observed and change sign."""
    X, Y, Z = tsdf.shape
    offsets = [(dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
    values = np.stack([tsdf[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz] for dx, dy, dz in offsets])
    seen = np.stack([observed[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz] for dx, dy, dz in offsets]).all(axis=0)
    cells = np.argwhere(seen & (values.min(axis=0) < 0) & (values.max(axis=0) > 0))
    return np.unique(np.concatenate([cells + np.array(o) for o in offsets]), axis=0)


def test_evidence_network_refuses_to_run_without_evidence():
    net = VortxNet(tiny_config(stereo_evidence=StereoEvidenceConfig())).eval()
    maps = tilted_maps()
    batch = evidence_batch(maps, [-0.6, -0.4, 1.4], (8, 8, 8))
    batch.stereo, batch.stereo_views = None, None
    with pytest.raises(ValueError, match="stereo evidence"):
        net(batch)


def test_configs_without_evidence_load_and_build_as_before():
    shipped = json.loads((REPO / "weights" / "vortx-default.json").read_text())
    assert "stereo_evidence" not in shipped
    config = VortxConfig.from_dict(shipped)
    assert config.stereo_evidence is None
    assert config.unet_in_channels(0) == config.feature_channels[0]
    assert config.unet_in_channels(2) == 3 * config.unet_base_widths[1] + config.feature_channels[2] + 1
    names = set(VortxNet(tiny_config()).state_dict())
    assert not any("evidence" in n for n in names)
    official = VortxConfig.official()
    assert official.stereo_evidence is None and VortxConfig.from_json(official.to_json()) == official


def test_evidence_config_round_trips_and_rejects_typos():
    config = tiny_config(stereo_evidence=StereoEvidenceConfig(truncation_voxels=2.0))
    assert VortxConfig.from_json(config.to_json()) == config
    assert config.unet_in_channels(0) == 17
    data = config.to_dict()
    data["stereo_evidence"] = {"truncation_voxel": 3}
    with pytest.raises(ValueError, match="truncation_voxel"):
        VortxConfig.from_dict(data)
    with pytest.raises(ValueError, match="transformer"):
        tiny_config(fusion="average", stereo_evidence=StereoEvidenceConfig())


@pytest.mark.parametrize("offset", [(0, 0, 0), (5, -3, 2), (-7, 9, -1)])
def test_blocks_with_surface_and_coverage_against_brute_force(offset):
    """FineFusion's block rules on a grid whose first voxel is off the block lattice, against a loop
    over every block: a block is kept when it holds a corner of a cell the surface passes through."""
    rng = np.random.default_rng(1)
    tsdf = rng.uniform(-1, 1, (11, 9, 7)).astype(np.float32)
    tsdf[rng.random(tsdf.shape) < 0.3] = 1.0  # unobserved
    tsdf[rng.random(tsdf.shape) < 0.5] = -1.0  # free space
    fine = FineFusion(torch.from_numpy(tsdf), offset)
    corners = {tuple(c) for c in surface_cell_corners(tsdf, tsdf < 1).tolist()}
    assert len(corners) > 20
    for scale in (2, 4):
        lo = [(o // scale) - 1 for o in offset]
        hi = [(o + n) // scale + 1 for o, n in zip(offset, tsdf.shape)]
        blocks = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1).reshape(-1, 3)
        got = fine.block_surface(scale, torch.from_numpy(blocks)).numpy()
        covered = fine.covers(scale, torch.from_numpy(blocks)).numpy()
        for block, value, cover in zip(blocks, got, covered):
            inside = [tuple(np.array(c)) for c in np.ndindex(scale, scale, scale)]
            local = [tuple(block * scale + np.array(c) - np.array(offset)) for c in inside]
            expected_surface = any(c in corners for c in local)
            expected_cover = any(all(0 <= c[a] < tsdf.shape[a] for a in range(3)) for c in local)
            assert value == (0.0 if expected_surface else 1.0), (scale, block)
            assert cover == expected_cover, (scale, block)


def test_blocks_added_beyond_the_classical_ones_are_capped_most_confident_first():
    """A level's kept blocks: every classical block it keeps, plus the added ones in the order of a loop
    over them sorted by logit, until MAX_ADDED_BLOCK_SHARE of the classical count is reached."""
    rng = np.random.default_rng(3)
    n = 400
    start = torch.from_numpy(np.where(rng.random(n) < 0.3, 5.0, -0.005)).float()
    logits = torch.from_numpy(rng.normal(0, 2, n)).float()
    keep = logits > 0
    got = cap_added_blocks(keep, logits, start).numpy()

    classical_kept = [i for i in range(n) if keep[i] and start[i] > 0]
    added = sorted((i for i in range(n) if keep[i] and start[i] <= 0), key=lambda i: -float(logits[i]))
    budget = int(MAX_ADDED_BLOCK_SHARE * len(classical_kept))
    assert len(added) > budget  # the cap bites in this case
    assert sorted(np.flatnonzero(got)) == sorted(classical_kept + added[:budget])
    few = keep & ((start > 0) | (logits > float(logits[added[budget // 2]])))  # under the budget: unchanged
    assert torch.equal(cap_added_blocks(few, logits, start), few)
