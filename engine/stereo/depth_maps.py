"""Stereo depth maps of a posed capture: which views are references, their depth ranges, the sweep
for each, and the optional cross-view consistency filter.

References are the reconstruction's keyframes (at most `max_references`, evenly spaced); sources are
chosen among all posed frames, so a capture with many near-duplicate photos still gives each
reference a good baseline.
"""

from __future__ import annotations

import time
from typing import Optional, Sequence

import cv2
import numpy as np
import torch

from ..capture import Frame
from ..jobs import CancelToken, ProgressCallback, check, report
from ..geometry.cameras import pixels_to_world, project_points, scale_intrinsics, world_to_camera
from ..capture.images import load_resized, resized_size
from .depth_filters import median_depth, remove_speckles
from .options import MATCHER_PATCHMATCH, StereoOptions
from .patchmatch_views import PatchMatchSchedule, PlaneMap, cpu_workers, patchmatch_views
from .plane_smoothing import smooth_along_planes
from .source_views import scene_points, select_sources, select_sources_by_triangulation
from .sweep import sweep_depth
from .sparse_seed import sparse_seed_depth
from .depth_map import DepthMap
from .view_agreement import CONSISTENCY_NEIGHBOURS, adopt_confirmed_planes, filter_geometric, geometric_confirmations

MIN_RANGE_POINTS = 30  # sparse points a view must see before its depth range is taken from them
CONSISTENCY_RELATIVE_DEPTH = 0.02  # two depths agree within 2 % (stereo-evidence.md)


def stereo_references(count: int, max_references: int) -> np.ndarray:
    """(R,) int64 positions of at most `max_references` of `count` keyframes, evenly spaced."""
    if count <= max_references:
        return np.arange(count, dtype=np.int64)
    return np.unique(np.round(np.linspace(0, count - 1, max_references)).astype(np.int64))


def grey_image(frame: Frame, long_side: int) -> tuple[np.ndarray, tuple[int, int]]:
    """(h, w) float32 grey in [0, 1] at a long side of `long_side` pixels, and its size (w, h)."""
    size = resized_size(frame.width, frame.height, min(long_side, max(frame.width, frame.height)), multiple=1)
    rgb = load_resized(frame, size)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0, size


def depth_range(
    K: np.ndarray, pose: np.ndarray, size: tuple[int, int], options: StereoOptions,
    points: Optional[np.ndarray] = None, bounds: Optional[tuple[np.ndarray, np.ndarray]] = None,
) -> tuple[float, float]:
    """(near, far) metres for one view.

    From the sparse SfM points it sees when there are enough (1st-99th percentile, widened by
    0.75x / 1.25x as COLMAP does), else from the scene bounds (the farthest corner of the box);
    always within the options' [min_depth, max_depth].
    """
    near, far = options.min_depth, options.max_depth
    if points is not None and len(points):
        u, v, z = project_points(points, K, pose)
        seen = z[(z > 1e-3) & (u >= 0) & (u < size[0]) & (v >= 0) & (v < size[1])]
        if len(seen) >= MIN_RANGE_POINTS:
            lo, hi = np.percentile(seen, [1, 99])
            near, far = max(near, 0.75 * lo), min(far, 1.25 * hi)
            return (near, far) if far > near * 1.1 else (options.min_depth, options.max_depth)
    if bounds is not None:
        lo, hi = bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        z = world_to_camera(corners, pose)[:, 2]
        far = min(far, max(float(z.max()), near * 2))
    return near, far


def ground_heights(points: Optional[np.ndarray], bounds: Optional[tuple[np.ndarray, np.ndarray]]) -> Optional[tuple[float, float]]:
    """(lowest, highest) world z of the scene for the horizontal-plane sweep: the scene box's, else the
    sparse points' 1st-99th percentile; None when neither is known."""
    if bounds is not None:
        return float(bounds[0][2]), float(bounds[1][2])
    if points is not None and len(points) >= MIN_RANGE_POINTS:
        lo, hi = np.percentile(points[:, 2], [1, 99])
        return float(lo), float(hi)
    return None


def ground_sweep(pose: np.ndarray, count: int, heights: Optional[tuple[float, float]],
                 device: torch.device) -> Optional[tuple[torch.Tensor, float, torch.Tensor]]:
    """The `ground_planes` argument of `sweep_depth` for a reference at `pose`: world +Z in its camera
    coordinates, its height, and `count` plane heights spanning the scene (None when off or unknown)."""
    if count < 3 or heights is None or heights[1] - heights[0] < 0.1:
        return None
    up = torch.as_tensor(pose[:3, :3].T @ np.array([0.0, 0.0, 1.0]), dtype=torch.float32, device=device)
    return up, float(pose[2, 3]), torch.linspace(heights[0], heights[1], count, dtype=torch.float32, device=device)


