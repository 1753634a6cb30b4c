"""`VortxConfig`: every hyper-parameter that changes the network's shape or behaviour.

The config is saved next to the weights (JSON), so a weights file always rebuilds the exact network
that produced it. Runtime knobs that do not change results (chunk sizes, device) are not here.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any, Optional

from ..stereo.fused_tsdf import CLASSICAL_TRUNCATION_VOXELS

# Level 0 is the coarsest. The names are the official checkpoint's ModuleDict keys.
LEVEL_NAMES: tuple[str, str, str] = ("coarse", "medium", "fine")
# Each level's voxel size is the fine voxel size times this factor (16 / 8 / 4 cm by default).
LEVEL_SCALES: tuple[int, int, int] = (4, 2, 1)
# Image downsampling of the 2D feature map used at each level (1/16, 1/8, 1/4 of the image).
LEVEL_IMAGE_STRIDES: tuple[int, int, int] = (16, 8, 4)

BACKBONES = ("mnasnet", "efficientnet_lite0")
FUSIONS = ("transformer", "average")
# Which statistics the 3D CNN's BatchNorms use at inference (see VortxConfig).
SPARSE_NORM_STATISTICS = ("running", "scene")


@dataclass(frozen=True)
class StereoEvidenceConfig:
    """Plane-sweep stereo depth as input (engine/model/stereo_evidence.py).

    truncation_voxels: truncation of the per-view signed distance and of the coarse and medium levels'
                       fused TSDF, in voxels of each level (default: the classical stereo method's band,
                       CLASSICAL_TRUNCATION_VOXELS = 4; FineRecon and the ground truth use 3). The fine
                       level always starts from the classical method's own fused TSDF.
    view_tokens:       join [signed distance, confidence, valid] with the appearance features in the
                       view transformer's tokens.
    Always on with evidence: the fused TSDF as an input channel of every level's 3D CNN, and every
    level's head a residual on it (zero-initialised last layer: untrained = classical fusion).
    """

    truncation_voxels: float = CLASSICAL_TRUNCATION_VOXELS
    view_tokens: bool = True

    def __post_init__(self) -> None:
        if self.truncation_voxels <= 0:
            raise ValueError(f"stereo_evidence.truncation_voxels must be positive, got {self.truncation_voxels}")


@dataclass(frozen=True)
class VortxConfig:
    """Network shape and behaviour.

    backbone:           "efficientnet_lite0" (ImageNet weights ship offline; our default) or
                        "mnasnet" (MnasNet-1.0, the official model's trunk).
    feature_channels:   2D feature channels per level (coarse, medium, fine); official (80, 40, 24).
    unet_base_widths:   SparseUNet base width per level; the UNet outputs 3x this. Official (32, 16, 8).
    voxel_size:         fine voxel edge in metres; medium and coarse are 2x and 4x.
    fusion:             "transformer" (VoRTX) or "average" (ablation: masked mean of back-projected
                        features, no transformer and no projective occupancy).
    attn_layers, attn_heads: transformer depth and heads (official 2, 2).
    use_proj_occ:       pooling over views. True: softmax over projective-occupancy logits with a
                        null view (fine-tuning and inference). False: masked mean (training phase 1).
                        Ignored when fusion == "average".
    voxel_dropout:      in training, keep at most `max_train_voxels` random voxels per sample after
                        upsampling (medium, fine), as the authors do to bound memory.
    image_long_side:    long side in pixels of the photos the network was trained on; reconstruction
                        resizes photos to it unless told otherwise (official: 640 x 480).
    sparse_norm_statistics: what the 3D CNN's BatchNorms normalise with at inference. "running":
                        the averages accumulated in training (official). "scene": the statistics of
                        the scene's own active voxels at that level, as training normalises with the
                        batch's; for weights whose running averages, gathered on small training crops,
                        do not describe whole scenes (MODEL.md measures it).
    stereo_evidence:    None (appearance only: the official checkpoint, the v1/v2 weights) or a
                        StereoEvidenceConfig: the network also takes plane-sweep stereo depth maps.
    """

    backbone: str = "efficientnet_lite0"
    feature_channels: tuple[int, int, int] = (80, 40, 24)
    unet_base_widths: tuple[int, int, int] = (32, 16, 8)
    voxel_size: float = 0.04
    fusion: str = "transformer"
    attn_layers: int = 2
    attn_heads: int = 2
    use_proj_occ: bool = True
    voxel_dropout: bool = True
    max_train_voxels: tuple[int, int] = (2**14, 2**16)
    image_long_side: int = 640
    sparse_norm_statistics: str = "running"
    stereo_evidence: Optional[StereoEvidenceConfig] = None

    def __post_init__(self) -> None:
        if isinstance(self.stereo_evidence, dict):  # from JSON
            known = {f.name for f in dataclasses.fields(StereoEvidenceConfig)}
            unknown = sorted(set(self.stereo_evidence) - known)
            if unknown:
                raise ValueError(f"unknown stereo_evidence fields: {unknown}")
            object.__setattr__(self, "stereo_evidence", StereoEvidenceConfig(**self.stereo_evidence))
        # Lists arrive from JSON; store tuples so the config stays hashable and comparable.
        for name in ("feature_channels", "unet_base_widths", "max_train_voxels"):
            object.__setattr__(self, name, tuple(int(v) for v in getattr(self, name)))
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.fusion not in FUSIONS:
            raise ValueError(f"fusion must be one of {FUSIONS}, got {self.fusion!r}")
        if len(self.feature_channels) != 3 or len(self.unet_base_widths) != 3:
            raise ValueError("feature_channels and unet_base_widths need one value per level (3)")
        if len(self.max_train_voxels) != 2:
            raise ValueError("max_train_voxels needs two values (medium, fine)")
        if self.fusion == "transformer":
            for c in self.feature_channels:
                if c % self.attn_heads:
                    raise ValueError(f"feature channels {c} not divisible by attn_heads {self.attn_heads}")
        if self.sparse_norm_statistics not in SPARSE_NORM_STATISTICS:
            raise ValueError(f"sparse_norm_statistics must be one of {SPARSE_NORM_STATISTICS}, got {self.sparse_norm_statistics!r}")
        if self.voxel_size <= 0:
            raise ValueError("voxel_size must be positive")
        if self.stereo_evidence is not None and self.fusion != "transformer":
            raise ValueError("stereo_evidence needs fusion='transformer' (its view tokens join the transformer's)")

    @classmethod
    def official(cls) -> "VortxConfig":
        """The configuration of the authors' released checkpoint (MnasNet, full widths, proj-occ pooling)."""
        return cls(backbone="mnasnet", use_proj_occ=True)

    def level_voxel_size(self, level: int) -> float:
        """Voxel edge in metres at `level` (0 = coarse)."""
        return self.voxel_size * LEVEL_SCALES[level]

    def unet_in_channels(self, level: int) -> int:
        """Input channels of the level's 3D CNN: [upsampled features | fused 2D features | upsampled logit]
        plus, with stereo evidence, [fused stereo TSDF]."""
        evidence = 1 if self.stereo_evidence is not None else 0  # the fused stereo TSDF
        if level == 0:
            return self.feature_channels[0] + evidence
        return 3 * self.unet_base_widths[level - 1] + self.feature_channels[level] + 1 + evidence

    def unet_out_channels(self, level: int) -> int:
        return 3 * self.unet_base_widths[level]

    def to_dict(self) -> dict[str, Any]:
        return {f.name: _jsonable(getattr(self, f.name)) for f in dataclasses.fields(self)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "VortxConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown VortxConfig fields: {unknown}")
        return cls(**data)

    @classmethod
    def from_json(cls, text: str) -> "VortxConfig":
        return cls.from_dict(json.loads(text))


def _jsonable(value: Any) -> Any:
    if isinstance(value, StereoEvidenceConfig):
        return dataclasses.asdict(value)
    return list(value) if isinstance(value, tuple) else value
