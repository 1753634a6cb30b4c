"""Kernel maps: for each kernel offset, which input rows feed which output rows.

A convolution computes ``out[p] = sum_k in[p + off_k * s] @ W[k]`` (torchsparse v1.4 semantics,
vortx-spec.md section 6). A ``KernelMap`` lists, for every offset k, the pairs (input row, output
row) for which both voxels are active.

Neighbour search uses hashing without a hash table: coordinates are packed into one int64 key by a
mixed radix whose per-axis range covers every queried position, the keys are sorted once, and each
offset's queries (``key(p) + key(off * s)``: the packing is linear) are looked up with
``torch.searchsorted`` plus an equality check. Everything is vectorised and device-agnostic.

Offset order (torchsparse v1.4 ``get_kernel_offsets``):
- odd kernels (3^3): x fastest, ``k = (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)``, centre 13;
- the 2^3 down/up-sampling kernel: z fastest, offsets in {0, 1}, ``k = dx * 4 + dy * 2 + dz``.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import accumulate

import torch
from torch import Tensor

# Keys must stay below 2**63; the margin keeps sums of a key and an offset delta representable.
_MAX_KEY_SPACE = 2**62


@dataclass(frozen=True)
class KernelMap:
    """Input/output row pairs grouped by kernel offset.

    in_idx, out_idx: (P,) int64, grouped by offset in offset order (offset k's pairs follow those of
        offsets < k), sorted by output row within each offset (scatter locality); see ``pairs(k)``.
    counts: pairs per offset, length K.
    n_in, n_out: rows of the input and output feature matrices.
    identity_offset: offset whose pairs are exactly r -> r for every row (the centre of a
        submanifold kernel); its pairs are *not* stored (counts entry 0) and the convolution applies
        it as a plain matmul. None when there is no such offset.
    """

    in_idx: Tensor
    out_idx: Tensor
    counts: tuple[int, ...]
    n_in: int
    n_out: int
    identity_offset: int | None = None

    def __post_init__(self) -> None:
        # Slice starts per offset, computed once (the convolution asks for them on every call).
        object.__setattr__(self, "_starts", tuple(accumulate(self.counts, initial=0)))

    @property
    def num_offsets(self) -> int:
        return len(self.counts)

    @property
    def max_pairs(self) -> int:
        """Pairs of the largest stored offset (workspace size of the convolution)."""
        return max(self.counts, default=0)

    def pairs(self, k: int) -> tuple[Tensor, Tensor]:
        """(input rows, output rows) of offset k, each (P_k,)."""
        start = self._starts[k]  # type: ignore[attr-defined]
        end = start + self.counts[k]
        return self.in_idx[start:end], self.out_idx[start:end]

    def num_pairs(self) -> int:
        """Active (input, output) pairs including the unstored identity offset."""
        return sum(self.counts) + (self.n_in if self.identity_offset is not None else 0)

    def transposed(self) -> "KernelMap":
        """The same pairs with inputs and outputs swapped (a deconvolution reuses a downsample map).

        Pairs are re-sorted by their new output row within each offset.
        """
        if self.identity_offset is not None:
            raise ValueError("transposing a map with an unstored identity offset is not supported")
        in_parts, out_parts = [], []
        for k in range(self.num_offsets):
            i, o = self.pairs(k)
            order = torch.argsort(i)
            in_parts.append(o[order])
            out_parts.append(i[order])
        return KernelMap(
            in_idx=_cat_or_empty(in_parts, self.in_idx),
            out_idx=_cat_or_empty(out_parts, self.out_idx),
            counts=self.counts,
            n_in=self.n_out,
            n_out=self.n_in,
        )


def kernel_offsets(kernel_size: int) -> Tensor:
    """(K, 3) int64 offsets (dx, dy, dz) in torchsparse v1.4 order, before scaling by the stride."""
    if kernel_size % 2 == 1:
        r = kernel_size // 2
        span = range(-r, r + 1)
        return torch.tensor([(dx, dy, dz) for dz in span for dy in span for dx in span], dtype=torch.int64)
    if kernel_size == 2:
        return torch.tensor([(dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], dtype=torch.int64)
    raise ValueError(f"kernel_size must be odd or 2, got {kernel_size}")


class _KeyPacker:
    """Mixed-radix packing of [batch, x, y, z] into one int64, exact for coordinates in [lo, hi].

    Because the packing is linear inside that box, ``key(p + d) == key(p) + delta(d)``.
    """

    def __init__(self, lo: list[int], hi: list[int]) -> None:
        spans = [h - l + 1 for l, h in zip(lo, hi)]
        space = spans[0] * spans[1] * spans[2] * spans[3]
        if space >= _MAX_KEY_SPACE:
            raise ValueError(
                f"coordinate range too large to hash: batch {lo[0]}..{hi[0]}, x {lo[1]}..{hi[1]}, "
                f"y {lo[2]}..{hi[2]}, z {lo[3]}..{hi[3]}"
            )
        self.lo = lo
        self.mult = [spans[1] * spans[2] * spans[3], spans[2] * spans[3], spans[3], 1]

    def keys(self, coords: Tensor) -> Tensor:
        """(N, 4) int64 -> (N,) int64."""
        key = (coords[:, 0] - self.lo[0]) * self.mult[0]
        for a in (1, 2, 3):
            key = key + (coords[:, a] - self.lo[a]) * self.mult[a]
        return key

    def delta(self, offset_xyz: list[int]) -> int:
        return sum(d * m for d, m in zip(offset_xyz, self.mult[1:]))


def _coord_bounds(coords: Tensor, margin: int) -> tuple[list[int], list[int]]:
    """Per-axis min/max of (N, 4) coords, widened by ``margin`` on x, y, z (one device sync)."""
    bounds = torch.stack([coords.min(dim=0).values, coords.max(dim=0).values]).tolist()
    lo = [bounds[0][0]] + [v - margin for v in bounds[0][1:]]
    hi = [bounds[1][0]] + [v + margin for v in bounds[1][1:]]
    return lo, hi


def _check_stride_multiples(coords: Tensor, stride: int) -> None:
    if stride > 1 and bool((coords[:, 1:] % stride != 0).any()):
        raise ValueError(f"coordinates of a stride-{stride} tensor must be multiples of {stride} in x, y, z")


def _cat_or_empty(parts: list[Tensor], like: Tensor) -> Tensor:
    return torch.cat(parts) if parts else like.new_empty(0)


def lexicographic_order(coords: Tensor) -> Tensor | None:
    """Row permutation sorting (N, 4) coords by (batch, x, y, z), or None when already sorted.

    Kernel maps build about 2.5x faster and convolutions run about 1.5x faster on sorted rows
    (cache-friendly searches, gathers and scatters), so multi-layer networks sort once up front.
    """
    if coords.shape[0] < 2:
        return None
    keys = _KeyPacker(*_coord_bounds(coords, 0)).keys(coords)
    if bool((keys[1:] >= keys[:-1]).all()):
        return None
    return torch.argsort(keys)


def build_submanifold_map(coords: Tensor, stride: int, kernel_size: int) -> KernelMap:
    """Kernel map of a stride-1 (submanifold) convolution: outputs at the input coordinates.

    coords: (N, 4) int64, unique, multiples of ``stride``. kernel_size: odd.
    Pair (i, o) of offset k means ``coords[i] == coords[o] + off_k * stride``.
    """
    if kernel_size % 2 != 1:
        raise ValueError(f"submanifold convolution needs an odd kernel size, got {kernel_size}")
    n = coords.shape[0]
    offsets = kernel_offsets(kernel_size).tolist()
    num_offsets = len(offsets)
    centre = num_offsets // 2
    empty = coords.new_empty(0)
    if n == 0:
        return KernelMap(empty, empty, (0,) * num_offsets, 0, 0, identity_offset=centre)
    _check_stride_multiples(coords, stride)

    radius = kernel_size // 2
    packer = _KeyPacker(*_coord_bounds(coords, radius * stride))
    keys = packer.keys(coords)
    sorted_keys, order = torch.sort(keys)
    if bool((sorted_keys[1:] == sorted_keys[:-1]).any()):
        raise ValueError("duplicate coordinates in a sparse tensor")

    # With key-sorted input (e.g. coordinates made by downsampling), neighbour rows increase with
    # output rows, so mirrored pairs come out already sorted and need no argsort.
    presorted = bool((keys[1:] > keys[:-1]).all())

    in_parts: list[Tensor | None] = [None] * num_offsets
    out_parts: list[Tensor | None] = [None] * num_offsets
    # Offsets k and K-1-k are negatives of each other: if coords[i] = coords[o] + d then
    # coords[o] = coords[i] - d. So only the first half is searched and mirrored.
    for k in range(centre):
        query = keys + packer.delta([d * stride for d in offsets[k]])
        pos = torch.searchsorted(sorted_keys, query).clamp_(max=n - 1)
        found = sorted_keys[pos] == query
        out_rows = found.nonzero().squeeze(1)  # ascending: already sorted by output row
        in_rows = order[pos[out_rows]]
        in_parts[k], out_parts[k] = in_rows, out_rows
        if presorted:
            in_parts[num_offsets - 1 - k], out_parts[num_offsets - 1 - k] = out_rows, in_rows
        else:
            mirror = torch.argsort(in_rows)  # sort the mirrored pairs by their output row
            in_parts[num_offsets - 1 - k] = out_rows[mirror]
            out_parts[num_offsets - 1 - k] = in_rows[mirror]
    in_parts[centre] = out_parts[centre] = empty
    counts = tuple(p.shape[0] for p in in_parts)  # type: ignore[union-attr]
    return KernelMap(
        in_idx=torch.cat(in_parts),  # type: ignore[arg-type]
        out_idx=torch.cat(out_parts),  # type: ignore[arg-type]
        counts=counts,
        n_in=n,
        n_out=n,
        identity_offset=centre,
    )


def build_downsample_map(coords: Tensor, stride: int) -> tuple[Tensor, KernelMap]:
    """Kernel map of the 2^3, stride-2 convolution from a stride-s tensor to stride 2s.

    coords: (N, 4) int64, unique, multiples of s. Returns ``(parent_coords, kmap)``:
    parent_coords (M, 4) are the parents that have children, ``floor(c / 2s) * 2s`` (batch kept),
    sorted by packed key; every input row i has exactly one pair, to its parent, at offset
    ``k = dx * 4 + dy * 2 + dz`` with ``(dx, dy, dz) = (c / s) mod 2``.
    """
    n = coords.shape[0]
    empty = coords.new_empty(0)
    if n == 0:
        return coords.new_empty(0, 4), KernelMap(empty, empty, (0,) * 8, 0, 0)
    _check_stride_multiples(coords, stride)
    step = 2 * stride
    parents = coords.clone()
    parents[:, 1:] = torch.div(coords[:, 1:], step, rounding_mode="floor") * step
    bits = torch.remainder(torch.div(coords[:, 1:], stride, rounding_mode="floor"), 2)
    offset_index = bits[:, 0] * 4 + bits[:, 1] * 2 + bits[:, 2]

    packer = _KeyPacker(*_coord_bounds(parents, 0))
    parent_keys, parent_of = torch.unique(packer.keys(parents), sorted=True, return_inverse=True)
    n_out = parent_keys.shape[0]
    # One representative child per parent gives the parent's coordinates without unpacking keys.
    first_child = torch.full((n_out,), n, dtype=torch.int64, device=coords.device)
    first_child.scatter_reduce_(0, parent_of, torch.arange(n, device=coords.device), reduce="amin")
    parent_coords = parents[first_child]

    # Group pairs by offset, then by output row: one sort on a combined key.
    # Two children with the same parent and offset are the same voxel, so a repeated group key
    # is exactly a duplicate coordinate.
    sorted_group_key, order = torch.sort(offset_index * n_out + parent_of)
    if bool((sorted_group_key[1:] == sorted_group_key[:-1]).any()):
        raise ValueError("duplicate coordinates in a sparse tensor")
    counts = tuple(torch.bincount(offset_index, minlength=8).tolist())
    kmap = KernelMap(in_idx=order, out_idx=parent_of[order], counts=counts, n_in=n, n_out=n_out)
    return parent_coords, kmap
