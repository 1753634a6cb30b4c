"""Feature pyramid on top of a 2D trunk: three maps at 1/16, 1/8 and 1/4 of the image.

The head follows the official `MnasMulti` (NeuralRecon's FPN): every block is BN -> ReLU -> conv
without bias, the top trunk map is the pyramid's working width, and each finer level adds a 1x1
lateral projection of the trunk map to the 2x bilinear upsampling of the level above. Subclasses
provide the trunk (`extract`) and the input normalisation; the head is shared, so any trunk with
outputs at strides 4/8/16 plugs in.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def bn_relu_conv(in_channels: int, out_channels: int, kernel_size: int) -> nn.Sequential:
    """Pre-activation conv block; indices 0 (BN) and 2 (conv) are the official key names."""
    conv = nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False)
    nn.init.kaiming_normal_(conv.weight)
    return nn.Sequential(nn.BatchNorm2d(in_channels), nn.ReLU(inplace=True), conv)


class FeaturePyramid(nn.Module):
    """Base class: trunk (subclass) + pyramid head (here).

    Subclasses set `trunk_channels` = channels of the trunk maps at strides (4, 8, 16), build their
    trunk modules, call `_build_head`, and implement `extract` and `normalize`.
    """

    # RGB mean / std in 0-255 units, set by subclasses.
    pixel_mean: tuple[float, float, float]
    pixel_std: tuple[float, float, float]

    def _build_head(self, trunk_channels: tuple[int, int, int], out_channels: tuple[int, int, int]) -> None:
        """trunk_channels: (c4, c8, c16); out_channels: (coarse, medium, fine) = (1/16, 1/8, 1/4)."""
        c4, c8, c16 = trunk_channels
        width = c16  # the top map is used as-is, so the lateral maps are projected to its width
        self.out_channels = tuple(out_channels)
        self.inner1 = bn_relu_conv(c8, width, 1)
        self.inner2 = bn_relu_conv(c4, width, 1)
        self.out1 = bn_relu_conv(width, out_channels[0], 1)
        self.out2 = bn_relu_conv(width, out_channels[1], 3)
        self.out3 = bn_relu_conv(width, out_channels[2], 3)

    def extract(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Normalised images (N, 3, H, W) -> trunk maps at strides 4, 8, 16."""
        raise NotImplementedError

    def trunk_modules(self) -> list[nn.Module]:
        """The pretrained trunk (what the authors freeze in training phase 1)."""
        raise NotImplementedError

    def normalize(self, images: torch.Tensor) -> torch.Tensor:
        """RGB 0-255 (N, 3, H, W) -> the trunk's expected input distribution."""
        mean = images.new_tensor(self.pixel_mean).view(1, 3, 1, 1)
        std = images.new_tensor(self.pixel_std).view(1, 3, 1, 1)
        return (images - mean) / std

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        """RGB 0-255 (N, 3, H, W) -> [coarse (N, C0, H/16, W/16), medium (N, C1, H/8, W/8), fine (N, C2, H/4, W/4)]."""
        f4, f8, f16 = self.extract(self.normalize(images))
        top = f16
        coarse = self.out1(top)
        top = _upsample_to(top, f8) + self.inner1(f8)
        medium = self.out2(top)
        top = _upsample_to(top, f4) + self.inner2(f4)
        fine = self.out3(top)
        return [coarse, medium, fine]

    def freeze_trunk(self, frozen: bool = True) -> None:
        """Freeze the trunk as the authors' phase 1 does (Lightning `freeze(train_bn=False)`).

        Trunk parameters stop receiving gradients and trunk BatchNorms stop tracking statistics:
        in train mode they normalise with batch statistics, in eval mode with the stored ImageNet
        statistics. `frozen=False` undoes both.
        """
        for module in self.trunk_modules():
            for p in module.parameters():
                p.requires_grad_(not frozen)
            for m in module.modules():
                if isinstance(m, nn.modules.batchnorm._BatchNorm):
                    m.track_running_stats = not frozen


def _upsample_to(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    # 2x bilinear (align_corners=False) as the official FPN; sizing by the target also covers
    # image sizes that are not multiples of 16, where 2x would be off by one.
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)