def estimate_depth_maps(
    frames: Sequence[Frame],
    poses: np.ndarray,
    references: Sequence[int],
    options: StereoOptions,
    points: Optional[np.ndarray] = None,
    bounds: Optional[tuple[np.ndarray, np.ndarray]] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    stages: Optional[dict[str, float]] = None,
) -> list[DepthMap]:
    """Depth maps for `references` (positions in `frames`), matched against any of `frames` (the sweep)
    or against the other references (PatchMatch). `stages` receives seconds per stage.

    frames: posed frames with K; poses (F, 4, 4) camera-to-world (the frames' poses, metres);
    points: optional (N, 3) sparse points for the depth ranges; bounds: optional (min, max) of the
    scene box. Images are read once each, at the stereo resolution.
    """
    options.validate()
    device = torch.device(options.device)
    poses = np.asarray(poses, dtype=np.float64)
    # Grey images at the stereo size, kept on the CPU (one photo is a source of several references)
    # and moved to the device per reference, so a long capture does not fill GPU memory.
    images: dict[int, tuple[torch.Tensor, np.ndarray]] = {}

    def image(i: int) -> tuple[torch.Tensor, np.ndarray]:
        if i not in images:
            grey, size = grey_image(frames[i], options.long_side)
            K = scale_intrinsics(frames[i].K, (frames[i].width, frames[i].height), size)
            images[i] = (torch.as_tensor(grey), K)
        return images[i]

    if options.matcher == MATCHER_PATCHMATCH:
        return _patchmatch_maps(frames, poses, references, options, image, points, bounds, progress, cancel,
                                stages if stages is not None else {})
    heights = ground_heights(points, bounds)
    maps: list[DepthMap] = []
    for done, r in enumerate(references):
        check(cancel)
        report(progress, "stereo depth", done, len(references))
        reference, K_ref = image(int(r))
        size = (reference.shape[1], reference.shape[0])
        near_far = depth_range(K_ref, poses[r], size, options, points, bounds)
        # The sources are stacked, so they must share one size (mixed captures are refused upstream):
        # keep those of the most common size among them.
        candidates = [(int(s), *image(int(s))) for s in select_sources(poses, int(r), options.sources)]
        shapes = [tuple(im.shape) for _, im, _ in candidates]
        common = max(set(shapes), key=shapes.count) if shapes else None
        chosen = [(s, im, K) for (s, im, K), shape in zip(candidates, shapes) if shape == common]
        used = np.array([s for s, _, _ in chosen], dtype=np.int64)
        if chosen:
            src_stack = torch.stack([im for _, im, _ in chosen]).to(device)
            K_src = torch.as_tensor(np.stack([K for _, _, K in chosen]), dtype=torch.float32, device=device)
            src_from_ref = torch.as_tensor(np.linalg.inv(poses[used]) @ poses[r], dtype=torch.float32, device=device)
        else:
            src_stack = torch.zeros((0, *reference.shape), device=device)
            K_src = src_from_ref = torch.zeros((0, 3, 3), device=device)
        with torch.inference_mode():
            result = sweep_depth(reference.to(device), src_stack, torch.as_tensor(K_ref, dtype=torch.float32, device=device),
                                 K_src, src_from_ref, near_far, options.planes, options.refine_planes, options.best_k,
                                 options.window, options.min_ncc, options.refine_rounds, cancel,
                                 ground_planes=ground_sweep(poses[r], options.ground_planes, heights, device))
        depth = result.depth.cpu().numpy().astype(np.float32)
        confidence = result.confidence.cpu().numpy().astype(np.float32)
        if options.clean_depth:
            depth = median_depth(depth)
            speckles = remove_speckles(depth)
            depth[speckles], confidence[speckles] = 0.0, 0.0
        maps.append(DepthMap(int(r), depth, confidence, K_ref, poses[r], used, near_far))
    report(progress, "stereo depth", len(references), len(references))
    if options.consistency_views > 0:
        filter_consistent(maps, options.consistency_views)
    return maps


