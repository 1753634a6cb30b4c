"""`reconstruct`: photos with poses -> room mesh, the official VoRTX inference (spec section 4).

Per level (16 / 8 / 4 cm at the default 4 cm): every tile is back-projected and fused with its own
views (streaming tiles and voxel chunks bounds memory), the fused features of all tiles are
concatenated, and ONE 3D CNN pass runs over the whole scene, so tiles have no seams; then voxels
with logit > 0 are kept and upsampled to the next level, where they are re-split by tile. The fine
level's TSDF gives the mesh, coloured from the photos.
"""

from __future__ import annotations

import time
from typing import Any, Optional, Sequence

import numpy as np
import torch

from ..capture import Capture
from ..errors import VortxError
from ..jobs import CancelToken, ProgressCallback, check, report
from ..model.outputs import tsdf_from_logits
from ..model.stereo_evidence import FineFusion, meshable_voxels
from ..stereo.depth_maps import DepthMap
from ..stereo.fused_tsdf import CLASSICAL_TRUNCATION_VOXELS
from ..stereo.vertex_evidence import attach_evidence
from .block_fusion import MIN_OBSERVATIONS
from .colour import colour_mesh
from .finish_step import finish_reconstruction
from .features import FeatureCache, encode_keyframes, keyframe_image_size
from .tile_fusion import SceneStereo, fuse_tile
from .memory import PeakMemory
from .mesh import extract_mesh
from .network import load_network
from .plan import ReconPlan, plan_reconstruction
from . import stereo_fusion  # its functions looked up at call time: tests stand in for stereo_depth_maps
from .recon_result import ReconResult, StageTimer, empty_mesh
from .settings import LEVEL_SCALES, ReconSettings, level_label
from .tiles import TileState


def empty_scene_message(label: str) -> str:
    return (
        f"no voxel was predicted occupied at {label}: the weights may be untrained/random, or the poses "
        "are not metric and gravity-aligned (metres, world Z up); check the capture's scale and orientation"
    )


def reconstruct(
    capture: Capture,
    settings: ReconSettings,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    plan: Optional[ReconPlan] = None,
) -> ReconResult:
    """Reconstruct a mesh from a posed capture with `settings.method` (stereo fusion or VoRTX).

    plan: a plan made earlier with `plan_reconstruction(capture, settings)` (e.g. to draw its tiles
    while the run goes on: tile states change in place); made here when None.
    Raises PoseError when no frame has a pose, WeightsError for unusable weights, Cancelled.
    """
    settings.validate()
    device = resolve_device(settings.device)
    if settings.method == "stereo":
        return stereo_fusion.run_stereo_fusion(capture, settings, device, progress, cancel, plan)
    model, config, weights_label = load_network(settings.weights, settings.seed, device)
    return run_reconstruction(model, capture, settings, device, progress, cancel, plan, model_info={
        "weights": weights_label,
        "config": config.to_dict(),
    })


def resolve_device(name: str) -> torch.device:
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise VortxError("device 'cuda' was requested but this PyTorch has no usable CUDA GPU; use --device cpu")
    return device


