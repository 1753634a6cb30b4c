"""`python -m engine eval-sensor CAPTURE`: a phone capture's result against its own held-out LiDAR.

A phone export (3D Scanner App, Stray Scanner, Record3D, Polycam) carries a depth map per photo, but
no separate ground truth. So every `--every`-th photo is held out: the reconstruction runs, with
every default, on the other photos (their images and, unless `--no-sensor-depth`, their depth), and
the result mesh is rendered from each held-out camera and compared with that frame's own LiDAR depth
at its confident pixels (ARKit confidence high, depth under `MAX_TRUTH_DEPTH_M`). Per held-out frame,
then averaged:

- `within_5cm`: share of the confident pixels whose rendered depth is within 5 cm of the LiDAR's (a
  pixel where the mesh has no surface counts as a miss);
- `rendered`: share of the confident pixels where the mesh has a surface at all;
- `median_error_m`: median |rendered - LiDAR| where both exist;
- `normals_30deg`: share of the confident pixels where the mesh has a surface whose normal (from the
  rendered depth) lies within 30 deg of the LiDAR's (from its depth; the pixel and its four neighbours
  measured); a crumpled wall at the right depth scores low here (random orientations: ~13 %);
- `gap_rendered`: share of the frame's pixels where the sensor measured nothing the reconstruction
  takes (no return, or ARKit confidence low: glass, black, the far end of a corridor; `gap_share` of
  the frame) where the mesh has a surface all the same: what the walk's other photos filled in. No
  truth says where that surface should be, so it is coverage, not accuracy.

These per-pixel depths are strict on a walk: a wall seen at 70 deg from the ray is 3 cm off along its
normal when its depth is 8.8 cm off. So the mesh is also scored as every room is (`engine eval`,
SUN3D's protocol): against the LiDAR surface, the held-out frames' confident depth fused into a TSDF
(`lidar_surface`: 4 cm voxels, the truth's observed voxels trimming both sides), Atlas precision,
recall and F at 5 cm by nearest surface point, and the surface metrics (normal agreement, floaters,
pieces, area ratio). Beside it, the room box fitted to that truth: the metric's floor on the same
surface (a corridor's floor, ceiling and outer walls are most of its area).

Both variants run by default (sensor depth on, then stereo alone), so each number stands beside its
baseline measured the same way; the reconstruction's own flags (`--finish`, `--max-room-size`, ...)
apply to both.

Where points were triangulated with the poses the reconstruction uses (by the pose check, or by the
refinement when it ran), `photo_depth_ratio` is the median ratio of their depth to the held-out LiDAR's at the pixels they fall on:
how far the photos' own geometry (poses and intrinsics) and the truth disagree in scale before any
surface is built. On the 3D Scanner App corridor it is 0.983-0.993 (by which photos are checked): at 3 m, 2-5 cm of the 5 cm.

`--photos-only` measures what a user with the photos alone gets: the kept photos lose their poses,
intrinsics and depth, structure from motion poses them and finds up and scale as for any photo folder
(stereo alone, then), and the mesh is moved onto the phone's world by the similarity that fits the
SfM camera centres to the phone's before it is compared. The phone's poses are the truth for what SfM
found: the scale (phone metres per estimated metre, 1 when the floor-based scale is right) and how far
"up" is off (`engine.poses.pose_errors`). Where the LiDAR is no input (`--photos-only`, `--variant
stereo`), `--all-photos` keeps every photo in, as a user has them (SfM splits a walk with every
other photo missing sooner), and the LiDAR of every N-th frame stays the truth.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture import load_capture
from ..capture.model import Capture, Frame
from ..capture.sensor_depth import HIGH_CONFIDENCE, read_sensor_depth, sensor_measured, sensor_points
from ..errors import VortxError
from ..geometry.cameras import project_points, scale_intrinsics
from ..geometry.depth_normals import depth_normals
from ..geometry.depth_render import render_depth
from ..jobs import TqdmProgress
from ..mesh_io import Mesh
from ..poses.prepare import KEEP_POSES_HELP, SFM_IF_UNPOSED, prepare_capture
from ..poses import Similarity
from ..poses.sfm import SfmOptions
from ..recon.driver import reconstruct
from ..recon.output_frame import moved_mesh
from ..recon.presets import add_quality_argument, settings_from_quality_arguments
from ..recon.settings import ReconSettings, add_setting_arguments
from ..tsdf.integration import fuse_ground_truth
from ..tsdf.volume import TsdfVolume
from .against_truth import compare_poses
from .cli import truth_tsdf_mesh
from .mesh_metrics import evaluate_mesh
from .room_box import room_box_from_tsdf
from .surface_metrics import evaluate_surface

MAX_TRUTH_DEPTH_M = 4.5  # a phone LiDAR's reliable range; beyond it the sensor is no truth
AGREEMENT_M = 0.05
# A triangulated point and the LiDAR depth at its pixel farther apart than this ratio are two surfaces
# (the point hidden behind what the sensor saw, or the sensor's edge), not one measured twice.
SAME_SURFACE_RATIO = 1.25
MIN_RATIO_POINTS = 50
NORMAL_AGREEMENT_DEG = 30.0
# The LiDAR surface's grid: SUN3D's observed-space trim (4 cm, 12 cm band). SUN3D's truth mesh is fused
# at 2 cm, but a 2 cm grid over the corridor's 20 x 32 m walk would hold 2 GB; at 4 cm it is 0.5 GB.
TRUTH_VOXEL_M = 0.04
TRUTH_TRUNCATION_M = 0.12


@dataclass
class LidarSurface:
    """The held-out frames' LiDAR as one surface: `volume` their confident depth fused (its observed
    voxels trim what is scored), `mesh` its zero level, both in the phone's world."""

    volume: TsdfVolume
    mesh: Mesh


