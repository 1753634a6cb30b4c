"""The classical method: plane-sweep stereo depth -> TSDF fusion -> marching cubes -> coloured mesh.

No network and no weights: it is the honest floor of the learned method and the fallback that works
out of the box. The plan (keyframes, bounds, tiles) is the same as VoRTX's, so Blender draws the same
tile overlay and the result lands in the same voxel grid.
"""

from __future__ import annotations

import time
from typing import Any, Optional

import numpy as np
import torch

from ..capture import Capture
from ..geometry.cameras import pixels_to_world
from ..jobs import CancelToken, ProgressCallback, check, report
from ..stereo.depth_maps import estimate_depth_maps, stereo_references
from ..stereo.fused_tsdf import fuse_depth_maps
from ..stereo.options import MATCHER_PATCHMATCH, StereoOptions
from ..stereo.sensor_maps import sensor_depth_map
from ..stereo.depth_maps import DepthMap
from ..stereo.fused_tsdf import CLASSICAL_TRUNCATION_VOXELS, drop_unsupported_pieces
from ..stereo.vertex_evidence import attach_evidence
from .block_fusion import fuse_blocks
from .colour import colour_mesh
from .finish_step import finish_reconstruction
from .memory import PeakMemory
from .plan import ReconPlan, plan_reconstruction, posed_frames
from .scene_bounds import evidence_box
from .recon_result import ReconResult, StageTimer, empty_mesh
from .settings import ReconSettings
from .tiles import TileState