def run_reconstruction(
    model: torch.nn.Module,
    capture: Capture,
    settings: ReconSettings,
    device: torch.device,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    plan: Optional[ReconPlan] = None,
    model_info: Optional[dict[str, Any]] = None,
) -> ReconResult:
    """The pipeline with a ready model: a VortxNet, or any object with its inference API
    (encode_views, fuse, level_step, prune_and_upsample) and a `config` (VortxConfig)."""
    timer = StageTimer()
    started, cpu_started = time.perf_counter(), time.process_time()
    stats: dict[str, Any] = {
        "settings": settings.to_dict(),
        "model": model_info or {},
        "device": str(device),
        "torch": torch.__version__,
        "frames": len(capture.frames),
        "warnings": [],  # this run's own warnings; the plan's are put first below
    }
    with PeakMemory(device) as memory:
        with timer.stage("keyframes"):
            plan = plan or plan_reconstruction(capture, settings, progress, cancel)
        stereo_maps = None
        if getattr(model, "uses_stereo", False):  # weights with stereo evidence: the depth maps, once
            with timer.stage("stereo depth"):
                stereo_maps = stereo_fusion.stereo_depth_maps(capture, plan, stereo_fusion.stereo_options(settings, device),
                                                             progress, cancel)
            stats["stereo"] = {"references": len(stereo_maps),
                               "completeness_mean": round(float(np.mean([m.completeness for m in stereo_maps])), 4)
                               if stereo_maps else 0.0}
        result = _run_planned(model, plan, settings, device, timer, stats, progress, cancel, stereo_maps)
    stats["timings_s"] = {**{k: round(v, 4) for k, v in timer.seconds.items()}, "total": round(time.perf_counter() - started, 4)}
    stats["cpu_timings_s"] = {**{k: round(v, 4) for k, v in timer.cpu_seconds.items()},
                              "total": round(time.process_time() - cpu_started, 4)}
    stats["memory"] = memory.to_dict()
    stats["warnings"] = list(plan.warnings) + stats["warnings"]
    result.warnings = list(stats["warnings"])
    stats["message"] = result.message
    stats["tiles"]["states"] = {s.value: sum(t.state is s for t in plan.tiles) for s in TileState}
    return result


def _run_planned(
    model: torch.nn.Module,
    plan: ReconPlan,
    settings: ReconSettings,
    device: torch.device,
    timer: StageTimer,
    stats: dict[str, Any],
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
    stereo_maps: Optional[Sequence[DepthMap]] = None,
) -> ReconResult:
    """stereo_maps: the run's stereo depth maps when it has them; they give the mesh its confidence layer
    (where no map sees the surface, the network completed it)."""
    grid = plan.grid
    active = plan.active_tiles
    config = model.config
    image_size = keyframe_image_size(plan.keyframes, settings.image_long_side or config.image_long_side)
    if abs(settings.voxel_size - config.voxel_size) > 1e-9:
        stats["warnings"].append(
            f"the weights were trained with {level_label(config.voxel_size)} voxels; {level_label(settings.voxel_size)} "
            "shows the network the scene at another scale, so expect a worse mesh"
        )
    stats.update({
        "keyframes": len(plan.keyframes),
        "keyframe_ids": list(plan.keyframe_ids),
        "image_size": list(image_size),
        "bounds": plan.bounds.to_dict(),
        "grid": {"origin": grid.origin.tolist(), "voxel_size": grid.voxel_size, "shape": grid.shape.tolist(),
                 "tiles_per_axis": grid.tiles_per_axis.tolist()},
        "tiles": {"count": len(plan.tiles), "active": len(active),
                  "views_per_tile": [int(len(t.views)) for t in plan.tiles],
                  "views_used": int(len(np.unique(np.concatenate([t.views for t in plan.tiles])))) if plan.tiles else 0},
        "levels": [],
    })
    if not active:
        return ReconResult(empty_mesh(), plan.tiles, stats, "no keyframe sees any part of the scene bounds")

    with timer.stage("features"):
        cache = encode_keyframes(model, plan.keyframes, plan.Ks, plan.poses, image_size, device,
                                 settings.feature_chunk, settings.fp16_features, progress, cancel)
    stats["feature_cache_bytes"] = cache.nbytes

    stereo = None
    if getattr(model, "uses_stereo", False):
        if not stereo_maps:
            raise VortxError("these weights take stereo depth, and stereo found no depth map for this capture")
        stereo = SceneStereo.from_depth_maps(stereo_maps, len(plan.keyframes), device)
        with timer.stage("TSDF fusion"):  # the classical method's field: where the network starts
            stereo.fine = classical_fine_fusion(plan, stereo_maps, settings.voxel_size, device, progress, cancel)
    final, message = _run_levels(model, plan, settings, cache, device, timer, stats, progress, cancel, stereo)
    del cache
    if final is None:
        for tile in plan.tiles:
            tile.state = TileState.EMPTY
        return ReconResult(empty_mesh(), plan.tiles, stats, message)

    report(progress, "mesh", 0, 1)
    with timer.stage("mesh"):
        tsdf = tsdf_from_logits(final.logits.reshape(-1).float()).cpu().numpy()
        voxels = final.coords[:, 1:].cpu().numpy()
        if stereo is not None:  # no surface where neither classical fusion nor the network observed
            keep, values = meshable_voxels(torch.from_numpy(tsdf), stereo.fine.observed_at(final.coords[:, 1:]).cpu())
            voxels, tsdf = voxels[keep.numpy()], values[keep].numpy()
        mesh = extract_mesh(voxels, tsdf, grid.origin, settings.voxel_size)
    report(progress, "mesh", 1, 1)
    stats["mesh"] = {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))}
    if len(mesh.faces) == 0:
        return ReconResult(empty_mesh(), plan.tiles, stats,
                           f"the fine TSDF ({level_label(settings.voxel_size)}) never changes sign, so there is no "
                           "surface: the weights may be untrained/random, or the poses are not metric and gravity-aligned")
    check(cancel)
    unfinished = mesh
    with timer.stage("finish"):
        mesh, finish_stats = finish_reconstruction(mesh, plan, settings, stereo_maps)
    if finish_stats is not None:  # the sidecar's "mesh" is the mesh written; marching cubes' count stays in "finish"
        stats["finish"] = finish_stats
        stats["mesh"] = {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))}
    with timer.stage("colour"):
        mesh.colors = colour_mesh(mesh, plan, settings, progress, cancel)
    if stereo_maps:
        with timer.stage("evidence"):
            # Judged in the band the classical surface it started from was fused with, as the stereo method does.
            stats["evidence"] = attach_evidence(mesh, stereo_maps, settings.voxel_size, network_completes=True,
                                                truncation_voxels=CLASSICAL_TRUNCATION_VOXELS)
    return ReconResult(mesh, plan.tiles, stats, None, unfinished_mesh=unfinished if finish_stats is not None else None)