def split_capture(capture: Capture, every: int) -> tuple[Capture, list[Frame]]:
    """(the capture without every `every`-th frame (positions 1, 1 + every, ...), the held-out frames)."""
    if every < 2:
        raise VortxError(f"--every must be at least 2 (1 in every N photos held out), got {every}")
    held = [f for i, f in enumerate(capture.frames) if i % every == 1]
    kept = [f for i, f in enumerate(capture.frames) if i % every != 1]
    return capture.with_frames(kept), held


def sensor_truth(frame: Frame) -> tuple[np.ndarray, Optional[np.ndarray], np.ndarray, np.ndarray]:
    """A held-out frame's LiDAR as truth: depth (h, w) metres, confidence (h, w) or None, where it is
    truth (h, w) bool (a return under MAX_TRUTH_DEPTH_M, confidence high when the app exports one), and K
    (3, 3) at the depth map's size."""
    truth, confidence = read_sensor_depth(frame.sensor_depth)
    h, w = truth.shape
    confident = (truth > 0) & (truth < MAX_TRUTH_DEPTH_M)
    if confidence is not None:
        confident &= confidence >= HIGH_CONFIDENCE
    return truth, confidence, confident, scale_intrinsics(frame.K, (frame.width, frame.height), (w, h))


def compare_to_sensor(mesh: Mesh, frame: Frame, pose: np.ndarray) -> Optional[dict[str, float]]:
    """The mesh rendered from `frame` at `pose` (4, 4) against the frame's confident LiDAR depth, or
    None when the frame has no confident pixel in range."""
    assert frame.sensor_depth is not None and frame.K is not None
    truth, confidence, confident, K = sensor_truth(frame)
    h, w = truth.shape
    if not confident.any():
        return None
    rendered = render_depth(mesh.vertices, mesh.faces, K, pose, (w, h))
    hit = np.isfinite(rendered) & confident
    error = np.abs(rendered - truth)
    gap = ~sensor_measured(truth, confidence)
    true_normals, has_true_normal = depth_normals(np.where(confident, truth, 0.0), K)
    mesh_normals, has_mesh_normal = depth_normals(np.where(np.isfinite(rendered), rendered, 0.0), K)
    agree = np.abs(np.sum(true_normals * mesh_normals, axis=-1)) >= np.cos(np.radians(NORMAL_AGREEMENT_DEG))
    judged = has_true_normal & confident
    return {
        "within_5cm": float((hit & (error < AGREEMENT_M)).sum() / confident.sum()),
        "rendered": float(hit.sum() / confident.sum()),
        "median_error_m": float(np.median(error[hit])) if hit.any() else float("nan"),
        "normals_30deg": float((judged & has_mesh_normal & agree).sum() / judged.sum()) if judged.any() else float("nan"),
        "pixels": int(confident.sum()),
        "gap_share": float(gap.mean()),
        "gap_rendered": float((np.isfinite(rendered) & gap).sum() / gap.sum()) if gap.any() else float("nan"),
    }


