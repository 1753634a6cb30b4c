"""MnasNet-1.0 trunk (the official VoRTX 2D backbone) + the shared pyramid head.

Reproduces torchvision's `mnasnet1_0().layers[0..10]` module by module, so the state-dict keys are
the official checkpoint's `cnn2d.conv0.* / conv1.* / conv2.*` exactly:
  conv0 = layers[0..8]: stem conv s2, depthwise conv, 1x1 conv, then a stride-2 stack -> 24 ch, 1/4
  conv1 = layers[9]:    stack k5 s2 x3 expansion 3 -> 40 ch, 1/8
  conv2 = layers[10]:   stack k5 s2 x3 expansion 6 -> 80 ch, 1/16
No ImageNet MnasNet weights exist offline; this trunk is random unless an official checkpoint is loaded.
"""

from __future__ import annotations

import torch
from torch import nn

from .fpn import FeaturePyramid

# torchvision's MnasNet uses the TensorFlow momentum 0.9997, i.e. PyTorch momentum 0.0003.
BN_MOMENTUM = 1.0 - 0.9997


class InvertedResidual(nn.Module):
    """1x1 expand -> kxk depthwise (stride) -> 1x1 project, residual when the shape is kept."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, stride: int, expansion: int) -> None:
        super().__init__()
        mid = in_ch * expansion
        self.apply_residual = in_ch == out_ch and stride == 1
        self.layers = nn.Sequential(
            nn.Conv2d(in_ch, mid, 1, bias=False),
            nn.BatchNorm2d(mid, momentum=BN_MOMENTUM),
            nn.ReLU(inplace=True),
            nn.Conv2d(mid, mid, kernel_size, stride=stride, padding=kernel_size // 2, groups=mid, bias=False),
            nn.BatchNorm2d(mid, momentum=BN_MOMENTUM),
            nn.ReLU(inplace=True),
            nn.Conv2d(mid, out_ch, 1, bias=False),
            nn.BatchNorm2d(out_ch, momentum=BN_MOMENTUM),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.layers(x)
        return y + x if self.apply_residual else y


def inverted_residual_stack(
    in_ch: int, out_ch: int, kernel_size: int, stride: int, expansion: int, repeats: int
) -> nn.Sequential:
    """`repeats` blocks; only the first changes width and stride."""
    blocks = [InvertedResidual(in_ch, out_ch, kernel_size, stride, expansion)]
    blocks += [InvertedResidual(out_ch, out_ch, kernel_size, 1, expansion) for _ in range(repeats - 1)]
    return nn.Sequential(*blocks)


def _mnasnet_stem() -> nn.Sequential:
    """torchvision `layers[0..8]` (1/4 resolution, 24 channels)."""
    return nn.Sequential(
        nn.Conv2d(3, 32, 3, stride=2, padding=1, bias=False),
        nn.BatchNorm2d(32, momentum=BN_MOMENTUM),
        nn.ReLU(inplace=True),
        nn.Conv2d(32, 32, 3, padding=1, groups=32, bias=False),
        nn.BatchNorm2d(32, momentum=BN_MOMENTUM),
        nn.ReLU(inplace=True),
        nn.Conv2d(32, 16, 1, bias=False),
        nn.BatchNorm2d(16, momentum=BN_MOMENTUM),
        inverted_residual_stack(16, 24, 3, 2, 3, 3),
    )


def _init_trunk(module: nn.Module) -> None:
    # torchvision's MnasNet initialisation, so a from-scratch trunk trains like the reference.
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)


class MnasNetPyramid(FeaturePyramid):
    """MnasNet-1.0 trunk to 1/16 + pyramid head. Input RGB 0-255; normalised with the authors' constants."""

    pixel_mean = (127.71, 114.66, 99.32)
    pixel_std = (75.31, 73.53, 71.66)
    trunk_channels = (24, 40, 80)

    def __init__(self, out_channels: tuple[int, int, int]) -> None:
        super().__init__()
        self.conv0 = _mnasnet_stem()
        self.conv1 = inverted_residual_stack(24, 40, 5, 2, 3, 3)
        self.conv2 = inverted_residual_stack(40, 80, 5, 2, 6, 3)
        for trunk in self.trunk_modules():
            _init_trunk(trunk)
        self._build_head(self.trunk_channels, out_channels)

    def trunk_modules(self) -> list[nn.Module]:
        return [self.conv0, self.conv1, self.conv2]

    def extract(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        f4 = self.conv0(x)
        f8 = self.conv1(f4)
        f16 = self.conv2(f8)
        return f4, f8, f16
