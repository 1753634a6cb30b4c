"""`VortxNet`: the VoRTX network as composable steps.

Per level l (0 = coarse 16 cm, 1 = medium 8 cm, 2 = fine 4 cm):
  2D pyramid features (view-direction encoded)  --encode_views-->  (V, C_l, H/s, W/s)
  back-project at the voxels + fuse over views  --fuse-->          (N, C_l), LayerNorm'd
  [up-features | fused | up-logit] -> SparseUNet -> 1x1 head      --level_step-->  features, logits
  keep logit > 0, copy to the 8 children        --prune_and_upsample-->  next level's input
The fine logits are TSDF logits (TSDF = 1.05 tanh). With stereo evidence (`config.stereo_evidence`,
engine/model/stereo_evidence.py) `fuse` also takes the views' stereo depth maps (token evidence) and
`level_step` the voxels' `LevelEvidence`: the fused stereo TSDF as an extra 3D CNN input channel, and
the logits of classical fusion (`FineFusion`) that the head's output is added to (last layer zero at
init: untrained = the classical stereo method's surface).
The inference driver (`engine.recon`) calls the
steps itself so it can fuse per tile and run each level's 3D CNN over the whole scene; `forward`
composes the same steps for a training batch of crops.

Submodule names are the official checkpoint's (without its `vortx.` prefix): `cnn2d`, `upsampler`,
`view_embedders.<level>`, `layer_norms.<level>`, `mv_fusion.<level>`, `cnns3d.<level>`,
`output_layers.<level>`, with level names coarse / medium / fine.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn

from ..sparse import SparseBatchNorm, SparseConv3d, SparseVoxels
from .backbone_efficientnet import EfficientNetLite0Pyramid
from .backbone_mnasnet import MnasNetPyramid
from .backprojection import Projection, project_to_feature_maps, sample_features
from .coarse_to_fine import Upsampler, subsample_per_sample
from .config import LEVEL_IMAGE_STRIDES, LEVEL_NAMES, LEVEL_SCALES, VortxConfig
from .fpn import FeaturePyramid
from .view_fusion import AverageFusion, TransformerFusion
from .outputs import FusionOutput, LevelOutput, LevelPrediction, StereoEvidence, VortxBatch
from .stereo_evidence import (EVIDENCE_CHANNELS, FineFusion, LevelEvidence, cap_added_blocks, fused_tsdf, prior_logits,
                              view_evidence)
from ..stereo.fused_tsdf import CLASSICAL_TRUNCATION_VOXELS
from .unet3d import SparseUNet
from .view_encoding import ViewDirectionEncoder

# Voxels per fusion chunk: bounds the (chunk, V, C) attention activations; ~2k-16k sequences is
# the fast range for the transformer on CPU (platform notes section 4).
DEFAULT_FUSION_CHUNK = 8192
# Images per backbone call at inference; small chunks avoid the allocation cost of big batches on CPU.
DEFAULT_IMAGE_CHUNK = 4


def build_pyramid(config: VortxConfig, pretrained: bool) -> FeaturePyramid:
    if config.backbone == "mnasnet":
        # No MnasNet ImageNet weights exist offline; `pretrained` has nothing to load here.
        return MnasNetPyramid(config.feature_channels)
    return EfficientNetLite0Pyramid(config.feature_channels, pretrained=pretrained)


class VortxNet(nn.Module):
    """The VoRTX network. `pretrained_backbone` loads ImageNet weights (EfficientNet-Lite0 only)."""

    def __init__(self, config: VortxConfig | None = None, pretrained_backbone: bool = False) -> None:
        super().__init__()
        config = config or VortxConfig()
        self.config = config
        self.use_proj_occ = config.use_proj_occ
        self.fusion_chunk = DEFAULT_FUSION_CHUNK
        self.image_chunk = DEFAULT_IMAGE_CHUNK

        self.cnn2d = build_pyramid(config, pretrained_backbone)
        self.upsampler = Upsampler()
        self.view_embedders = nn.ModuleDict()
        self.layer_norms = nn.ModuleDict()
        self.mv_fusion = nn.ModuleDict()
        self.cnns3d = nn.ModuleDict()
        self.output_layers = nn.ModuleDict()
        for level, name in enumerate(LEVEL_NAMES):
            channels = config.feature_channels[level]
            self.view_embedders[name] = ViewDirectionEncoder(channels)
            self.layer_norms[name] = nn.LayerNorm(channels)
            if config.fusion == "transformer":
                tokens = config.stereo_evidence is not None and config.stereo_evidence.view_tokens
                self.mv_fusion[name] = TransformerFusion(channels, config.attn_layers, config.attn_heads,
                                                         EVIDENCE_CHANNELS if tokens else 0)
            else:
                self.mv_fusion[name] = AverageFusion()
            self.cnns3d[name] = SparseUNet(config.unet_in_channels(level), config.unet_base_widths[level])
            self.output_layers[name] = SparseConv3d(config.unet_out_channels(level), 1, kernel_size=1)
            if config.stereo_evidence is not None:
                nn.init.zeros_(self.output_layers[name].kernel)  # residual on the stereo prior
        for module in self.cnns3d.modules():
            if isinstance(module, SparseBatchNorm):
                module.scene_statistics = config.sparse_norm_statistics == "scene"

    # --- configuration ------------------------------------------------------------------------

    @property
    def backbone(self) -> FeaturePyramid:
        """The 2D feature pyramid (`trunk_modules()`, `freeze_trunk()`); stored as `cnn2d`."""
        return self.cnn2d

    @property
    def uses_stereo(self) -> bool:
        """True when the network takes stereo evidence (fuse's `evidence`, level_step's `evidence`)."""
        return self.config.stereo_evidence is not None

    def evidence_truncation(self, level: int) -> float:
        """Truncation in metres of the level's stereo evidence (its voxels times truncation_voxels)."""
        if self.config.stereo_evidence is None:
            raise ValueError("this network takes no stereo evidence")
        return self.config.stereo_evidence.truncation_voxels * self.config.level_voxel_size(level)

    def crop_fine_fusion(self, origin: torch.Tensor, shape: tuple[int, int, int], evidence: StereoEvidence) -> FineFusion:
        """The classical fused TSDF of a crop's fine voxels (X, Y, Z) = `shape` at origin (3,) + index *
        voxel_size, from all of its stereo maps (inference fuses the whole scene's grid the same way)."""
        index = dense_grid_coords(1, list(shape), origin.device)[:, 1:]
        points = origin.to(torch.float64) + index.to(torch.float64) * self.config.voxel_size
        tsdf = fused_tsdf(points, evidence, CLASSICAL_TRUNCATION_VOXELS * self.config.voxel_size)
        return FineFusion(tsdf.reshape(*shape), (0, 0, 0))

    def level_evidence(self, level: int, coords: torch.Tensor, points: torch.Tensor, evidence: StereoEvidence,
                       fine: FineFusion) -> LevelEvidence:
        """Stereo evidence of a level's voxels: coords (N, 3) in level units (the frame of `fine`), points
        (N, 3) their world positions, `evidence` the scene's (or crop's) maps."""
        if level == len(LEVEL_NAMES) - 1:
            tsdf = fine.tsdf_at(coords)
            return LevelEvidence(tsdf, prior_logits(True, tsdf))
        tsdf = fused_tsdf(points, evidence, self.evidence_truncation(level)).to(fine.tsdf.device)
        return LevelEvidence(tsdf, prior_logits(False, fine.block_surface(LEVEL_SCALES[level], coords)))

    def set_use_proj_occ(self, use_proj_occ: bool) -> None:
        """Switch view pooling: softmax-with-null over projective occupancy (True) or masked mean."""
        self.use_proj_occ = bool(use_proj_occ)
        self.config = dataclasses.replace(self.config, use_proj_occ=self.use_proj_occ)

    # --- steps --------------------------------------------------------------------------------

    def encode_views(self, images: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor) -> list[torch.Tensor]:
        """images (V, 3, H, W) RGB 0-255; K (V, 3, 3) pixels; cam_to_world (V, 4, 4)
        -> per level (V, C_l, H/s_l, W/s_l), s = 16, 8, 4, view-direction encoding applied.

        In eval mode the images go through the backbone in chunks (same result, less memory); in
        train mode all at once, so BatchNorm sees the whole batch.
        """
        chunk = self.image_chunk if not self.training else len(images)
        pieces = [self.cnn2d(images[i : i + chunk]) for i in range(0, len(images), max(chunk, 1))]
        maps = [torch.cat([p[level] for p in pieces]) for level in range(len(LEVEL_NAMES))]
        return [
            self.view_embedders[name](maps[level], K, cam_to_world, LEVEL_IMAGE_STRIDES[level])
            for level, name in enumerate(LEVEL_NAMES)
        ]

    def fuse(
        self,
        level: int,
        points_world: torch.Tensor,
        feats: torch.Tensor,
        K: torch.Tensor,
        cam_to_world: torch.Tensor,
        image_hw: tuple[int, int],
        with_views: bool = True,
        evidence: StereoEvidence | None = None,
    ) -> FusionOutput:
        """Back-project `feats` to the points and fuse over views.

        points_world (M, 3) voxel corners in metres; feats (V, C, h, w) from encode_views at this
        level; K (V, 3, 3) in image pixels; cam_to_world (V, 4, 4); image_hw the images' (H, W).
        with_views=False drops the (M, V) per-view outputs (inference needs only the features).
        evidence: the V views' stereo depth maps (StereoEvidence.views), required exactly when the
        config asks for view tokens.
        """
        tokens = self.config.stereo_evidence is not None and self.config.stereo_evidence.view_tokens
        if tokens and evidence is None:
            raise ValueError("these weights take stereo evidence: pass the views' stereo depth maps to fuse()")
        if evidence is not None and len(evidence) != len(feats):
            raise ValueError(f"stereo evidence has {len(evidence)} maps for {len(feats)} views")
        stride = LEVEL_IMAGE_STRIDES[level]
        h, w = feats.shape[-2:]
        if (h, w) != (-(-image_hw[0] // stride), -(-image_hw[1] // stride)):
            raise ValueError(f"level {level} feature map {(h, w)} does not belong to images of size {image_hw}")
        name = LEVEL_NAMES[level]
        points = points_world.to(torch.float32)
        pooled, logits, projections = [], [], []
        # max(.., 1): an empty point set still makes one (empty) chunk, so shapes stay consistent.
        for start in range(0, max(len(points), 1), self.fusion_chunk):
            chunk_pooled, chunk_logits, projection = self._fuse_chunk(
                level, points[start : start + self.fusion_chunk], feats, K, cam_to_world, stride,
                evidence if tokens else None,
            )
            pooled.append(chunk_pooled)
            if with_views:  # otherwise let each chunk's (m, V) tensors go at once
                logits.append(chunk_logits)
                projections.append(projection)
        features = self.layer_norms[name](torch.cat(pooled))
        if not with_views:
            return FusionOutput(features)
        return FusionOutput(
            features=features,
            proj_occ_logits=None if logits[0] is None else torch.cat(logits),
            valid=torch.cat([p.valid for p in projections]),
            depth=torch.cat([p.depth for p in projections]),
            pixels=torch.cat([p.pixels for p in projections]),
        )

    def _fuse_chunk(
        self, level: int, points: torch.Tensor, feats: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor,
        stride: int, evidence: StereoEvidence | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None, Projection]:
        """points (m, 3) -> pooled (m, C) before LayerNorm, proj-occ logits (m, V) | None, the projection."""
        name = LEVEL_NAMES[level]
        projection = project_to_feature_maps(points, K, cam_to_world, stride, tuple(feats.shape[-2:]))
        # Points no view sees pool to exactly 0 under both pooling rules, so the transformer only
        # runs on the seen ones; their per-view logits (never valid, never supervised) stay 0.
        seen = torch.nonzero(projection.valid.any(dim=1)).view(-1)
        all_seen = len(seen) == len(points)
        grid, depth, valid = projection.grid, projection.depth, projection.valid
        if not all_seen:
            grid, depth, valid = grid[seen], depth[seen], valid[seen]
        sampled = sample_features(feats, grid)  # (m, V, C)
        tokens = None
        if evidence is not None:
            seen_points = points if all_seen else points[seen]
            tokens = view_evidence(seen_points, evidence, self.evidence_truncation(level)).to(sampled.dtype)
        pooled, logits = self.mv_fusion[name](sampled, depth, valid, self.use_proj_occ, tokens)
        if not all_seen:
            pooled = pooled.new_zeros(len(points), pooled.shape[1]).index_copy(0, seen, pooled)
            if logits is not None:
                logits = logits.new_zeros(len(points), logits.shape[1]).index_copy(0, seen, logits)
        return pooled, logits, projection

    def level_step(
        self, level: int, coords: torch.Tensor, fused: torch.Tensor, previous: LevelOutput | None,
        evidence: LevelEvidence | None = None,
    ) -> LevelOutput:
        """3D CNN + head at one level.

        coords (N, 4) [batch, x, y, z] level units; fused (N, C_l) from fuse(); previous: the
        upsampled output of the level above, row-aligned with coords (None at level 0);
        evidence: the voxels' stereo evidence (`level_evidence()`), required exactly when the config
        has stereo evidence.
        """
        name = LEVEL_NAMES[level]
        if self.uses_stereo != (evidence is not None):
            raise ValueError("stereo evidence must be given exactly when the weights take stereo evidence")
        if evidence is not None:
            if len(evidence) != len(coords):
                raise ValueError(f"stereo evidence has {len(evidence)} rows for {len(coords)} voxels")
            fused = torch.cat([fused, evidence.tsdf.reshape(-1, 1).to(fused)], dim=1)
        if level == 0:
            x = fused
        else:
            if previous is None:
                raise ValueError(f"level {level} needs the upsampled output of level {level - 1}")
            if previous.coords.shape != coords.shape or not torch.equal(previous.coords, coords):
                raise ValueError("previous.coords must be the same rows as coords (upsampled, then subsampled alike)")
            dtype = torch.promote_types(fused.dtype, previous.features.dtype)
            x = torch.cat([previous.features.to(dtype), fused.to(dtype), previous.logits[:, None].to(dtype)], dim=1)
        if len(coords) == 0:
            width = self.config.unet_out_channels(level)
            return LevelOutput(coords, x.new_zeros(0, width), x.new_zeros(0))
        voxels = self.cnns3d[name](SparseVoxels(coords, x, stride=1))
        logits = self.output_layers[name](voxels).feats[:, 0]
        if evidence is not None:
            logits = logits + evidence.start.to(logits)
        return LevelOutput(coords, voxels.feats, logits)

    def prune_and_upsample(self, out: LevelOutput, evidence: LevelEvidence | None = None) -> LevelOutput:
        """Keep voxels with logit > 0 and copy each to its 8 children (next level's coordinates).
        With stereo evidence, the blocks kept beyond the classical ones are capped (`cap_added_blocks`)."""
        keep = out.logits > 0
        if evidence is not None:
            keep = cap_added_blocks(keep, out.logits, evidence.start.to(out.logits))
        kept = out.select(keep)
        return LevelOutput(
            coords=self.upsampler.upsample_coords(kept.coords),
            features=self.upsampler.upsample_values(kept.features),
            logits=self.upsampler.upsample_values(kept.logits),
        )

    # --- training forward ---------------------------------------------------------------------

    def forward(self, batch: VortxBatch) -> dict[str, LevelPrediction]:
        """Coarse-to-fine over a batch of crops -> {level name: LevelPrediction}.

        Levels after one where no voxel has logit > 0 are absent (as in the authors' code). In train
        mode with `config.voxel_dropout`, at most `config.max_train_voxels` random voxels per sample
        are kept after upsampling at the medium and fine levels.
        """
        b, v = batch.images.shape[:2]
        image_hw = (batch.images.shape[-2], batch.images.shape[-1])
        # One backbone pass over all B*V images (BatchNorm statistics over the whole batch, as the
        # authors), then split per sample: each sample only sees its own views.
        maps = self.encode_views(batch.images.flatten(0, 1), batch.K.flatten(0, 1), batch.cam_to_world.flatten(0, 1))
        feats = [[m.view(b, v, *m.shape[1:])[i] for m in maps] for i in range(b)]

        predictions: dict[str, LevelPrediction] = {}
        fine = None
        if self.uses_stereo:
            if batch.stereo is None:
                raise ValueError("these weights take stereo evidence: the batch has none (VortxBatch.stereo)")
            fine = [self.crop_fine_fusion(batch.origin[i], batch.crop_shape, batch.stereo[i]) for i in range(b)]
        coords = dense_grid_coords(b, [c // 4 for c in batch.crop_shape], batch.images.device)
        previous: LevelOutput | None = None
        out: LevelOutput | None = None
        for level, name in enumerate(LEVEL_NAMES):
            if out is not None:
                previous = self.prune_and_upsample(out, evidence)
                if len(previous) == 0:
                    break
                if self.training and self.config.voxel_dropout:
                    previous = previous.select(subsample_per_sample(previous.coords, self.config.max_train_voxels[level - 1]))
                coords = previous.coords
            voxel_size = self.config.level_voxel_size(level)
            points = batch.origin.to(torch.float32)[coords[:, 0]] + coords[:, 1:].to(torch.float32) * voxel_size
            fused, views, evidence = self._fuse_batch(level, coords, points, feats, batch, image_hw, fine)
            out = self.level_step(level, coords, fused, previous, evidence)
            predictions[name] = LevelPrediction(coords=coords, points=points, logits=out.logits,
                                                voxel_size=voxel_size, **views)
        return predictions

    def _fuse_batch(
        self,
        level: int,
        coords: torch.Tensor,
        points: torch.Tensor,
        feats: list[list[torch.Tensor]],
        batch: VortxBatch,
        image_hw: tuple[int, int],
        fine: list[FineFusion] | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor | None], LevelEvidence | None]:
        """fuse() per sample (each with its own views), scattered back into the batch's row order.

        coords (N, 4), points (N, 3), feats[sample][level] (V, C, h, w), fine: with stereo evidence
        each sample's classical fused TSDF -> fused (N, C), the per-view fields of LevelPrediction
        ((N, V) / (N, V, 2)) and, with stereo evidence, the voxels' LevelEvidence from each sample's
        own maps."""
        n, v = len(coords), batch.images.shape[1]
        evidence_rows = LevelEvidence(points.new_ones(n), points.new_zeros(n)) if self.uses_stereo else None
        fused = None
        views: dict[str, torch.Tensor | None] = {
            "proj_occ_logits": None,
            "valid": torch.zeros(n, v, dtype=torch.bool, device=coords.device),
            "depth": points.new_zeros(n, v),
            "pixels": points.new_zeros(n, v, 2),
        }
        for i in range(batch.batch_size):
            rows = torch.nonzero(coords[:, 0] == i).view(-1)
            if len(rows) == 0:
                continue
            evidence = None
            if self.uses_stereo:
                evidence = batch.stereo[i].views(batch.stereo_views[i])
                sample = self.level_evidence(level, coords[rows, 1:], points[rows], batch.stereo[i], fine[i])
                evidence_rows = LevelEvidence(evidence_rows.tsdf.index_copy(0, rows, sample.tsdf.to(points)),
                                              evidence_rows.start.index_copy(0, rows, sample.start.to(points)))
            fo = self.fuse(level, points[rows], feats[i][level], batch.K[i], batch.cam_to_world[i], image_hw,
                           evidence=evidence)
            if fused is None:
                fused = fo.features.new_zeros(n, fo.features.shape[1])
            fused = fused.index_copy(0, rows, fo.features)
            if fo.proj_occ_logits is not None:
                if views["proj_occ_logits"] is None:
                    views["proj_occ_logits"] = fo.proj_occ_logits.new_zeros(n, v)
                views["proj_occ_logits"] = views["proj_occ_logits"].index_copy(0, rows, fo.proj_occ_logits)
            for key in ("valid", "depth", "pixels"):
                views[key][rows] = getattr(fo, key).to(views[key].dtype)
        if fused is None:
            fused = points.new_zeros(n, self.config.feature_channels[level])
        return fused, views, evidence_rows


def dense_grid_coords(batch_size: int, shape: list[int], device: torch.device) -> torch.Tensor:
    """Every voxel of a (X, Y, Z) grid for each sample: (B*X*Y*Z, 4) int64 [batch, x, y, z], batch-major."""
    axes = [torch.arange(s, device=device) for s in shape]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    batch = torch.arange(batch_size, device=device).repeat_interleave(len(grid))
    return torch.cat([batch[:, None], grid.repeat(batch_size, 1)], dim=1)
