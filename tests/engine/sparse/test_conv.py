"""Sparse convolutions against torch's dense Conv3d / ConvTranspose3d and an independent Python loop.

Dense equivalents (vortx-spec.md section 6) are exact when the dense input is zero at inactive
voxels and the dense output is read only at the sparse output coordinates. Everything runs in
float64 with tolerance 1e-6, forward and gradients for features and kernel.
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from engine.sparse import SparseConv3d, SparseVoxels, conv3d

DT = torch.float64
TOL = dict(rtol=1e-6, atol=1e-6)
GRID = 10
# Sparse coordinates are (dense index - SHIFT) * stride, so negative coordinates are exercised. SHIFT is
# even so that stride-2 parents (floor(c / 2s) * 2s) coincide with the dense grid's 2x2x2 cells.
SHIFT = 4


def random_scene(seed: int, channels: int, stride: int = 1, grid: int = GRID, occupancy: float = 0.3, batch: int = 2):
    """Dense indices (N, 4) [b, i, j, k], the sparse tensor's coords (N, 4) and random feats (N, C)."""
    gen = torch.Generator().manual_seed(seed)
    idx = (torch.rand(batch, grid, grid, grid, generator=gen) < occupancy).nonzero()
    # Shuffle rows: kernel maps must not rely on sorted input coordinates.
    idx = idx[torch.randperm(len(idx), generator=gen)]
    coords = idx.clone()
    coords[:, 1:] = (idx[:, 1:] - SHIFT) * stride
    feats = torch.randn(len(idx), channels, generator=gen, dtype=DT)
    return idx, coords, feats


def to_dense(idx: torch.Tensor, feats: torch.Tensor, grid: int, batch: int = 2) -> torch.Tensor:
    """(N, C) feats at dense indices -> (B, C, G, G, G), zero elsewhere (differentiable in feats)."""
    vol = feats.new_zeros(batch, grid, grid, grid, feats.shape[1])
    vol = vol.index_put((idx[:, 0], idx[:, 1], idx[:, 2], idx[:, 3]), feats)
    return vol.permute(0, 4, 1, 2, 3)