def lidar_surface(views: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> LidarSurface:
    """The truth surface of `views`, each (depth (h, w) metres with 0 where it is no truth, K (3, 3) at
    its size, camera-to-world pose (4, 4)), fused as SUN3D's sensor depth is (`fuse_ground_truth`)."""
    depths, Ks, poses = zip(*views)
    volume = fuse_ground_truth(list(depths), np.stack(Ks), np.stack(poses), voxel_size=TRUTH_VOXEL_M,
                               trunc=TRUTH_TRUNCATION_M, depth_cap=MAX_TRUTH_DEPTH_M)
    return LidarSurface(volume, truth_tsdf_mesh(volume))


def held_out_surface(held: list[Frame]) -> LidarSurface:
    """`lidar_surface` of the held-out frames' confident depth, at their own (the phone's) poses."""
    views = []
    for frame in held:
        truth, _, confident, K = sensor_truth(frame)
        views.append((np.where(confident, truth, 0.0).astype(np.float32), K, frame.pose))
    return lidar_surface(views)


def surface_scores(mesh: Mesh, truth: LidarSurface) -> dict[str, float]:
    """Atlas metrics (acc, comp, prec, recall, fscore at 5 cm) and the surface metrics of `mesh`
    against `truth`, both trimmed to the truth's observed voxels, as `engine eval` scores a room."""
    return {**evaluate_mesh(mesh, truth.mesh, truth.volume).as_dict(),
            **evaluate_surface(mesh, truth.mesh, truth.volume).as_dict()}


def photo_depth_ratio(points: np.ndarray, views: list[tuple[Frame, np.ndarray]]) -> Optional[float]:
    """Median over `points` (N, 3) seen in `views` ((frame, 4 x 4 pose) with sensor depth) of the point's
    depth over the frame's confident LiDAR depth at its pixel, over the pairs within SAME_SURFACE_RATIO
    of each other; None with fewer than MIN_RATIO_POINTS such pairs."""
    ratios = []
    for frame, pose in views:
        truth, _, confident, K = sensor_truth(frame)
        h, w = truth.shape
        u, v, z = project_points(points, K, pose)
        inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        row, col = v[inside].astype(np.int64), u[inside].astype(np.int64)
        measured = confident[row, col]
        ratio = z[inside][measured] / truth[row, col][measured]
        ratios.append(ratio[(ratio > 1 / SAME_SURFACE_RATIO) & (ratio < SAME_SURFACE_RATIO)])
    ratios = np.concatenate(ratios) if ratios else np.zeros(0)
    return float(np.median(ratios)) if len(ratios) >= MIN_RATIO_POINTS else None


def mean_of_rows(rows: list[dict[str, float]]) -> dict[str, float]:
    """The held-out frames' mean of each `compare_to_sensor` score (a frame without a gap has none)."""
    keys = ("within_5cm", "rendered", "median_error_m", "normals_30deg", "gap_share", "gap_rendered")
    return {key: float(np.nanmean([r[key] for r in rows])) for key in keys}


def photos_alone(capture: Capture) -> Capture:
    """`capture` as a user with its photos alone has it: no poses, intrinsics, depth or sparse points."""
    frames = [replace(f, K=None, pose=None, sensor_depth=None, depth_path=None) for f in capture.frames]
    return replace(capture, format="images", frames=frames, metric=False, points=None, point_colors=None,
                   pose_origin="", warnings=[], notes=[])


def without_held_out_points(kept: Capture, held: list[Frame]) -> Capture:
    """`kept` whose point cloud, a phone capture's LiDAR (`load_capture`), leaves the `held` frames' out:
    the points bound and seed stereo, so the truth's own depth would otherwise be an input."""
    if kept.points is None or not kept.frames_with_sensor_depth:
        return kept
    held_photos = {f.image_path for f in held}
    return kept.with_points(*sensor_points([f for f in kept.frames if f.image_path not in held_photos]))


def evaluate_variant(kept: Capture, held: list[Frame], settings: ReconSettings, keep_poses: bool = False,
                     progress=None, photos_only: bool = False, sfm_options: Optional[SfmOptions] = None) -> dict:
    """Reconstruct `kept` as `engine reconstruct` does (pose check, refinement when off) with `settings`,
    and compare the mesh with each held-out frame's LiDAR, and with their surface (fused once the
    reconstruction is done, so its grid never adds to its peak memory). `photos_only`: from
    `photos_alone(kept)`, posed by structure from motion with `sfm_options`."""
    if not photos_only:
        kept = without_held_out_points(kept, held)
    started = time.perf_counter()
    prepared = prepare_capture(photos_alone(kept) if photos_only else kept, sfm=SFM_IF_UNPOSED, check_poses=True,
                               refine_when_off=not keep_poses, progress=progress, sfm_options=sfm_options)
    result = reconstruct(prepared.capture, settings, progress=progress)
    seconds = time.perf_counter() - started
    mesh, poses_found = result.mesh, None
    if photos_only:
        # The mesh moves onto the phone's world; the held-out frames keep the phone's poses.
        comparison = compare_poses({f.image_path.stem: f.pose for f in prepared.capture.frames if f.pose is not None},
                                   {f.image_path.stem: f.pose for f in kept.frames if f.pose is not None})
        mesh = moved(mesh, comparison.to_truth)
        poses_found = {"registered": len(comparison.stems), "photos": len(kept.frames),
                       "models": list(prepared.sfm.model_sizes) if prepared.sfm is not None else [],
                       "scale_source": prepared.scale_source, "description": prepared.description,
                       **{key: float(value) for key, value in comparison.errors.items()}}
        similarity = None
    else:
        # Held-out poses move into the reconstruction's world as the kept ones did (identity for a metric capture).
        similarity = prepared.similarity
    rows = []
    for frame in held:
        pose = similarity.apply_pose(frame.pose) if similarity is not None else frame.pose
        row = compare_to_sensor(mesh, frame, pose)
        if row is not None:
            rows.append({"frame": frame.name, **row})
    # Points triangulated with the poses used, in the phone's world as the held-out poses are: the
    # refinement's when it ran, else the pose check's (a capture's own points, the LiDAR's, would agree
    # with the LiDAR by construction).
    triangulated = None
    if not photos_only:
        triangulated = (prepared.refinement.points if prepared.refinement is not None
                        else prepared.pose_check.triangulated if prepared.pose_check is not None else None)
    ratio = (photo_depth_ratio(triangulated, [(frame, frame.pose) for frame in held])
             if triangulated is not None and len(triangulated) else None)
    if not rows:
        raise VortxError("no held-out frame has confident sensor depth to compare with")
    mean = mean_of_rows(rows)
    # The surface is the phone's; the mesh goes back there (identity for a metric capture).
    to_phone = comparison.to_truth if photos_only else similarity.inverse() if similarity is not None else None
    truth = held_out_surface(held)
    surface = surface_scores(mesh if photos_only else moved(mesh, to_phone), truth)
    # Finish Off from the same run: marching cubes' mesh before the finishing
    unfinished = (surface_scores(moved(result.unfinished_mesh, to_phone), truth)
                  if result.unfinished_mesh is not None else None)
    return {"sensor_depth": settings.sensor_depth and not photos_only, "photos_only": photos_only,
            "poses_found": poses_found, "settings": settings.to_dict(), "keep_poses": keep_poses,
            "poses_refined": prepared.refinement is not None, "frames_in": len(kept.frames), "held_out": len(rows),
            "faces": int(len(mesh.faces)), "seconds": round(seconds, 1), "mean": mean, "surface": surface,
            "surface_unfinished": unfinished,
            "frames": rows,
            "photo_depth_ratio": ratio,
            "stereo": result.stats.get("stereo", {}), "finish": result.stats.get("finish", {}),
            "warnings": list(result.warnings)}


def moved(mesh: Mesh, similarity: Optional[Similarity]) -> Mesh:
    """`mesh` moved by `similarity` (`output_frame.moved_mesh`); None leaves it as it is."""
    return mesh if similarity is None else moved_mesh(mesh, similarity)


def variant_name(result: dict) -> str:
    return ("photos alone (SfM)" if result.get("photos_only") else "sensor depth" if result["sensor_depth"]
            else "stereo alone")


def format_rows(results: list[dict], box: Optional[dict] = None) -> str:
    """The per-pixel table, then the table against the LiDAR surface (with `box`, the room box's
    scores on it), then what the photos' geometry and SfM found."""
    lines = [f"{'variant':<22}{'within 5 cm':>12}{'rendered':>10}{'median err':>12}{'normals':>9}{'gaps filled':>13}"
             f"{'faces':>9}{'time':>8}"]
    for r in results:
        m = r["mean"]
        lines.append(f"{variant_name(r):<22}{m['within_5cm']:>12.3f}{m['rendered']:>10.3f}{100 * m['median_error_m']:>10.1f}cm"
                     f"{m['normals_30deg']:>9.3f}{m['gap_rendered']:>13.3f}{r['faces']:>9}{r['seconds']:>7.0f}s")
    if results:
        lines.append(f"gaps filled: of the held-out pixels where the sensor measured nothing "
                     f"({results[0]['mean']['gap_share']:.0%} of them), the share the mesh covers")
    surface_rows = [(variant_name(r), r["surface"]) for r in results if r.get("surface")]
    if box is not None:
        surface_rows.append(("room box (fitted to it)", box))
    if surface_rows:
        lines.append(f"against the LiDAR surface (the held-out frames' confident depth fused at {100 * TRUTH_VOXEL_M:g} cm; "
                     f"both trimmed to its observed voxels; 5 cm):")
        lines.append(f"{'':<24}{'prec':>7}{'recall':>8}{'F':>7}{'normals':>9}{'floaters':>10}{'pieces':>8}{'area ratio':>12}")
        for name, m in surface_rows:
            lines.append(f"{name:<24}{m['prec']:>7.3f}{m['recall']:>8.3f}{m['fscore']:>7.3f}{m['normal_agreement']:>9.3f}"
                         f"{m['floater_share']:>10.3f}{m['pieces']:>8}{m['area_ratio']:>12.3f}")
    ratio = next((r["photo_depth_ratio"] for r in results if r.get("photo_depth_ratio") is not None), None)
    if ratio is not None:
        lines.append(f"the photos' own geometry: points triangulated with the poses used lie at {ratio:.3f} of the "
                     f"LiDAR's depth (median), {100 * abs(1 - ratio) * 3:.1f} cm at 3 m before any surface is built")
    for r in results:
        found = r.get("poses_found")
        if found:
            lines.append(f"photos alone: SfM posed {found['registered']} of {found['photos']} photos (models "
                         f"{', '.join(map(str, found['models']))}); scale {found['scale']:.3f} phone metres per metre "
                         f"found ({found['scale_source']}), up off by {found['up_deg']:.2f} deg, rotation error mean "
                         f"{found['rotation_deg_mean']:.2f} deg, position error mean {100 * found['position_mean']:.1f} cm")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="a phone app's export with depth (folder or zip)")
    parser.add_argument("--every", type=int, default=2, help="hold out 1 in every N photos (default 2)")
    parser.add_argument("--variant", choices=("both", "sensor", "stereo"), default="both",
                        help="with the sensor depth, stereo alone, or both (default)")
    parser.add_argument("--json", type=Path, help="write the per-frame and mean numbers here")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--keep-poses", action="store_true", help=KEEP_POSES_HELP)
    parser.add_argument("--photos-only", action="store_true",
                        help="reconstruct from the kept photos alone (their poses, intrinsics and depth dropped, SfM "
                             "poses them) and report the scale and up it found against the phone's")
    parser.add_argument("--all-photos", action="store_true",
                        help="with --photos-only or --variant stereo (the LiDAR is no input): reconstruct from every "
                             "photo and score on every N-th frame's LiDAR, as a user with all the photos gets")
    add_quality_argument(parser)
    add_setting_arguments(parser)  # the reconstruction's own flags (--finish, --max-room-size, ...)


