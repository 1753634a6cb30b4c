"""SparseUNet (SPVCNN voxel branch): official checkpoint keys, coordinates, gradients, batch independence."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from engine.model.unet3d import SparseUNet
from engine.sparse import SparseVoxels

KEYS_FILE = Path(__file__).resolve().parents[3].parent / "shared" / "design" / "vortx-official-keys.txt"
# (level name, input channels, base width, output channels) of the official model (vortx-spec.md section 1).
LEVELS = [("coarse", 80, 32, 96), ("medium", 137, 16, 48), ("fine", 73, 8, 24)]


def official_cnn3d_keys(level: str) -> dict[str, tuple[int, ...]]:
    """{key without 'vortx.cnns3d.<level>.': shape} from the design keys file, or skip when absent."""
    if not KEYS_FILE.is_file():
        pytest.skip(f"official key list not available: {KEYS_FILE} is missing (only present beside the team's checkout)")
    prefix = f"vortx.cnns3d.{level}."
    keys = {}
    for line in KEYS_FILE.read_text().splitlines():
        name, _, shape = line.partition("\t")
        if name.startswith(prefix):
            keys[name[len(prefix) :]] = tuple(int(v) for v in re.findall(r"\d+", shape))
    assert keys, f"no {prefix} keys in {KEYS_FILE}"
    return keys


def random_scene(seed: int, channels: int, grid=(12, 12, 8), occupancy: float = 0.25, batch: int = 2):
    gen = torch.Generator().manual_seed(seed)
    coords = (torch.rand(batch, *grid, generator=gen) < occupancy).nonzero()
    coords = coords[torch.randperm(len(coords), generator=gen)]
    feats = torch.randn(len(coords), channels, generator=gen, dtype=torch.float64)
    return coords, feats


@pytest.mark.parametrize("level,in_channels,base,out_channels", LEVELS)
def test_state_dict_matches_official_keys_and_shapes(level, in_channels, base, out_channels):
    official = official_cnn3d_keys(level)
    net = SparseUNet(in_channels, base)
    ours = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    assert sorted(ours) == sorted(official), (
        f"missing {sorted(set(official) - set(ours))[:5]}, unexpected {sorted(set(ours) - set(official))[:5]}"
    )
    for key, shape in official.items():
        assert ours[key] == shape, f"{key}: ours {ours[key]}, official {shape}"
    assert net.out_channels == out_channels


@pytest.mark.parametrize("level,in_channels,base,out_channels", LEVELS)
def test_official_level_widths_run(level, in_channels, base, out_channels):
    net = SparseUNet(in_channels, base).eval()
    coords, feats = random_scene(1, in_channels, grid=(8, 8, 6))
    with torch.no_grad():
        out = net(SparseVoxels(coords, feats.float()))
    assert out.coords is coords and out.feats.shape == (len(coords), out_channels)


def test_forward_backward_preserves_coordinates():
    torch.manual_seed(0)
    net = SparseUNet(137, 16).double().train()
    coords, feats = random_scene(1, 137, grid=(10, 10, 6))
    feats.requires_grad_()
    out = net(SparseVoxels(coords, feats))
    assert out.coords is coords and out.stride == 1
    assert out.feats.shape == (len(coords), 48)
    assert bool((out.feats >= 0).all()), "the last residual block ends in a ReLU"
    out.feats.square().mean().backward()
    assert feats.grad is not None and torch.isfinite(feats.grad).all() and feats.grad.abs().sum() > 0
    for name, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


def test_row_order_of_the_input_does_not_matter():
    torch.manual_seed(0)
    net = SparseUNet(5, 4).double().eval()
    coords, feats = random_scene(4, 5)  # shuffled rows: the net sorts internally and restores the order
    order = torch.argsort(coords[:, 0] * 10**6 + coords[:, 1] * 10**4 + coords[:, 2] * 100 + coords[:, 3])
    with torch.no_grad():
        shuffled = net(SparseVoxels(coords, feats))
        x_sorted = SparseVoxels(coords[order], feats[order])
        presorted = net(x_sorted)
    assert shuffled.coords is coords
    torch.testing.assert_close(shuffled.feats[order], presorted.feats, rtol=1e-9, atol=1e-9)
    # Sorted input runs directly on its own cache: both strided levels and their maps are there.
    assert sorted(x_sorted.cache.coords) == [1, 2, 4]


def test_batch_elements_do_not_interact():
    torch.manual_seed(0)
    net = SparseUNet(6, 4).double().eval()
    with torch.no_grad():  # non-trivial running statistics, so BN is not the identity
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.running_mean.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 1.5)
    coords, feats = random_scene(2, 6)
    first = coords[:, 0] == 0
    with torch.no_grad():
        base = net(SparseVoxels(coords, feats)).feats
        changed = feats.clone()
        changed[~first] = torch.randn(int((~first).sum()), 6, dtype=torch.float64)
        other = net(SparseVoxels(coords, changed)).feats
        alone = net(SparseVoxels(coords[first], feats[first])).feats
    assert not torch.allclose(base[~first], other[~first]), "batch 1 did change"
    torch.testing.assert_close(other[first], base[first], rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(alone, base[first], rtol=1e-6, atol=1e-6)


def test_wrong_input_width_is_rejected():
    coords, feats = random_scene(3, 5)
    with pytest.raises(ValueError, match="expects 6 input channels"):
        SparseUNet(6, 4)(SparseVoxels(coords, feats))