def at(vol: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """(B, C, X, Y, Z) read at (N, 4) dense indices -> (N, C)."""
    return vol[idx[:, 0], :, idx[:, 1], idx[:, 2], idx[:, 3]]


def dense_index(coords: torch.Tensor, stride: int, shift: int) -> torch.Tensor:
    out = coords.clone()
    out[:, 1:] = coords[:, 1:] // stride + shift
    return out


def check_against_dense(sparse_fn, dense_fn, feats: torch.Tensor, kernel: torch.Tensor, out_rows_dense, seed: int = 0):
    """Run sparse and dense versions on leaf copies; compare outputs and both gradients.

    sparse_fn(feats, kernel) -> (N_out, Cout); dense_fn(feats, kernel) -> dense output volume;
    out_rows_dense: (N_out, 4) dense indices of the sparse output rows.
    """
    fs, ks = feats.clone().requires_grad_(), kernel.clone().requires_grad_()
    fd, kd = feats.clone().requires_grad_(), kernel.clone().requires_grad_()
    out_s = sparse_fn(fs, ks)
    out_d = at(dense_fn(fd, kd), out_rows_dense)
    assert out_s.shape == out_d.shape
    torch.testing.assert_close(out_s, out_d, **TOL)
    weights = torch.randn(out_s.shape, generator=torch.Generator().manual_seed(seed), dtype=DT)
    (out_s * weights).sum().backward()
    (out_d * weights).sum().backward()
    torch.testing.assert_close(fs.grad, fd.grad, **TOL)
    torch.testing.assert_close(ks.grad, kd.grad, **TOL)
    # Guard against a vacuous comparison (e.g. an empty neighbourhood everywhere).
    assert fs.grad.abs().sum() > 0 and ks.grad.abs().sum() > 0


@pytest.mark.parametrize("stride", [1, 2])
def test_submanifold_3x3x3_matches_dense_conv(stride):
    idx, coords, feats = random_scene(1, channels=3, stride=stride)
    kernel = torch.randn(27, 3, 4, dtype=DT)

    def sparse(f, k):
        out = conv3d(SparseVoxels(coords, f, stride=stride), k, 3)
        assert out.coords is coords and out.stride == stride
        return out.feats

    def dense(f, k):
        return F.conv3d(to_dense(idx, f, GRID), k.view(3, 3, 3, 3, 4).permute(4, 3, 2, 1, 0), padding=1)

    check_against_dense(sparse, dense, feats, kernel, idx)


def test_pointwise_matches_dense_conv():
    idx, coords, feats = random_scene(2, channels=5)
    kernel = torch.randn(5, 2, dtype=DT)

    def sparse(f, k):
        return conv3d(SparseVoxels(coords, f), k, 1).feats

    def dense(f, k):
        return F.conv3d(to_dense(idx, f, GRID), k.t()[:, :, None, None, None])

    check_against_dense(sparse, dense, feats, kernel, idx)


@pytest.mark.parametrize("stride", [1, 2])
def test_downsample_k2s2_matches_dense_strided_conv(stride):
    idx, coords, feats = random_scene(3, channels=3, stride=stride)
    kernel = torch.randn(8, 3, 4, dtype=DT)
    x = SparseVoxels(coords, feats, stride=stride)
    out = conv3d(x, kernel, 2, stride=2)

    # Output set = parents that have at least one child, computed independently on dense indices.
    assert out.stride == 2 * stride
    assert bool((out.coords[:, 1:] % (2 * stride) == 0).all())
    expected = torch.unique(torch.cat([idx[:, :1], idx[:, 1:] // 2], dim=1), dim=0)
    got = torch.unique(dense_index(out.coords, 2 * stride, SHIFT // 2), dim=0)
    assert torch.equal(got, expected)
    assert len(torch.unique(out.coords, dim=0)) == len(out.coords)

    def sparse(f, k):
        return conv3d(x.replace_feats(f), k, 2, stride=2).feats

    def dense(f, k):
        return F.conv3d(to_dense(idx, f, GRID), k.view(2, 2, 2, 3, 4).permute(4, 3, 0, 1, 2), stride=2)

    check_against_dense(sparse, dense, feats, kernel, dense_index(out.coords, 2 * stride, SHIFT // 2))


def test_transposed_k2s2_returns_to_fine_set_and_matches_dense():
    idx, coords, feats = random_scene(4, channels=3)
    x = SparseVoxels(coords, feats)
    coarse = conv3d(x, torch.randn(8, 3, 4, dtype=DT), 2, stride=2)
    coarse_idx = dense_index(coarse.coords, 2, SHIFT // 2)
    coarse_feats = torch.randn(coarse.num_voxels, 4, dtype=DT)
    kernel = torch.randn(8, 4, 5, dtype=DT)

    up = conv3d(coarse.replace_feats(coarse_feats), kernel, 2, stride=2, transposed=True)
    assert up.coords is coords and up.stride == 1 and up.feats.shape == (len(coords), 5)

    def sparse(f, k):
        return conv3d(coarse.replace_feats(f), k, 2, stride=2, transposed=True).feats

    def dense(f, k):
        vol = to_dense(coarse_idx, f, GRID // 2)
        return F.conv_transpose3d(vol, k.view(2, 2, 2, 4, 5).permute(3, 4, 0, 1, 2), stride=2)

    check_against_dense(sparse, dense, coarse_feats, kernel, idx)


# --- independent reference: the official formula with Python loops --------------------------------


def reference_conv(coords, feats, kernel, stride, kind):
    """out[p] = sum_k in[p + off_k * s] @ W[k], written from the spec with dicts and loops.

    kind: "sub" (3^3, outputs at the inputs), "down" (2^3 s2, outputs at parents with children) or
    "up" (inputs are parents; outputs given as `coords` of the fine set, see caller).
    Returns {output coordinate tuple: (Cout,) tensor}.
    """
    rows = {tuple(c): i for i, c in enumerate(coords.tolist())}
    out = {}
    if kind == "sub":
        for p in rows:
            acc = torch.zeros(kernel.shape[2], dtype=DT)
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for dz in (-1, 0, 1):
                        k = (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)
                        q = (p[0], p[1] + dx * stride, p[2] + dy * stride, p[3] + dz * stride)
                        if q in rows:
                            acc = acc + feats[rows[q]] @ kernel[k]
            out[p] = acc
    elif kind == "down":
        for p, i in rows.items():
            parent = (p[0],) + tuple(math.floor(v / (2 * stride)) * 2 * stride for v in p[1:])
            dx, dy, dz = ((v - pv) // stride for v, pv in zip(p[1:], parent[1:]))
            k = dx * 4 + dy * 2 + dz
            out[parent] = out.get(parent, 0) + feats[i] @ kernel[k]
    return out


def test_reference_loop_submanifold_and_strided():
    gen = torch.Generator().manual_seed(5)
    for stride in (1, 2):
        coords = torch.unique(torch.cat([torch.randint(0, 2, (40, 1), generator=gen),
                                         torch.randint(-3, 3, (40, 3), generator=gen) * stride], 1), dim=0)
        coords = coords[torch.randperm(len(coords), generator=gen)]
        feats = torch.randn(len(coords), 2, dtype=DT, generator=gen)
        x = SparseVoxels(coords, feats, stride=stride)

        sub_kernel = torch.randn(27, 2, 3, dtype=DT, generator=gen)
        ref = reference_conv(coords, feats, sub_kernel, stride, "sub")
        got = conv3d(x, sub_kernel, 3)
        for c, f in zip(got.coords.tolist(), got.feats):
            torch.testing.assert_close(f, ref[tuple(c)], **TOL)

        down_kernel = torch.randn(8, 2, 3, dtype=DT, generator=gen)
        ref = reference_conv(coords, feats, down_kernel, stride, "down")
        down = conv3d(x, down_kernel, 2, stride=2)
        assert sorted(map(tuple, down.coords.tolist())) == sorted(ref)
        for c, f in zip(down.coords.tolist(), down.feats):
            torch.testing.assert_close(f, ref[tuple(c)], **TOL)

        # Transposed: fine[p] = coarse[parent(p)] @ W[k((p / s) mod 2)], written out directly.
        up_kernel = torch.randn(8, 3, 2, dtype=DT, generator=gen)
        up = conv3d(down, up_kernel, 2, stride=2, transposed=True)
        coarse_row = {tuple(c): i for i, c in enumerate(down.coords.tolist())}
        assert up.coords is coords
        for c, f in zip(coords.tolist(), up.feats):
            parent = (c[0],) + tuple(math.floor(v / (2 * stride)) * 2 * stride for v in c[1:])
            bx, by, bz = ((v // stride) % 2 for v in c[1:])
            expected = down.feats[coarse_row[parent]] @ up_kernel[bx * 4 + by * 2 + bz]
            torch.testing.assert_close(f, expected, **TOL)


# --- module behaviour ------------------------------------------------------------------------------


def test_module_parameter_shapes_and_init_bounds():
    torch.manual_seed(0)
    sub = SparseConv3d(16, 32, 3)
    point = SparseConv3d(16, 32, 1)
    down = SparseConv3d(16, 32, 2, stride=2)
    up = SparseConv3d(16, 32, 2, stride=2, transposed=True)
    assert [n for n, _ in sub.named_parameters()] == ["kernel"]
    assert sub.kernel.shape == (27, 16, 32) and point.kernel.shape == (16, 32)
    assert down.kernel.shape == (8, 16, 32) and up.kernel.shape == (8, 16, 32)
    for module, fan in ((sub, 27 * 16), (point, 16), (down, 8 * 16), (up, 8 * 32)):
        bound = 1 / math.sqrt(fan)
        assert module.kernel.abs().max() <= bound
        assert module.kernel.abs().max() > 0.9 * bound  # uniform over the whole range, not a narrower init
    with pytest.raises(ValueError):
        SparseConv3d(4, 4, 3, stride=2)


def test_module_forward_uses_conv3d():
    idx, coords, feats = random_scene(6, channels=3)
    module = SparseConv3d(3, 4, 3).double()
    out = module(SparseVoxels(coords, feats))
    torch.testing.assert_close(out.feats, conv3d(SparseVoxels(coords, feats), module.kernel, 3).feats)


def test_autocast_cpu_runs_in_bfloat16():
    _, coords, feats = random_scene(7, channels=8)
    feats, kernel = feats.float(), torch.randn(27, 8, 8)
    x = SparseVoxels(coords, feats)
    full = conv3d(x, kernel, 3).feats
    with torch.autocast("cpu", dtype=torch.bfloat16):
        low = conv3d(x, kernel, 3).feats
    assert low.dtype == torch.bfloat16
    torch.testing.assert_close(low.float(), full, rtol=0.05, atol=0.1)


def test_empty_tensor():
    coords = torch.zeros(0, 4, dtype=torch.int64)
    x = SparseVoxels(coords, torch.zeros(0, 3, dtype=DT))
    assert conv3d(x, torch.randn(27, 3, 4, dtype=DT), 3).feats.shape == (0, 4)
    down = conv3d(x, torch.randn(8, 3, 4, dtype=DT), 2, stride=2)
    assert down.feats.shape == (0, 4) and down.coords.shape == (0, 4)
    assert conv3d(down, torch.randn(8, 4, 2, dtype=DT), 2, stride=2, transposed=True).feats.shape == (0, 2)
