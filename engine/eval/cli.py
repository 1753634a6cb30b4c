"""`python -m engine eval PRED.ply GT.ply|ROOM_DIR [--observed TSDF.npz] [--depth [CAPTURE]] [--json out.json]`.

Prints the Atlas metrics table for the prediction and, with --box-baseline, for the room box fitted
to the ground truth (the floor a real result must beat), with --truth-tsdf for the truth's own TSDF
meshed (the ceiling of a volumetric method), then the surface metrics of the same meshes
(surface_metrics.py: normal agreement, floater share, pieces, area ratio, open boundary per m^2).
With --depth, also the 2D depth metrics: the meshes rendered into the capture's posed frames against
their depth maps.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..capture import load_capture
from ..data.room_folders import gt_path as room_tsdf_path
from ..errors import VortxError
from ..mesh_io import Mesh, read_ply
from ..recon.mesh import extract_mesh
from ..tsdf.volume import TsdfVolume
from .depth_metrics import DEPTH_METRIC_NAMES, capture_depth_views, mesh_depth_metrics
from .mesh_metrics import MeshMetrics, evaluate_mesh
from .room_box import fit_room_box, room_box_from_tsdf
from .surface_metrics import SURFACE_LEGEND, SurfaceMetrics, evaluate_surface, surface_table

COLUMNS = ("acc", "comp", "prec", "recall", "fscore")


def truth_tsdf_mesh(volume: TsdfVolume) -> Mesh:
    """The zero level of a ground-truth TSDF over its observed voxels, at its voxel size (world metres):
    the ceiling of a volumetric method, what a perfect fusion of the observed space scores.

    Its area ratio is not 1: a rendered room's thin two-sided parts mesh to one surface or none at 4 cm
    (37 % of room_07002's observed true surface, and of the demo room's, has an opposite-facing surface
    within 4 cm; their truths' TSDF meshes have area ratios 0.67 and 0.64)."""
    observed = volume.observed
    return extract_mesh(np.argwhere(observed), volume.tsdf[observed], volume.origin, volume.voxel_size)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pred", type=Path, help="predicted mesh (.ply), world metres")
    parser.add_argument("gt", type=Path, help="ground-truth mesh (.ply), or a synthetic room folder "
                        "(uses its mesh_gt.ply and, unless --observed is given, its ground-truth TSDF: tsdf_gt.npz "
                        "or tsdf_gt_04.npz)")
    parser.add_argument("--observed", type=Path, help="ground-truth TSDF (.npz): trim to its observed voxels")
    parser.add_argument("--no-trim-gt", action="store_true", help="trim only the prediction (Atlas does "
                        "not trim its scanned ground truth; our synthetic ground truth is the whole scene)")
    parser.add_argument("--threshold", type=float, default=0.05, help="precision/recall distance (m)")
    parser.add_argument("--down-sample", type=float, default=0.02, help="voxel down-sampling size (m)")
    parser.add_argument("--box-baseline", action="store_true", help="also score a plain box room fitted to the ground truth")
    parser.add_argument("--truth-tsdf", action="store_true",
                        help="also score the ground-truth TSDF meshed at its voxel size: what a perfect volumetric "
                        "reconstruction of the observed space scores (the ceiling of the area ratio, under 1 on rooms "
                        "with thin parts)")
    parser.add_argument("--depth", nargs="?", const=True, default=None, metavar="CAPTURE",
                        help="also the depth metrics against the depth maps of CAPTURE (default: the room "
                        "folder given as GT)")
    parser.add_argument("--depth-every", type=int, default=1, help="with --depth: use every N-th frame")
    parser.add_argument("--json", type=Path, help="write the metrics here as JSON")


def run(args: argparse.Namespace) -> int:
    gt_path, observed_path = args.gt, args.observed
    if gt_path.is_dir():
        room = gt_path
        gt_path = room / "mesh_gt.ply"
        if observed_path is None:

            observed_path = room_tsdf_path(room)  # the renderer's, or the one training fused
    for path in (args.pred, gt_path) + ((observed_path,) if observed_path else ()):
        if not path.is_file():
            raise VortxError(f"{path}: file not found")
    try:
        pred, gt = read_ply(args.pred), read_ply(gt_path)
    except (ValueError, KeyError) as error:
        raise VortxError(f"cannot read mesh: {error}") from error
    observed = TsdfVolume.load(observed_path) if observed_path else None
    depth_views = None
    if args.depth is not None:
        source = args.gt if args.depth is True else Path(args.depth)
        if not source.is_dir():
            raise VortxError(f"--depth needs a capture folder with depth maps (a rendered room or ScanNet scene); "
                             f"{source} is not a folder")

        depth_views = capture_depth_views(load_capture(source), every=max(1, args.depth_every))

    def score(mesh) -> MeshMetrics:
        return evaluate_mesh(mesh, gt, observed, args.threshold, args.down_sample, trim_gt=not args.no_trim_gt)

    def score_surface(mesh) -> SurfaceMetrics:
        return evaluate_surface(mesh, gt, observed, args.threshold, trim_gt=not args.no_trim_gt)

    rows = {args.pred.name: score(pred)}
    surface_rows = {args.pred.name: score_surface(pred)}
    if args.box_baseline:
        box = room_box_from_tsdf(observed) if observed is not None else fit_room_box(gt.vertices)
        rows["room box baseline"] = score(box)
        surface_rows["room box baseline"] = score_surface(box)
    if args.truth_tsdf:
        if observed is None:
            raise VortxError("--truth-tsdf needs the ground-truth TSDF: give a room folder with tsdf_gt.npz, or --observed")
        reference = truth_tsdf_mesh(observed)
        rows["truth's TSDF meshed"] = score(reference)
        surface_rows["truth's TSDF meshed"] = score_surface(reference)

    trimmed = "none" if observed is None else ("prediction" if args.no_trim_gt else "prediction and ground truth")
    print(f"ground truth: {gt_path}   trimmed to observed voxels: {trimmed}")
    print(f"threshold {args.threshold * 100:g} cm, down-sampling {args.down_sample * 100:g} cm")
    print(format_table(rows))
    print(f"surface ({SURFACE_LEGEND}):")
    print(surface_table(surface_rows))
    depth_rows = {}
    if depth_views is not None:
        meshes = {args.pred.name: pred} | ({"room box baseline": box} if args.box_baseline else {})
        depth_rows = {name: mesh_depth_metrics(m.vertices, m.faces, depth_views) for name, m in meshes.items()}
        print(f"depth metrics over {len(depth_views)} frames (meshes rendered into each frame)")
        print(format_depth_table(depth_rows))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({
            "gt": str(gt_path), "observed": str(observed_path) if observed_path else None,
            "threshold": args.threshold, "down_sample": args.down_sample, "trim_gt": not args.no_trim_gt,
            "results": {name: m.as_dict() for name, m in rows.items()},
            "surface": {name: m.as_dict() for name, m in surface_rows.items()},
            "depth": depth_rows or None,
        }, indent=2))
    return 0


def format_depth_table(rows: dict[str, dict[str, float]]) -> str:
    width = max(len(n) for n in rows) + 2
    lines = ["".ljust(width) + "".join(c.rjust(9) for c in DEPTH_METRIC_NAMES)]
    for name, m in rows.items():
        lines.append(name.ljust(width) + "".join(f"{m[c]:9.4f}" for c in DEPTH_METRIC_NAMES))
    return "\n".join(lines)


def format_table(rows: dict[str, MeshMetrics]) -> str:
    width = max(len(n) for n in rows) + 2
    lines = ["".ljust(width) + "".join(c.rjust(9) for c in COLUMNS) + "   points pred/gt"]
    for name, m in rows.items():
        values = "".join(f"{getattr(m, c):9.4f}" for c in COLUMNS)
        lines.append(name.ljust(width) + values + f"   {m.n_pred}/{m.n_gt}")
    return "\n".join(lines)