def filter_consistent(maps: list[DepthMap], min_views: int) -> None:
    """Drop, in place, depths that fewer than `min_views` other references confirm.

    A depth is confirmed by a neighbouring reference when its 3D point projects into that view
    and the neighbour's depth there agrees within 2 % of the point's depth in that view.
    """
    if not maps:
        return
    poses = np.stack([m.pose for m in maps])
    neighbours = max(CONSISTENCY_NEIGHBOURS, min_views)  # asking for more confirmations than views checked would drop everything
    confirmations = []
    for a, m in enumerate(maps):
        h, w = m.depth.shape
        v, u = np.nonzero(m.depth > 0)
        z = m.depth[v, u].astype(np.float64)
        world = pixels_to_world(u, v, z, m.K, m.pose)
        count = np.zeros(len(z), dtype=np.int64)
        for b in select_sources(poses, a, neighbours):
            other = maps[int(b)]
            cam = (world - other.pose[:3, 3]) @ other.pose[:3, :3]
            zb = cam[:, 2]
            front = zb > 1e-3
            zs = np.where(front, zb, 1.0)
            ub = np.floor(other.K[0, 0] * cam[:, 0] / zs + other.K[0, 2]).astype(np.int64)
            vb = np.floor(other.K[1, 1] * cam[:, 1] / zs + other.K[1, 2]).astype(np.int64)
            oh, ow = other.depth.shape
            inside = front & (ub >= 0) & (ub < ow) & (vb >= 0) & (vb < oh)
            found = np.zeros(len(z))
            found[inside] = other.depth[vb[inside], ub[inside]]
            count += (inside & (found > 0) & (np.abs(found - zb) <= CONSISTENCY_RELATIVE_DEPTH * zb)).astype(np.int64)
        confirmations.append((v, u, count))
    for m, (v, u, count) in zip(maps, confirmations):
        drop = count < min_views
        m.depth[v[drop], u[drop]] = 0.0
        m.confidence[v[drop], u[drop]] = 0.0


def patchmatch_sources(poses: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, reference: int, count: int,
                       depth_range: tuple[float, float], seed: Optional[np.ndarray] = None) -> np.ndarray:
    """Sources of `reference` among the given views by triangulation angle and overlap over its whole
    view (a grid of its pixels, lifted to the sparse points' surface where `seed` (h, w), their
    triangulated depth, covers them, and to the middle of its depth range elsewhere); the pose rule
    (`select_sources`) when that finds fewer than `count`.

    Not over the sparse points alone, as OpenMVS does: in a room they sit on the textured things, so
    the sources chosen for them miss the plain walls and floor around them. On the demo room (SfM
    poses and points) the grid gave F 0.789 against 0.763, recall 0.737 against 0.687; on the real
    SUN3D room 0.493 against 0.490 (docs/experiments.md, "PatchMatch faster on 2 cores"). The grid at
    one middle depth, though, chose sources with less overlap where the surface is far from it: lifting
    it to the seed's depth took SUN3D's depth maps within 5 % from 0.609 to 0.637 and room_07002's F
    from 0.656 to 0.686 (docs/experiments.md, "Sources over the seed's surface")."""
    middle = 2.0 / (1.0 / depth_range[0] + 1.0 / depth_range[1])  # the middle in inverse depth
    seen = scene_points(Ks[reference], poses[reference], tuple(sizes[reference]), middle, seed)
    chosen = select_sources_by_triangulation(poses, Ks, sizes, reference, count, seen)
    if len(chosen) < count:
        extra = [s for s in select_sources(poses, reference, count) if s not in set(chosen.tolist())]
        chosen = np.concatenate([chosen, np.asarray(extra[:count - len(chosen)], dtype=np.int64)])
    return chosen.astype(np.int64)


