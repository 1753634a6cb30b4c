"""`python -m engine eval-weights`: held-out evaluation of trained weights and the picture for the model card.

For every held-out room (rendered, never used in training): reconstruct it with `engine.recon`
from its colour frames and poses only, then the Atlas metrics (`engine.eval.evaluate_mesh`, trimmed
to the observed ground-truth voxels) against `mesh_gt.ply`; the plain room box fitted to the ground
truth (`engine.eval.room_box_from_tsdf`) is measured the same way as the floor. Beside them, per room
and as means, the surface metrics (`engine/eval/surface_metrics.py`: normal agreement, floater share,
pieces, area ratio, open boundary per m^2; the first two trimmed the same way). A weights entry whose path is
`stereo` scores the classical stereo-fusion method (no network) beside them.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..capture import load_capture
from ..data.room_folders import find_rooms, precompute_room, with_true_poses
from ..errors import VortxError
from ..eval.depth_metrics import capture_depth_views, mesh_depth_metrics
from ..eval.mesh_metrics import evaluate_mesh
from ..eval.room_box import room_box_from_tsdf
from ..eval.surface_metrics import evaluate_surface
from ..geometry.cameras import look_at
from ..geometry.depth_render import render_depth, shade
from ..mesh_io import read_ply, write_ply
from ..meshops import subdivide
from .. import recon  # recon.reconstruct looked up at call time: tests stand in for it
from ..recon.settings import ReconSettings
from ..tsdf.volume import TsdfVolume
from .surface_metrics import SURFACE_KEYS, surface_cells, surface_headings

DEPTH_EVERY = 4  # frames for the depth metrics: every 4th (10 of a rendered room's 40)
DEPTH_KEYS = ("AbsRel", "AbsDiff", "r1", "complete")
STEREO_METHOD = "stereo"  # a --weights PATH that means "the classical stereo method"
MESH_KEYS = ("acc", "comp", "prec", "recall", "fscore")


def evaluate_rooms(
    rooms: Sequence[Path],
    weights: dict[str, Optional[str]],
    recon_overrides: Optional[dict] = None,
    out_dir: Optional[Path] = None,
    box: bool = True,
) -> dict:
    """weights: label -> weights path, or STEREO_METHOD for classical stereo fusion.
    Returns {label: {room: metrics dict}, ...} plus means."""
    results: dict = {label: {} for label in weights}
    if box:
        results["room box"] = {}
    for room in map(Path, rooms):
        volume = TsdfVolume.load(precompute_room(room))
        gt = read_ply(room / "mesh_gt.ply")
        capture = load_capture(room)
        # Methods get the room's poses (with errors in a "real" room); the rendered depth is scored
        # from the poses it was rendered from.
        depth_views = capture_depth_views(with_true_poses(capture), every=DEPTH_EVERY)

        def depth_scores(mesh) -> dict:
            scores = mesh_depth_metrics(mesh.vertices, mesh.faces, depth_views)
            return {k: scores[k] for k in DEPTH_KEYS}

        for label, path in weights.items():
            if path == STEREO_METHOD:
                settings = ReconSettings(method="stereo", **(recon_overrides or {}))
            else:  # the method is explicit: stereo is the product's default
                settings = ReconSettings(method="vortx", weights=str(path) if path else None, **(recon_overrides or {}))
            t0 = time.time()
            res = recon.reconstruct(capture, settings)
            m = (evaluate_mesh(res.mesh, gt, observed=volume).as_dict() | depth_scores(res.mesh)
                 | evaluate_surface(res.mesh, gt, observed=volume).as_dict())
            m["seconds"] = round(time.time() - t0, 1)
            m["faces"] = int(len(res.mesh.faces))
            results[label][room.name] = m
            if out_dir is not None:
                Path(out_dir).mkdir(parents=True, exist_ok=True)
                write_ply(Path(out_dir) / f"{room.name}_{_slug(label)}.ply", res.mesh.vertices, res.mesh.faces)
            print(f"{room.name} {label}: F {m['fscore']:.3f} acc {m['acc']:.3f} comp {m['comp']:.3f} "
                  f"{_surface_summary(m)}", flush=True)
        if box:
            box_mesh = room_box_from_tsdf(volume)
            m = (evaluate_mesh(box_mesh, gt, observed=volume).as_dict() | depth_scores(box_mesh)
                 | evaluate_surface(box_mesh, gt, observed=volume).as_dict())
            results["room box"][room.name] = m
            print(f"{room.name} room box: F {m['fscore']:.3f} {_surface_summary(m)}", flush=True)
        if out_dir is not None:  # partial results survive an interrupted run
            save_json({"per_room": results}, Path(out_dir) / "metrics_partial.json")
    summary = {}
    for label, per_room in results.items():
        keys = MESH_KEYS + DEPTH_KEYS + SURFACE_KEYS
        summary[label] = {k: float(np.mean([m[k] for m in per_room.values()])) for k in keys} if per_room else {}
    return {"per_room": results, "mean": summary}


def _surface_summary(m: dict) -> str:
    cells = surface_cells(m)
    return ", ".join(f"{heading} {cell}" for heading, cell in zip(surface_headings(), cells))


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label)


def metrics_table(result: dict) -> str:
    """Markdown table of the mean metrics (the surface metrics' columns as surface_metrics names them)."""
    lines = ["| method | F-score | precision | recall | acc (m) | comp (m) | AbsRel | AbsDiff (m) | r1 | depth complete | "
             + " | ".join(surface_headings()) + " |",
             "|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(SURFACE_KEYS)]
    for label, m in result["mean"].items():
        if m:
            lines.append(f"| {label} | {m['fscore']:.3f} | {m['prec']:.3f} | {m['recall']:.3f} | "
                         f"{m['acc']:.3f} | {m['comp']:.3f} | {m['AbsRel']:.3f} | {m['AbsDiff']:.3f} | "
                         f"{m['r1']:.3f} | {m['complete']:.3f} | " + " | ".join(surface_cells(m)) + " |")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Picture: shaded renders of meshes side by side (numpy rasteriser engine.geometry.depth_render)


def render_side_by_side(meshes: Sequence, labels: Sequence[str], out_path: Path, size=(320, 240),
                        clip_above: Optional[float] = None) -> Path:
    """One elevated view of each mesh (same camera), ceilings clipped, written as one PNG."""
    ref = np.asarray(meshes[-1].vertices, np.float64)
    lo, hi = ref.min(0), ref.max(0)
    center = (lo + hi) / 2
    top = hi[2] - 0.3 if clip_above is None else clip_above
    eye = center + np.array([-(hi[0] - lo[0]) * 0.45, -(hi[1] - lo[1]) * 0.75, (hi[2] - lo[2]) * 1.6])
    pose = look_at(eye, center - np.array([0, 0, 0.5]))
    w, h = size
    K = np.array([[0.75 * w, 0, w / 2], [0, 0.75 * w, h / 2], [0, 0, 1.0]])
    panels = []
    for mesh, label in zip(meshes, labels):
        v = np.asarray(mesh.vertices, np.float64)
        f = np.asarray(mesh.faces)
        keep = (v[f][:, :, 2] < top).all(1)  # drop the ceiling so the room is visible from above
        if keep.any():
            sv, sf = subdivide(v, f[keep])
            depth = render_depth(sv, sf, K, pose, size)
        else:
            depth = np.full((h, w), np.inf, np.float32)
        img = cv2.cvtColor(shade(depth, K), cv2.COLOR_GRAY2BGR)
        cv2.putText(img, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (20, 20, 160), 1, cv2.LINE_AA)
        panels.append(img)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out_path), np.concatenate(panels, 1), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return out_path


def save_json(obj: dict, path: Path) -> None:
    Path(path).write_text(json.dumps(obj, indent=2))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rooms", nargs="+", required=True, help="held-out room folders, or folders holding them")
    parser.add_argument("--weights", nargs="+", required=True,
                        help="LABEL=PATH (.safetensors); PATH may be 'random', or 'stereo' for classical stereo fusion")
    parser.add_argument("--out", default="runs/eval", help="folder for metrics.json and the predicted meshes")
    parser.add_argument("--image-size", type=int, default=128, help="reconstruction image long side (pixels)")
    parser.add_argument("--views", type=int, default=12, help="views per tile")
    parser.add_argument("--frustum-depth", type=float, default=3.0, help="scene bounds: frusta cut at this depth (m)")
    parser.add_argument("--max-room-size", type=float, nargs=3, default=[7.0, 7.0, 3.5], help="clip the bounds (m)")
    parser.add_argument("--no-box", action="store_true", help="skip the room-box baseline")
    parser.add_argument("--picture", default=None, help="PNG: first room, first weights vs ground truth")


def run(args: argparse.Namespace) -> int:
    """`python -m engine eval-weights --rooms DIR --weights LABEL=PATH ... [--picture PNG]`."""
    bad = [w for w in args.weights if "=" not in w]
    if bad:
        raise VortxError(f"--weights takes LABEL=PATH, got {', '.join(bad)}")
    weights = dict(w.split("=", 1) for w in args.weights)
    rooms = find_rooms(args.rooms)
    if not rooms:
        raise VortxError(f"no room folders found in {', '.join(args.rooms)}")
    overrides = dict(image_long_side=args.image_size, views=args.views, frustum_depth=args.frustum_depth,
                     max_room_size=tuple(args.max_room_size))
    out = Path(args.out)
    result = evaluate_rooms(rooms, weights, overrides, out_dir=out, box=not args.no_box)
    result["settings"] = overrides
    save_json(result, out / "metrics.json")
    print(metrics_table(result))
    if args.picture:
        room = rooms[0]
        label = next(iter(weights))
        pred = read_ply(out / f"{room.name}_{_slug(label)}.ply")
        gt = read_ply(room / "mesh_gt.ply")
        render_side_by_side([pred, gt], [f"{label} ({room.name})", "ground truth"], Path(args.picture))
    return 0
