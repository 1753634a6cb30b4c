"""SparseBatchNorm / SparseReLU: statistics over active voxels only, checkpoint-compatible names."""

from __future__ import annotations

import torch
from torch import nn

from engine.sparse import SparseBatchNorm, SparseReLU, SparseVoxels

DT = torch.float64
TOL = dict(rtol=1e-6, atol=1e-6)


def sparse_input(n: int = 50, channels: int = 4, seed: int = 0) -> SparseVoxels:
    gen = torch.Generator().manual_seed(seed)
    coords = torch.unique(torch.randint(0, 8, (n, 4), generator=gen), dim=0)
    coords[:, 0] %= 2
    coords = torch.unique(coords, dim=0)
    feats = torch.randn(len(coords), channels, generator=gen, dtype=DT) * 3 + 2
    return SparseVoxels(coords, feats)


def test_batchnorm_uses_statistics_of_active_voxels_only():
    x = sparse_input()
    bn = SparseBatchNorm(4).double()
    with torch.no_grad():
        bn.weight.copy_(torch.tensor([1.0, 2.0, 0.5, -1.0]))
        bn.bias.copy_(torch.tensor([0.0, 1.0, -1.0, 0.5]))
    y = bn(x)
    assert y.coords is x.coords and y.cache is x.cache
    mean = x.feats.mean(0)
    var = ((x.feats - mean) ** 2).mean(0)  # biased variance normalises in training mode
    expected = (x.feats - mean) / torch.sqrt(var + bn.eps) * bn.weight + bn.bias
    torch.testing.assert_close(y.feats, expected, **TOL)
    n = x.num_voxels
    torch.testing.assert_close(bn.running_mean, 0.1 * mean, **TOL)
    torch.testing.assert_close(bn.running_var, 0.9 + 0.1 * var * n / (n - 1), **TOL)
    assert int(bn.num_batches_tracked) == 1

    # A dense BatchNorm3d over the whole grid would count the inactive zeros and give other values.
    dense_mean = x.feats.sum(0) / (2 * 8 * 8 * 8)
    assert not torch.allclose(dense_mean, mean)

    bn.eval()
    z = bn(x)
    expected_eval = (x.feats - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps) * bn.weight + bn.bias
    torch.testing.assert_close(z.feats, expected_eval, **TOL)


def test_batchnorm_state_dict_names_match_batchnorm1d():
    assert list(SparseBatchNorm(7).state_dict()) == list(nn.BatchNorm1d(7).state_dict())
    reference = nn.BatchNorm1d(7)
    SparseBatchNorm(7).load_state_dict(reference.state_dict(), strict=True)


def test_relu_keeps_coordinates():
    x = sparse_input(seed=1)
    y = SparseReLU()(x)
    assert y.coords is x.coords
    torch.testing.assert_close(y.feats, x.feats.clamp(min=0))


def test_scene_statistics_normalise_with_the_voxels_passed_in_and_keep_the_running_averages():
    x = sparse_input(seed=2)
    bn = SparseBatchNorm(4).double()
    with torch.no_grad():
        bn.running_mean.copy_(torch.tensor([5.0, -3.0, 0.0, 1.0]))
        bn.running_var.copy_(torch.tensor([0.5, 4.0, 2.0, 9.0]))
        bn.weight.copy_(torch.tensor([1.0, 2.0, 0.5, -1.0]))
        bn.bias.copy_(torch.tensor([0.0, 1.0, -1.0, 0.5]))
    bn.scene_statistics = True
    bn.eval()
    before = {k: v.clone() for k, v in bn.state_dict().items()}
    y = bn(x)
    mean = x.feats.mean(0)
    var = ((x.feats - mean) ** 2).mean(0)
    torch.testing.assert_close(y.feats, (x.feats - mean) / torch.sqrt(var + bn.eps) * bn.weight + bn.bias, **TOL)
    for key, value in bn.state_dict().items():
        torch.testing.assert_close(value, before[key], **TOL)  # inference never changes the weights file's state

    bn.scene_statistics = False
    expected_running = (x.feats - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps) * bn.weight + bn.bias
    torch.testing.assert_close(bn(x).feats, expected_running, **TOL)


def test_a_single_voxel_in_training_is_normalised_with_the_running_averages_and_still_trains():
    # A training crop whose pruned level collapsed to one voxel: batch statistics do not exist.
    x = sparse_input(seed=3)
    one = SparseVoxels(x.coords[:1], x.feats[:1].clone())
    bn = SparseBatchNorm(4).double()
    with torch.no_grad():
        bn.running_mean.copy_(torch.tensor([1.0, -1.0, 0.5, 2.0]))
        bn.running_var.copy_(torch.tensor([4.0, 1.0, 0.25, 9.0]))
    before = {k: v.clone() for k, v in bn.state_dict().items()}
    y = bn.train()(one)
    expected = (one.feats - bn.running_mean) / torch.sqrt(bn.running_var + bn.eps) * bn.weight + bn.bias
    torch.testing.assert_close(y.feats, expected, **TOL)
    for key, value in bn.state_dict().items():
        torch.testing.assert_close(value, before[key], **TOL)
    y.feats.sum().backward()
    assert bn.weight.grad is not None and torch.all(bn.weight.grad != 0)
