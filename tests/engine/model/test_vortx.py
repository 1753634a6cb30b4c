"""The whole network: coarse-to-fine bookkeeping, training forward/backward, official layout, weights files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from engine.geometry.cameras import look_at as camera_look_at
from engine.errors import WeightsError
from engine.model import LevelOutput, VortxBatch, VortxConfig, VortxNet, load_weights, read_config, save_weights
from engine.model.coarse_to_fine import Upsampler, subsample_per_sample

KEYS_FILE = Path(__file__).resolve().parents[3].parent / "shared" / "design" / "vortx-official-keys.txt"
TINY = dict(backbone="mnasnet", feature_channels=(16, 8, 8), unet_base_widths=(8, 4, 4))
H, W = 48, 64


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def look_at(eye, target) -> torch.Tensor:
    return torch.from_numpy(camera_look_at(eye, target))


def tiny_batch(batch_size: int = 2, num_views: int = 3, crop_shape=(16, 16, 8)) -> VortxBatch:
    """Random images; cameras on a circle looking at each crop, crops at different world origins."""
    origins = torch.tensor([[0.0, 0.0, 0.0], [3.0, -1.0, 0.5]])[:batch_size]
    size = torch.tensor(crop_shape, dtype=torch.float64) * 0.04
    poses = []
    for origin in origins.double():
        center = origin + size / 2
        poses.append(torch.stack([
            look_at((center + torch.tensor([1.5 * math.cos(a), 1.5 * math.sin(a), 0.8])).tolist(), center.tolist())
            for a in (2 * math.pi * i / num_views for i in range(num_views))
        ]))
    K = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
    return VortxBatch(
        images=torch.rand(batch_size, num_views, 3, H, W) * 255,
        K=K.expand(batch_size, num_views, 3, 3).clone(),
        cam_to_world=torch.stack(poses),
        origin=origins,
        crop_shape=crop_shape,
    )


def keep_everything(net: VortxNet) -> None:
    """Make the coarse/medium heads positive on the (post-ReLU, non-negative) UNet features, so
    pruning keeps every voxel that has any activation and all three levels run."""
    with torch.no_grad():
        for name in ("coarse", "medium"):
            kernel = net.output_layers[name].kernel
            kernel.copy_(kernel.abs() + 0.01)


# --- coarse-to-fine bookkeeping ---------------------------------------------------------------


def test_prune_keeps_positive_logits_and_upsamples_to_the_eight_children():
    net = VortxNet(VortxConfig(**TINY))
    out = LevelOutput(
        coords=torch.tensor([[0, 1, 2, 3], [1, 0, 0, 0], [0, 5, 5, 5], [1, 4, 0, 2]]),
        features=torch.arange(8, dtype=torch.float32).view(4, 2),
        logits=torch.tensor([1.0, -1.0, 0.0, 2.5]),
    )
    up = net.prune_and_upsample(out)
    assert len(up) == 16
    children = {tuple(c) for c in up.coords.tolist()}
    expected = {(0, 2 + dx, 4 + dy, 6 + dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)}
    expected |= {(1, 8 + dx, 0 + dy, 4 + dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)}
    assert children == expected
    first = up.coords[:, 0] == 0
    assert torch.equal(up.features[first], torch.tensor([[0.0, 1.0]]).expand(8, 2))
    assert torch.equal(up.logits[first], torch.full((8,), 1.0))
    assert torch.equal(up.logits[~first], torch.full((8,), 2.5))


def test_upsampler_tables_have_the_official_shapes():
    up = Upsampler()
    assert up.upsample_offsets.shape == (1, 8, 4) and up.upsample_mul.shape == (1, 1, 4)
    assert sorted(map(tuple, up.upsample_offsets[0].tolist())) == sorted(
        (0, dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)
    )


def test_subsample_per_sample_caps_each_sample():
    coords = torch.cat([torch.zeros(10, 4, dtype=torch.long), torch.ones(3, 4, dtype=torch.long)])
    coords[:, 1] = torch.arange(13)
    keep = subsample_per_sample(coords, 5, torch.Generator().manual_seed(0))
    assert (coords[keep, 0] == 0).sum() == 5 and (coords[keep, 0] == 1).sum() == 3
    assert torch.equal(keep, torch.sort(keep).values) and len(keep.unique()) == 8


def test_level_step_rejects_an_unaligned_previous_level():
    net = VortxNet(VortxConfig(**TINY))
    coords = torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0]])
    previous = LevelOutput(coords.flip(0), torch.zeros(2, 24), torch.zeros(2))
    with pytest.raises(ValueError, match="same rows"):
        net.level_step(1, coords, torch.zeros(2, 8), previous)


# --- training forward -------------------------------------------------------------------------


def test_training_forward_and_backward_on_a_tiny_scene():
    torch.manual_seed(0)
    config = VortxConfig(**TINY, max_train_voxels=(40, 150), use_proj_occ=True)
    net = VortxNet(config).train()
    keep_everything(net)
    batch = tiny_batch(crop_shape=(8, 8, 8))
    out = net(batch)

    assert list(out) == ["coarse", "medium", "fine"]
    coarse, medium, fine = out["coarse"], out["medium"], out["fine"]
    assert len(coarse.coords) == 2 * 2 * 2 * 2  # the dense coarse grid of both crops
    for level, prediction in enumerate(out.values()):
        n = len(prediction.coords)
        assert prediction.logits.shape == (n,)
        assert prediction.proj_occ_logits.shape == prediction.valid.shape == prediction.depth.shape == (n, 3)
        assert prediction.pixels.shape == (n, 3, 2)
        assert prediction.voxel_size == pytest.approx(0.04 * 2 ** (2 - level))
        # Corner-anchored voxel positions in each crop's frame.
        expected = batch.origin[prediction.coords[:, 0]] + prediction.coords[:, 1:].float() * prediction.voxel_size
        torch.testing.assert_close(prediction.points, expected)
        assert prediction.valid.any(dim=1).float().mean() > 0.5, "the cameras look at the crops"
    # Voxel dropout caps each sample; every medium voxel is a child of a kept coarse voxel.
    for sample in (0, 1):
        assert (medium.coords[:, 0] == sample).sum() == 40
        assert (fine.coords[:, 0] == sample).sum() == 150
    parents = {tuple(c) for c in coarse.coords[coarse.logits > 0].tolist()}
    assert all((b, x // 2, y // 2, z // 2) in parents for b, x, y, z in medium.coords.tolist())
    assert (fine.tsdf().abs() < 1.05).all()

    loss = sum(p.logits.square().mean() + p.proj_occ_logits[p.valid].sigmoid().mean() for p in out.values())
    loss.backward()
    for name in ("cnn2d.out3.2.weight", "view_embedders.fine.conv.0.weight", "mv_fusion.coarse.depth_mlp.weight",
                 "mv_fusion.fine.transformer.encoder_layers.1.attn.in_proj_weight", "cnns3d.medium.stem.0.kernel",
                 "output_layers.fine.kernel", "layer_norms.medium.weight"):
        grad = net.get_parameter(name).grad
        assert grad is not None and grad.abs().sum() > 0, name


def test_forward_stops_when_no_voxel_is_kept():
    net = VortxNet(VortxConfig(**TINY)).eval()
    with torch.no_grad():
        net.output_layers["coarse"].kernel.fill_(-1.0)  # UNet features are >= 0 -> logits <= 0
        out = net(tiny_batch(batch_size=1, crop_shape=(8, 8, 8)))
    assert list(out) == ["coarse"]


# --- official layout and weights files --------------------------------------------------------


def test_official_config_has_exactly_the_official_keys_and_shapes():
    if not KEYS_FILE.is_file():
        pytest.skip(f"official key list not available: {KEYS_FILE} is missing (only beside the team's checkout)")
    expected = {}
    for line in KEYS_FILE.read_text().splitlines():
        name, shape = line.split("\t")
        expected[name[len("vortx."):]] = tuple(int(s) for s in shape.strip("[]").split(",") if s.strip())
    net = VortxNet(VortxConfig.official())
    assert {k: tuple(v.shape) for k, v in net.state_dict().items()} == expected


def test_weights_round_trip_rebuilds_the_same_network(tmp_path):
    torch.manual_seed(0)
    config = VortxConfig(**TINY, fusion="transformer", use_proj_occ=False)
    net = VortxNet(config)
    path = save_weights(net, config, tmp_path / "tiny.safetensors")
    assert json.loads((tmp_path / "tiny.json").read_text()) == config.to_dict()
    loaded, loaded_config = load_weights(path)
    assert loaded_config == config and not loaded.training and loaded.use_proj_occ is False
    theirs = loaded.state_dict()
    for key, value in net.state_dict().items():
        assert torch.equal(theirs[key], value), key
    # The header alone is enough: the sidecar is only a readable copy.
    (tmp_path / "tiny.json").unlink()
    assert read_config(path) == config


def test_loading_weights_with_a_mismatched_config_names_the_problem(tmp_path):
    net = VortxNet(VortxConfig(**TINY))
    wrong = VortxConfig(**{**TINY, "feature_channels": (16, 8, 4)})
    path = save_weights(net, wrong, tmp_path / "wrong.safetensors")
    with pytest.raises(WeightsError, match="wrong shapes"):
        load_weights(path)
    with pytest.raises(WeightsError, match="does not exist"):
        load_weights(tmp_path / "missing.safetensors")


def test_config_json_round_trip_and_validation():
    config = VortxConfig(**TINY, fusion="average", voxel_dropout=False)
    assert VortxConfig.from_json(config.to_json()) == config
    official = VortxConfig.official()
    assert (official.backbone, official.feature_channels, official.unet_base_widths) == ("mnasnet", (80, 40, 24), (32, 16, 8))
    assert [official.unet_in_channels(level) for level in range(3)] == [80, 137, 73]
    with pytest.raises(ValueError):
        VortxConfig(fusion="max")
    with pytest.raises(ValueError):
        VortxConfig.from_dict({"backbone": "mnasnet", "colour": "red"})
