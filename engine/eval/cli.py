"""`python -m engine eval PRED.ply GT.ply|ROOM_DIR [--observed TSDF.npz] [--json out.json]`.

Prints the Atlas metrics table for the prediction and, with --box-baseline, for the room box fitted
to the ground truth (the floor a real result must beat).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import VortxError
from ..mesh_io import read_ply
from ..tsdf.volume import TsdfVolume
from .mesh_metrics import MeshMetrics, evaluate_mesh
from .room_box import fit_room_box, room_box_from_tsdf

COLUMNS = ("acc", "comp", "prec", "recall", "fscore")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("pred", type=Path, help="predicted mesh (.ply), world metres")
    parser.add_argument("gt", type=Path, help="ground-truth mesh (.ply), or a synthetic room folder "
                        "(uses its mesh_gt.ply and, unless --observed is given, its tsdf_gt.npz)")
    parser.add_argument("--observed", type=Path, help="ground-truth TSDF (.npz): trim to its observed voxels")
    parser.add_argument("--no-trim-gt", action="store_true", help="trim only the prediction (Atlas does "
                        "not trim its scanned ground truth; our synthetic ground truth is the whole scene)")
    parser.add_argument("--threshold", type=float, default=0.05, help="precision/recall distance (m)")
    parser.add_argument("--down-sample", type=float, default=0.02, help="voxel down-sampling size (m)")
    parser.add_argument("--box-baseline", action="store_true", help="also score a plain box room fitted to the ground truth")
    parser.add_argument("--json", type=Path, help="write the metrics here as JSON")


def run(args: argparse.Namespace) -> int:
    gt_path, observed_path = args.gt, args.observed
    if gt_path.is_dir():
        room = gt_path
        gt_path = room / "mesh_gt.ply"
        if observed_path is None and (room / "tsdf_gt.npz").is_file():
            observed_path = room / "tsdf_gt.npz"
    for path in (args.pred, gt_path) + ((observed_path,) if observed_path else ()):
        if not path.is_file():
            raise VortxError(f"{path}: file not found")
    try:
        pred, gt = read_ply(args.pred), read_ply(gt_path)
    except (ValueError, KeyError) as error:
        raise VortxError(f"cannot read mesh: {error}") from error
    observed = TsdfVolume.load(observed_path) if observed_path else None

    def score(mesh) -> MeshMetrics:
        return evaluate_mesh(mesh, gt, observed, args.threshold, args.down_sample, trim_gt=not args.no_trim_gt)

    rows = {args.pred.name: score(pred)}
    if args.box_baseline:
        box = room_box_from_tsdf(observed) if observed is not None else fit_room_box(gt.vertices)
        rows["room box baseline"] = score(box)

    trimmed = "none" if observed is None else ("prediction" if args.no_trim_gt else "prediction and ground truth")
    print(f"ground truth: {gt_path}   trimmed to observed voxels: {trimmed}")
    print(f"threshold {args.threshold * 100:g} cm, down-sampling {args.down_sample * 100:g} cm")
    print(format_table(rows))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({
            "gt": str(gt_path), "observed": str(observed_path) if observed_path else None,
            "threshold": args.threshold, "down_sample": args.down_sample, "trim_gt": not args.no_trim_gt,
            "results": {name: m.as_dict() for name, m in rows.items()},
        }, indent=2))
    return 0


def format_table(rows: dict[str, MeshMetrics]) -> str:
    width = max(len(n) for n in rows) + 2
    lines = ["".ljust(width) + "".join(c.rjust(9) for c in COLUMNS) + "   points pred/gt"]
    for name, m in rows.items():
        values = "".join(f"{getattr(m, c):9.4f}" for c in COLUMNS)
        lines.append(name.ljust(width) + values + f"   {m.n_pred}/{m.n_gt}")
    return "\n".join(lines)