def classical_fine_fusion(
    plan: ReconPlan, maps: Sequence[DepthMap], voxel_size: float, device: torch.device,
    progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
) -> FineFusion:
    """The stereo method's own fused TSDF of the run's maps, in the plan grid's fine-voxel frame."""
    origin, tsdf, weight = stereo_fusion.classical_fusion(plan, list(maps), voxel_size, device, progress, cancel)
    offset = np.round((origin - plan.grid.origin) / voxel_size).astype(np.int64)
    return FineFusion(torch.from_numpy(tsdf).to(device), tuple(int(o) for o in offset),
                      observed=torch.from_numpy(weight >= MIN_OBSERVATIONS).to(device))


def _coarse_coords(plan: ReconPlan) -> torch.Tensor:
    """(N, 4) [batch 0, x, y, z] every coarse voxel of the active tiles inside the scene bounds.

    The official code fuses whole tiles, but the padding past the bounds lies beyond every camera's
    frustum depth (or outside the clipped room) and would only cost time.
    """
    blocks = [plan.grid.level_indices(t, LEVEL_SCALES[0], within=plan.bounds) for t in plan.active_tiles]
    indices = np.concatenate(blocks)
    return torch.as_tensor(np.concatenate([np.zeros((len(indices), 1), np.int64), indices], axis=1))


