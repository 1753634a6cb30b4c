"""Kernel maps, coordinate hashing and the shared cache of SparseVoxels."""

from __future__ import annotations

import pytest
import torch

from engine.sparse import (
    SparseVoxels,
    build_downsample_map,
    build_submanifold_map,
    cat_features,
    conv3d,
    kernel_offsets,
    lexicographic_order,
)


def brute_force_pairs(coords: torch.Tensor, offset: list[int], stride: int) -> set[tuple[int, int]]:
    """{(input row, output row)} with coords[input] == coords[output] + offset * stride."""
    rows = {tuple(c): i for i, c in enumerate(coords.tolist())}
    pairs = set()
    for o, c in enumerate(coords.tolist()):
        q = (c[0], c[1] + offset[0] * stride, c[2] + offset[1] * stride, c[3] + offset[2] * stride)
        if q in rows:
            pairs.add((rows[q], o))
    return pairs


def test_offset_orders_follow_torchsparse():
    k3 = kernel_offsets(3).tolist()
    assert len(k3) == 27 and k3[13] == [0, 0, 0]
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                assert k3[(dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)] == [dx, dy, dz]
    k2 = kernel_offsets(2).tolist()
    assert k2 == [[dx, dy, dz] for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]


@pytest.mark.parametrize("shuffle", [True, False], ids=["shuffled", "sorted"])
def test_submanifold_map_equals_brute_force_on_far_apart_coordinates(shuffle):
    # Coordinates spanning a huge, sparse range with negatives and batch values 0 and 3: the packed
    # keys must not alias neighbours across axes or across batch entries.
    gen = torch.Generator().manual_seed(0)
    base = torch.randint(-2, 3, (300, 4), generator=gen)
    base[:, 0] = base[:, 0].abs() % 2 * 3
    base[:150, 1] += 100_000
    base[150:, 3] -= 70_000
    coords = torch.unique(base, dim=0)
    if shuffle:  # torch.unique returns sorted rows; both paths of the map builder are checked
        coords = coords[torch.randperm(len(coords), generator=gen)]
    kmap = build_submanifold_map(coords, 1, 3)
    assert kmap.identity_offset == 13 and kmap.counts[13] == 0
    offsets = kernel_offsets(3).tolist()
    for k in range(27):
        if k == 13:
            continue
        i, o = kmap.pairs(k)
        got = set(zip(i.tolist(), o.tolist()))
        assert got == brute_force_pairs(coords, offsets[k], 1)
        assert len(got) == len(i)
        assert bool((o[1:] >= o[:-1]).all()), "pairs are sorted by output row"
        # Mirror symmetry used to halve the search: offset -d holds the swapped pairs of d.
        mi, mo = kmap.pairs(26 - k)
        assert got == set(zip(mo.tolist(), mi.tolist()))


def test_duplicates_and_misaligned_coordinates_are_rejected():
    coords = torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0]])
    with pytest.raises(ValueError, match="duplicate"):
        build_submanifold_map(coords, 1, 3)
    with pytest.raises(ValueError, match="duplicate"):
        build_downsample_map(coords, 1)
    with pytest.raises(ValueError, match="multiples"):
        build_submanifold_map(torch.tensor([[0, 2, 0, 0], [0, 3, 0, 0]]), 2, 3)


def test_downsample_map_parents_and_offsets():
    coords = torch.tensor([[0, -1, 0, 0], [0, -2, 1, 0], [0, 3, 3, 3], [1, -1, 0, 0], [0, 2, 2, 2]])
    parents, kmap = build_downsample_map(coords, 1)
    assert kmap.n_in == 5 and kmap.n_out == len(parents) == 3
    seen = {}
    for k in range(8):
        for i, o in zip(*(t.tolist() for t in kmap.pairs(k))):
            c, p = coords[i].tolist(), parents[o].tolist()
            assert p == [c[0]] + [(v // 2) * 2 for v in c[1:]]
            assert k == (c[1] - p[1]) * 4 + (c[2] - p[2]) * 2 + (c[3] - p[3])
            seen[i] = o
    assert sorted(seen) == list(range(5)), "every input row has exactly one parent"


def test_cache_reuses_maps_and_coordinates_across_derived_tensors():
    coords = torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0], [0, 1, 1, 0], [0, 4, 4, 4]])
    x = SparseVoxels(coords, torch.randn(4, 2))
    y = conv3d(x, torch.randn(27, 2, 3), 3)
    assert y.cache is x.cache and len(x.cache.kernel_maps) == 1
    conv3d(y, torch.randn(27, 3, 3), 3)
    assert len(x.cache.kernel_maps) == 1, "same stride and kernel size reuse the map"
    down = conv3d(y, torch.randn(8, 3, 3), 2, stride=2)
    assert x.cache.coords[2] is down.coords and down.stride == 2
    down_again = conv3d(y, torch.randn(8, 3, 5), 2, stride=2)
    assert down_again.coords is down.coords
    cat = cat_features([down, down_again])
    assert cat.num_channels == 8 and cat.coords is down.coords
    with pytest.raises(ValueError):
        cat_features([down, y])
    with pytest.raises(ValueError):
        _ = x + down


def test_transposed_conv_needs_cached_fine_coordinates():
    coarse = SparseVoxels(torch.tensor([[0, 0, 0, 0], [0, 2, 0, 0]]), torch.randn(2, 3), stride=2)
    with pytest.raises(ValueError, match="stride-1 coordinates"):
        conv3d(coarse, torch.randn(8, 3, 3), 2, stride=2, transposed=True)


def test_new_coordinate_set_cannot_join_an_existing_cache():
    x = SparseVoxels(torch.tensor([[0, 0, 0, 0]]), torch.randn(1, 2))
    with pytest.raises(ValueError, match="different coordinate set"):
        SparseVoxels(torch.tensor([[0, 1, 0, 0]]), torch.randn(1, 2), cache=x.cache)
    with pytest.raises(ValueError):
        SparseVoxels(torch.tensor([[0, 1, 0]]), torch.randn(1, 2))
    with pytest.raises(ValueError):
        SparseVoxels(torch.tensor([[0, 1, 0, 0]]).int(), torch.randn(1, 2))


def test_downsampling_refuses_hand_registered_coarse_coordinates():
    fine = SparseVoxels(torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0]]), torch.randn(2, 2))
    SparseVoxels(torch.tensor([[0, 0, 0, 0]]), torch.randn(1, 2), stride=2, cache=fine.cache)
    with pytest.raises(ValueError, match="not made by downsampling"):
        conv3d(fine, torch.randn(8, 2, 2), 2, stride=2)


def test_lexicographic_order():
    coords = torch.tensor([[1, 0, 0, 0], [0, 5, -2, 1], [0, 5, -3, 7], [0, -9, 9, 9]])
    order = lexicographic_order(coords)
    assert order.tolist() == [3, 2, 1, 0]
    assert lexicographic_order(coords[order]) is None
    assert lexicographic_order(coords[:1]) is None