def run(args: argparse.Namespace) -> int:
    capture = load_capture(args.capture)
    if not capture.frames_with_sensor_depth:
        raise VortxError(f"{args.capture} has no sensor depth maps to hold out: choose a phone export with LiDAR depth")
    variants = (False,) if args.photos_only else {"both": (True, False), "sensor": (True,), "stereo": (False,)}[args.variant]
    if args.all_photos and any(variants):
        raise VortxError("--all-photos: the sensor depth would be scored against itself; use it with --photos-only "
                         "or --variant stereo")
    kept, held = split_capture(capture, args.every)
    if args.all_photos:
        kept = capture
    held = [f for f in held if f.sensor_depth is not None and f.pose is not None]
    if not held:
        raise VortxError(f"{args.capture}: no held-out frame has a pose and sensor depth to compare with")
    progress = TqdmProgress(disable=args.quiet)
    try:
        settings = settings_from_quality_arguments(args)
        results = [evaluate_variant(kept, held, replace(settings, sensor_depth=v), args.keep_poses, progress,
                                    args.photos_only)
                   for v in variants]
    finally:
        progress.close()
    truth = held_out_surface(held)  # fused again (6 s on the corridor) rather than held through a reconstruction
    box = surface_scores(room_box_from_tsdf(truth.volume), truth)
    print(format_rows(results, box))
    if args.json:
        args.json.write_text(json.dumps({"capture": str(args.capture), "every": args.every, "results": results,
                                         "room_box": box},
                                        indent=1) + "\n")
    return 0