def _patchmatch_maps(
    frames: Sequence[Frame], poses: np.ndarray, references: Sequence[int], options: StereoOptions, image,
    points: Optional[np.ndarray], bounds: Optional[tuple[np.ndarray, np.ndarray]],
    progress: Optional[ProgressCallback], cancel: Optional[CancelToken], stages: dict[str, float],
) -> list[DepthMap]:
    """PatchMatch depth and normal maps of `references` (patchmatch_views.py), matched against the
    other references (whose maps the geometric-consistency passes need), then filtered: kept where
    the matching cost is low enough and `options.consistency_views` other maps agree."""
    device = torch.device(options.device)
    references = [int(r) for r in references]
    ref_poses = poses[references]
    Ks = np.stack([image(r)[1] for r in references])
    sizes = np.array([(image(r)[0].shape[1], image(r)[0].shape[0]) for r in references])
    ranges = [depth_range(Ks[i], poses[r], tuple(sizes[i]), options, points, bounds) for i, r in enumerate(references)]
    seeds = None
    if options.sparse_seed and points is not None and len(points):
        started = time.perf_counter()
        seeds = [sparse_seed_depth(points, Ks[i], ref_poses[i], tuple(sizes[i]), ranges[i]) for i in range(len(references))]
        stages["sparse seed"] = time.perf_counter() - started
    # Sources among the references (positions into `references`), all of one size.
    sources = {}
    for i, r in enumerate(references):
        chosen = patchmatch_sources(ref_poses, Ks, sizes, i, options.sources, ranges[i],
                                    None if seeds is None else seeds[i])
        sources[i] = [int(s) for s in chosen if tuple(sizes[s]) == tuple(sizes[i])]
    schedule = PatchMatchSchedule(scales=options.scales, window=options.pm_window, coarse_iterations=options.coarse_iterations,
                                  fine_iterations=options.fine_iterations, geometric_passes=options.geometric_passes,
                                  geometric_weight=options.geometric_weight,
                                  seed_planes=options.seed_planes, planar_prior=options.planar_prior)
    local_image = lambda i: image(references[i])  # noqa: E731
    planes = patchmatch_views(list(range(len(references))), lambda i: sources[i], local_image, ref_poses, ranges,
                              schedule, device, initial_depths=seeds, progress=progress, cancel=cancel, stages=stages)
    started = time.perf_counter()
    maps = []
    max_cost = 1.0 - options.min_ncc
    on_prior = []
    for i, (r, plane) in enumerate(zip(references, planes)):
        keep = plane.cost <= max_cost
        prior = prior_candidates(plane, keep)
        on_prior.append(prior)
        depth = np.where(keep | prior, plane.depth, 0.0).astype(np.float32)
        confidence = np.where(keep, np.clip(1.0 - plane.cost, 0.0, 1.0), np.where(prior, PRIOR_CONFIDENCE, 0.0)).astype(np.float32)
        used = np.array([references[s] for s in sources[i]], dtype=np.int64)
        maps.append(DepthMap(r, depth, confidence, Ks[i], poses[r], used, ranges[i], normal=plane.normal))
    if any(p.any() for p in on_prior):
        keep_confirmed(maps, on_prior, PRIOR_CONFIRMING_VIEWS)
    if options.consistency_views > 0:
        filter_geometric(maps, options.consistency_views)
    for m in maps:
        speckles = remove_speckles(m.depth)
        m.depth[speckles], m.confidence[speckles] = 0.0, 0.0
    if options.adopt_confirmed_planes:
        adopt_confirmed_planes(maps, workers=cpu_workers(device))
    if options.plane_smoothing:
        for m in maps:
            m.depth = smooth_along_planes(m.depth, m.normal, m.K)
    stages["depth filter"] = time.perf_counter() - started
    return maps


# The planar prior's depths (planar_prior.py) that the photometric filter would drop: on a textureless
# wall no window matches, so the cost says nothing there; such a depth is kept when it lies on its
# prior plane and other views confirm it (ACMP's fusion: 2 views), with the weight in fusion of the
# weakest photometric depth kept at the default NCC >= 0.5.
PRIOR_AGREEMENT = 0.02  # the final depth within 2 % of the prior plane's
PRIOR_CONFIRMING_VIEWS = 2
PRIOR_CONFIDENCE = 0.5


def prior_candidates(plane: PlaneMap, photometric: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels the photometric filter drops (`photometric` False) whose depth lies on their
    planar prior's plane; all False when the map has no prior."""
    if plane.prior_depth is None:
        return np.zeros(plane.depth.shape, bool)
    prior = plane.prior_depth
    return ~photometric & (prior > 0) & (np.abs(plane.depth - prior) <= PRIOR_AGREEMENT * prior)


def keep_confirmed(maps: list[DepthMap], candidates: list[np.ndarray], min_views: int) -> None:
    """Drop, in place, the depths of each map's `candidates` (h, w) bool that fewer than `min_views` other
    maps confirm (`geometric_confirmations`); the other depths are left alone."""
    for m, candidate, (v, u, count) in zip(maps, candidates, geometric_confirmations(maps, min_views)):
        drop = candidate[v, u] & (count < min_views)
        m.depth[v[drop], u[drop]] = 0.0
        m.confidence[v[drop], u[drop]] = 0.0
