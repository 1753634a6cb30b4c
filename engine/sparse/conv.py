"""Sparse 3D convolution in pure PyTorch (gather -> matmul -> scatter), torchsparse v1.4 layout.

``out[p] = sum_k in[p + off_k * s] @ W[k]`` with ``W`` of shape (K, Cin, Cout), s the input stride.
Four kinds, chosen by (kernel_size, stride, transposed) exactly as torchsparse does:

- kernel_size 1, stride 1: pointwise, ``feats @ W`` with W (Cin, Cout); same coordinates.
- odd kernel_size, stride 1: submanifold, outputs at the input coordinates.
- kernel_size 2, stride 2: downsampling, outputs only at parents that have children
  (``floor(c / 2s) * 2s``), output stride 2s.
- kernel_size 2, stride 2, transposed: upsampling back onto the cached stride-s/2 coordinate set,
  reusing that downsample's map with inputs and outputs swapped:
  ``fine[p] = coarse[parent(p)] @ W[k((p / s_fine) mod 2)]``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .kernel_map import KernelMap, build_downsample_map, build_submanifold_map
from .tensor import SparseVoxels


class _SparseConvFunction(torch.autograd.Function):
    """Features-only sparse convolution over a kernel map.

    A custom Function rather than plain autograd ops so that the gathered (P_k, Cin) input rows are
    not kept for backward: they are re-gathered offset by offset there, which bounds the extra memory
    of a layer to one offset's rows instead of all P pairs (about 10x the layer input).
    Per-offset intermediates live in workspaces sized for the largest offset and reused with
    ``out=``: fresh multi-megabyte CPU allocations per offset cost page faults (measured ~15 %).
    """

    @staticmethod
    def forward(ctx, feats: Tensor, kernel: Tensor, kmap: KernelMap) -> Tensor:  # type: ignore[override]
        out = feats.new_zeros(kmap.n_out, kernel.shape[2])
        gathered = _Workspace(feats, feats.shape[1], kmap.max_pairs)
        products = _Workspace(feats, kernel.shape[2], kmap.max_pairs)
        for k in range(kmap.num_offsets):
            if k == kmap.identity_offset:
                out.addmm_(feats, kernel[k])
                continue
            in_rows, out_rows = kmap.pairs(k)
            n = in_rows.numel()
            if n == 0:
                continue
            rows = torch.index_select(feats, 0, in_rows, out=gathered.take(n))
            out.index_add_(0, out_rows, torch.mm(rows, kernel[k], out=products.take(n)))
        ctx.save_for_backward(feats, kernel)
        ctx.kmap = kmap
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor | None, Tensor | None, None]:  # type: ignore[override]
        feats, kernel = ctx.saved_tensors
        kmap: KernelMap = ctx.kmap
        need_feats, need_kernel = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        grad_out = grad_out.contiguous()
        grad_feats = torch.zeros_like(feats) if need_feats else None
        grad_kernel = torch.zeros_like(kernel) if need_kernel else None
        grad_rows_ws = _Workspace(grad_out, grad_out.shape[1], kmap.max_pairs)
        feat_rows_ws = _Workspace(feats, feats.shape[1], kmap.max_pairs)  # gathered inputs, then reused for products
        for k in range(kmap.num_offsets):
            if k == kmap.identity_offset:
                if grad_kernel is not None:
                    torch.mm(feats.t(), grad_out, out=grad_kernel[k])
                if grad_feats is not None:
                    grad_feats.addmm_(grad_out, kernel[k].t())
                continue
            in_rows, out_rows = kmap.pairs(k)
            n = in_rows.numel()
            if n == 0:
                continue
            grad_rows = torch.index_select(grad_out, 0, out_rows, out=grad_rows_ws.take(n))
            if grad_kernel is not None:
                rows = torch.index_select(feats, 0, in_rows, out=feat_rows_ws.take(n))
                torch.mm(rows.t(), grad_rows, out=grad_kernel[k])
            if grad_feats is not None:
                products = torch.mm(grad_rows, kernel[k].t(), out=feat_rows_ws.take(n))
                grad_feats.index_add_(0, in_rows, products)
        return grad_feats, grad_kernel, None


class _Workspace:
    """A (rows, channels) buffer allocated on first use; ``take(n)`` is a contiguous (n, channels) view."""

    def __init__(self, like: Tensor, channels: int, rows: int) -> None:
        self._like = like
        self._shape = (rows, channels)
        self._buffer: Tensor | None = None

    def take(self, n: int) -> Tensor:
        if self._buffer is None:
            self._buffer = self._like.new_empty(self._shape)
        return self._buffer[:n]


def sparse_conv_features(feats: Tensor, kernel: Tensor, kmap: KernelMap) -> Tensor:
    """(N_in, Cin) features, (K, Cin, Cout) kernel, map -> (N_out, Cout) features.

    Under ``torch.autocast`` the inputs are cast to the autocast dtype once and the loop runs with
    autocast off, so the scatter target and the products always share one dtype.
    """
    if kernel.dim() != 3 or kernel.shape[0] != kmap.num_offsets or kernel.shape[1] != feats.shape[1]:
        raise ValueError(
            f"kernel {tuple(kernel.shape)} does not fit {kmap.num_offsets} offsets and {feats.shape[1]} input channels"
        )
    if feats.shape[0] != kmap.n_in:
        raise ValueError(f"kernel map expects {kmap.n_in} input rows, got {feats.shape[0]}")
    device_type = feats.device.type
    if torch.is_autocast_enabled(device_type):
        dtype = torch.get_autocast_dtype(device_type)
    else:
        dtype = torch.promote_types(feats.dtype, kernel.dtype)
    feats, kernel = feats.to(dtype), kernel.to(dtype)
    with torch.autocast(device_type, enabled=False):
        return _SparseConvFunction.apply(feats.contiguous(), kernel.contiguous(), kmap)


# --- kernel maps from the shared cache -------------------------------------------------------------


def submanifold_map(x: SparseVoxels, kernel_size: int) -> KernelMap:
    key = ("submanifold", x.stride, kernel_size)
    kmap = x.cache.kernel_maps.get(key)
    if kmap is None:
        kmap = build_submanifold_map(x.coords, x.stride, kernel_size)
        x.cache.kernel_maps[key] = kmap
    return kmap


def downsample_map(x: SparseVoxels) -> tuple[Tensor, KernelMap]:
    """(coords at stride 2s, map from x's rows to them); both cached on x's cache."""
    key = ("downsample", x.stride, 2)
    kmap = x.cache.kernel_maps.get(key)
    coarse = x.cache.coords.get(2 * x.stride)
    if kmap is None:
        if coarse is not None:
            # The parents' row order is defined by the map build; coordinates registered by hand
            # at that stride cannot be matched to it.
            raise ValueError(
                f"stride-{2 * x.stride} coordinates are already in this cache but were not made by "
                "downsampling; build the coarse tensor with a strided convolution instead"
            )
        coarse, kmap = build_downsample_map(x.coords, x.stride)
        x.cache.coords[2 * x.stride] = coarse
        x.cache.kernel_maps[key] = kmap
    return coarse, kmap


def upsample_map(x: SparseVoxels) -> tuple[Tensor, KernelMap]:
    """(coords at stride s/2, map from x's rows to them): the transposed downsample map."""
    if x.stride % 2 != 0:
        raise ValueError(f"cannot upsample a stride-{x.stride} tensor by 2")
    fine_stride = x.stride // 2
    down = x.cache.kernel_maps.get(("downsample", fine_stride, 2))
    fine = x.cache.coords.get(fine_stride)
    if down is None or fine is None:
        raise ValueError(
            f"transposed convolution needs the stride-{fine_stride} coordinates this tensor was "
            "downsampled from; they are not in its cache (was it built from a strided convolution?)"
        )
    if down.n_out != x.num_voxels:
        raise ValueError("tensor does not have the coordinate set produced by the cached downsampling")
    key = ("upsample", x.stride, 2)
    kmap = x.cache.kernel_maps.get(key)
    if kmap is None:
        kmap = down.transposed()
        x.cache.kernel_maps[key] = kmap
    return fine, kmap


# --- functional API --------------------------------------------------------------------------------


def conv3d(x: SparseVoxels, kernel: Tensor, kernel_size: int, stride: int = 1, transposed: bool = False) -> SparseVoxels:
    """Sparse convolution of x (N, Cin) with a torchsparse-layout kernel.

    kernel: (Cin, Cout) when kernel_size == 1, else (kernel_size**3, Cin, Cout).
    Returns a tensor on the same cache; stride s, 2s (downsampling) or s/2 (transposed).
    """
    if kernel_size == 1 and stride == 1:
        if kernel.dim() != 2:
            raise ValueError(f"a 1x1x1 kernel is (Cin, Cout), got {tuple(kernel.shape)}")
        # Plain matmul: autocast applies as for any linear layer.
        return x.replace_feats(x.feats.matmul(kernel))
    if stride == 1 and not transposed:
        kmap = submanifold_map(x, kernel_size)
        return x.replace_feats(sparse_conv_features(x.feats, kernel, kmap))
    if kernel_size == 2 and stride == 2:
        if transposed:
            coords, kmap = upsample_map(x)
            new_stride = x.stride // 2
        else:
            coords, kmap = downsample_map(x)
            new_stride = x.stride * 2
        return SparseVoxels(coords, sparse_conv_features(x.feats, kernel, kmap), new_stride, x.cache)
    raise ValueError(
        f"unsupported sparse convolution: kernel_size={kernel_size}, stride={stride}, transposed={transposed} "
        "(supported: odd kernel with stride 1, and kernel 2 with stride 2, optionally transposed)"
    )


# --- module ----------------------------------------------------------------------------------------


class SparseConv3d(nn.Module):
    """torchsparse v1.4 ``spnn.Conv3d`` without bias: parameter ``kernel`` (K, Cin, Cout) or (Cin, Cout).

    Initialisation is torchsparse's: uniform in ``[-1/sqrt(fan), 1/sqrt(fan)]`` with
    ``fan = K * Cin`` (``K * Cout`` for a transposed conv).
    """

    def __init__(
        self, in_channels: int, out_channels: int, kernel_size: int = 3, stride: int = 1, transposed: bool = False
    ) -> None:
        super().__init__()
        supported = (stride == 1 and not transposed and kernel_size % 2 == 1) or (kernel_size == 2 and stride == 2)
        if not supported:
            raise ValueError(
                f"unsupported sparse convolution: kernel_size={kernel_size}, stride={stride}, transposed={transposed}"
            )
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.kernel_size = kernel_size
        self.stride = stride
        self.transposed = transposed
        volume = kernel_size**3
        shape = (in_channels, out_channels) if volume == 1 else (volume, in_channels, out_channels)
        self.kernel = nn.Parameter(torch.empty(shape))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        fan = (self.out_channels if self.transposed else self.in_channels) * self.kernel_size**3
        bound = 1.0 / math.sqrt(fan)
        nn.init.uniform_(self.kernel, -bound, bound)

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        return conv3d(x, self.kernel, self.kernel_size, self.stride, self.transposed)

    def extra_repr(self) -> str:
        s = f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, stride={self.stride}"
        return s + (", transposed=True" if self.transposed else "")