def stereo_options(settings: ReconSettings, device: torch.device) -> StereoOptions:
    """The stereo knobs of a reconstruction's settings (the depth range reaches past the frustum depth
    that bounds the scene, so a wall at the far side still has a plane behind it)."""
    return StereoOptions(matcher=settings.stereo_matcher, long_side=settings.stereo_image_size, planes=settings.stereo_planes,
                         sources=settings.stereo_sources,
                         best_k=max(1, settings.stereo_sources // 2), min_ncc=settings.stereo_min_ncc,
                         max_references=settings.stereo_views, consistency_views=settings.stereo_consistency,
                         sensor_depth=settings.sensor_depth,
                         min_depth=min(StereoOptions.min_depth, 0.5 * settings.frustum_depth),
                         max_depth=1.25 * settings.frustum_depth, device=str(device))


def stereo_depth_maps(
    capture: Capture, plan: ReconPlan, options: StereoOptions,
    progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
    stages: Optional[dict[str, float]] = None,
) -> list[DepthMap]:
    """Depth maps of (up to `options.max_references`) keyframes; sources come from every posed frame
    (the sweep) or from the other keyframes (PatchMatch, whose geometric passes need their maps).
    `stages` receives the matcher's stage seconds. With `options.sensor_depth`, every keyframe with
    sensor depth (a phone's LiDAR) gets its map from the sensor instead (stereo/sensor_maps.py), and
    stereo runs only for the others.

    DepthMap.frame indexes `plan.keyframes`, in keyframe order.
    """
    usable, _ = posed_frames(capture)
    frames = [capture.frames[i] for i in usable]
    poses = np.stack([f.pose for f in frames]).astype(np.float64)
    position = {frame_id: p for p, frame_id in enumerate(usable)}
    with_sensor = ({k for k, f in enumerate(plan.keyframes) if f.sensor_depth is not None}
                   if options.sensor_depth else set())
    without_sensor = np.array([k for k in range(len(plan.keyframes)) if k not in with_sensor], dtype=np.int64)
    chosen = without_sensor[stereo_references(len(without_sensor), options.max_references)]
    maps: list[DepthMap] = []
    if len(chosen):
        references = [position[plan.keyframe_ids[k]] for k in chosen]
        bounds = (plan.bounds.minimum, plan.bounds.maximum)
        # Sparse SfM points, when the capture carries them, give each view a tight depth range.
        points = capture.points if capture.points is not None and len(capture.points) else None
        maps = estimate_depth_maps(frames, poses, references, options, points=points, bounds=bounds, progress=progress,
                                   cancel=cancel, stages=stages)
        for m, k in zip(maps, chosen):
            m.frame = int(k)
    with_normals = options.matcher == MATCHER_PATCHMATCH  # the sensor's maps carry normals as PatchMatch's do
    for done, k in enumerate(sorted(with_sensor)):
        check(cancel)
        report(progress, "sensor depth", done, len(with_sensor))
        maps.append(sensor_depth_map(k, plan.keyframes[k], options.long_side, with_normals))
    return sorted(maps, key=lambda m: m.frame)


def depth_points_box(maps: list[DepthMap], margin: float, stride: int = 4) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """(min, max) world box of the stereo depths (every `stride`-th pixel, 0.5-99.5 percentile per
    axis, so a few wild depths do not stretch it), grown by `margin`; None when no map has a depth."""
    points = []
    for m in maps:
        v, u = np.nonzero(m.depth[::stride, ::stride] > 0)
        if len(v) == 0:
            continue
        v, u = v * stride, u * stride
        points.append(pixels_to_world(u, v, m.depth[v, u], m.K, m.pose))
    if not points:
        return None
    lo, hi = evidence_box(np.concatenate(points))
    return lo - margin, hi + margin


def fusion_grid(plan: ReconPlan, maps: list[DepthMap], voxel_size: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Origin (3,) and dims of the grid on the plan's voxel lattice that covers the surfaces stereo found:
    the scene bounds cut to the depth maps' box (the frusta at the bounds' depth reach metres past the
    walls, and fusion's cost is the grid's volume). The scene bounds keep whatever the sparse points
    show (scene_bounds.py); the same grid is the learned method's (`classical_fusion`), whose network
    runs only inside the plan's tiles, so both methods mesh the same space."""
    lo, hi = plan.bounds.minimum.astype(np.float64), plan.bounds.maximum.astype(np.float64)
    box = depth_points_box(maps, margin=4 * CLASSICAL_TRUNCATION_VOXELS * voxel_size)
    if box is not None:
        lo, hi = np.maximum(lo, box[0]), np.minimum(hi, box[1])
        hi = np.maximum(hi, lo + 2 * voxel_size)
    lattice = plan.grid.origin.astype(np.float64)
    origin = lattice + np.floor((lo - lattice) / voxel_size) * voxel_size
    dims = np.ceil((hi - origin) / voxel_size).astype(np.int64) + 1
    return origin, tuple(int(d) for d in np.maximum(dims, 2))


def classical_fusion(
    plan: ReconPlan, maps: list[DepthMap], voxel_size: float, device: torch.device,
    progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stereo method's fused TSDF of the depth maps: (origin (3,), tsdf, weight), each (X, Y, Z) float32
    on the plan's voxel lattice (`fusion_grid`), fused with the classical band. An evidence network starts
    from exactly this field (engine/model/stereo_evidence.py FineFusion)."""
    origin, dims = fusion_grid(plan, maps, voxel_size)
    tsdf, weight = fuse_depth_maps(maps, origin, dims, voxel_size, CLASSICAL_TRUNCATION_VOXELS, device, progress, cancel)
    return origin, tsdf, weight


def run_stereo_fusion(
    capture: Capture,
    settings: ReconSettings,
    device: torch.device,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    plan: Optional[ReconPlan] = None,
) -> ReconResult:
    """Reconstruct a mesh from a posed, metric capture with stereo fusion (see module doc)."""
    timer = StageTimer()
    started, cpu_started = time.perf_counter(), time.process_time()
    stats: dict[str, Any] = {"settings": settings.to_dict(), "model": {"method": "stereo"}, "device": str(device),
                             "torch": torch.__version__, "frames": len(capture.frames), "warnings": []}
    options = stereo_options(settings, device)
    options.validate()
    with PeakMemory(device) as memory:
        with timer.stage("keyframes"):
            plan = plan or plan_reconstruction(capture, settings, progress, cancel)
        stats.update({"keyframes": len(plan.keyframes), "keyframe_ids": list(plan.keyframe_ids),
                      "bounds": plan.bounds.to_dict(),
                      "tiles": {"count": len(plan.tiles), "active": len(plan.active_tiles)}})
        for tile in plan.active_tiles:
            tile.state = TileState.RUNNING
        stereo_stages: dict[str, float] = {}
        with timer.stage("stereo depth"):
            maps = stereo_depth_maps(capture, plan, options, progress, cancel, stereo_stages)
        stats["stereo"] = {
            "references": len(maps), "image_size": list(maps[0].depth.shape[::-1]) if maps else [],
            "completeness_mean": round(float(np.mean([m.completeness for m in maps])), 4) if maps else 0.0,
            "options": {k: v for k, v in vars(options).items() if k != "device"},
            "stages_s": {k: round(v, 4) for k, v in stereo_stages.items()},
        }
        if options.sensor_depth and any(f.sensor_depth is not None for f in plan.keyframes):
            stats["stereo"]["sensor_depth_maps"] = int(sum(plan.keyframes[m.frame].sensor_depth is not None for m in maps))
        check(cancel)
        with timer.stage("TSDF fusion"):  # fused and meshed block by block (block_fusion.py)
            origin, dims = fusion_grid(plan, maps, settings.voxel_size)
            blocks = fuse_blocks(maps, origin, dims, settings.voxel_size, CLASSICAL_TRUNCATION_VOXELS, device,
                                 options.evidence_fusion, options.min_support, progress, cancel)
            mesh = blocks.mesh
            stats["fusion"] = {"grid": list(dims), "blocks": blocks.blocks, "block_voxels": list(blocks.block_dims)}
        check(cancel)
        report(progress, "mesh", 0, 1)
        with timer.stage("mesh"):
            if blocks.vertex_support is not None and options.piece_min_views > 0:
                mesh, stats["pieces"] = drop_unsupported_pieces(mesh, blocks.vertex_support, options.piece_min_views)
            del blocks
        report(progress, "mesh", 1, 1)
        check(cancel)
        unfinished = mesh
        with timer.stage("finish"):
            mesh, finish_stats = finish_reconstruction(mesh, plan, settings, maps)
        if finish_stats is not None:
            stats["finish"] = finish_stats
        message = None
        if len(mesh.faces) == 0:
            message = ("stereo found no surface: the photos may lack texture or overlap, or the poses are not "
                       "metric and gravity-aligned (metres, world Z up)")
            mesh = empty_mesh()
        else:
            with timer.stage("colour"):
                mesh.colors = colour_mesh(mesh, plan, settings, progress, cancel)
            with timer.stage("evidence"):  # how well each vertex was observed: the confidence layer
                stats["evidence"] = attach_evidence(mesh, maps, settings.voxel_size, network_completes=False,
                                                    truncation_voxels=CLASSICAL_TRUNCATION_VOXELS)
    for tile in plan.active_tiles:
        tile.state = TileState.DONE if message is None else TileState.EMPTY
    stats["mesh"] = {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))}
    stats["timings_s"] = {**{k: round(v, 4) for k, v in timer.seconds.items()}, "total": round(time.perf_counter() - started, 4)}
    stats["cpu_timings_s"] = {**{k: round(v, 4) for k, v in timer.cpu_seconds.items()},
                              "total": round(time.process_time() - cpu_started, 4)}
    stats["memory"] = memory.to_dict()
    stats["warnings"] = list(plan.warnings)
    stats["message"] = message
    stats["tiles"]["states"] = {s.value: sum(t.state is s for t in plan.tiles) for s in TileState}
    return ReconResult(mesh, plan.tiles, stats, message, warnings=list(plan.warnings),
                       unfinished_mesh=unfinished if finish_stats is not None else None)