def _fuse_level(
    model: torch.nn.Module,
    level: int,
    coords: torch.Tensor,
    plan: ReconPlan,
    cache: FeatureCache,
    settings: ReconSettings,
    device: torch.device,
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
    stereo: Optional[SceneStereo] = None,
) -> torch.Tensor:
    """Fused features (N, C_level) on the CPU, row-aligned with `coords` (N, 4), tile by tile.

    Voxels are re-split by tile at every level; children stay in their parent's tile because tiles
    align with the coarse grid. Tile states and per-tile voxel counts are updated as tiles finish.
    """
    scale = LEVEL_SCALES[level]
    voxel = settings.voxel_size * scale
    label = level_label(voxel)
    stage = f"fusion {label}"
    owner = plan.grid.tile_ids(coords[:, 1:].cpu().numpy(), scale)
    order = np.argsort(owner, kind="stable")
    starts = np.searchsorted(owner[order], np.arange(len(plan.tiles) + 1))
    points = torch.as_tensor(plan.grid.origin, dtype=torch.float32) + coords[:, 1:].cpu().float() * voxel
    fused = torch.zeros((len(coords), model.config.feature_channels[level]), dtype=torch.float32)
    active = [t for t, tile in enumerate(plan.tiles) if len(tile.views)]
    last_level = level == len(LEVEL_SCALES) - 1
    for done, t in enumerate(active):
        check(cancel)
        report(progress, stage, done, len(active))
        tile = plan.tiles[t]
        rows = torch.as_tensor(order[starts[t]:starts[t + 1]])
        tile.voxels[label] = int(len(rows))
        if len(rows) == 0:
            tile.state = TileState.EMPTY  # everything in it was pruned at the level above
            continue
        tile.state = TileState.RUNNING
        fused[rows] = fuse_tile(model, level, points[rows], cache, tile.views, device, settings.fusion_chunk, cancel,
                                stereo)
        tile.state = TileState.DONE if last_level else TileState.PENDING
    report(progress, stage, len(active), len(active))
    return fused


def _run_levels(
    model: torch.nn.Module,
    plan: ReconPlan,
    settings: ReconSettings,
    cache: FeatureCache,
    device: torch.device,
    timer: StageTimer,
    stats: dict[str, Any],
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
    stereo: Optional[SceneStereo] = None,
) -> tuple[Optional[Any], Optional[str]]:
    """Per level: fuse tile by tile, then ONE 3D CNN over all tiles' voxels (no seams), prune and
    upsample. -> (fine LevelOutput, None), or (None, message) when pruning leaves nothing."""
    coords = _coarse_coords(plan)
    if stereo is not None:  # where the classical method fused: the room as its depth maps show it
        coords = coords[stereo.fine.covers(LEVEL_SCALES[0], coords[:, 1:]).cpu()]
    previous = None
    for level, scale in enumerate(LEVEL_SCALES):
        voxel = settings.voxel_size * scale
        label = level_label(voxel)
        with timer.stage(f"fusion {label}"):
            fused = _fuse_level(model, level, coords, plan, cache, settings, device, progress, cancel, stereo)
            evidence = None
            if stereo is not None:  # this level's fused stereo TSDF (3D CNN input) and classical start
                points = torch.as_tensor(plan.grid.origin, dtype=torch.float32) + coords[:, 1:].cpu().float() * voxel
                evidence = model.level_evidence(level, coords[:, 1:].to(device), points.to(device), stereo.maps,
                                                stereo.fine)
        check(cancel)
        cnn_stage = f"3D CNN {label}"
        report(progress, cnn_stage, 0, 1)
        with timer.stage(cnn_stage), torch.inference_mode():
            out = model.level_step(level, coords.to(device), fused.to(device), previous, evidence)
            del fused
            occupied = int((out.logits.reshape(-1) > 0).sum())
            stats["levels"].append({"label": label, "voxel_size": voxel, "voxels": int(len(coords)), "occupied": occupied})
            if level == len(LEVEL_SCALES) - 1:
                report(progress, cnn_stage, 1, 1)
                return out, None
            previous = model.prune_and_upsample(out, evidence)
            del out
        report(progress, cnn_stage, 1, 1)
        if len(previous.coords) == 0:
            return None, empty_scene_message(label)
        coords = previous.coords
    raise AssertionError("unreachable: the loop returns at the fine level")
