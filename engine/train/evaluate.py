"""Held-out evaluation of trained weights and the picture for the model card.

For every held-out room (rendered, never used in training): reconstruct it with `engine.recon`
from its colour frames and poses only, then the Atlas metrics (`engine.eval.evaluate_mesh`, trimmed
to the observed ground-truth voxels) against `mesh_gt.ply`; the plain room box fitted to the ground
truth (`engine.eval.room_box_from_tsdf`) is measured the same way as the floor.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..data.room_folders import find_rooms, precompute_room

DEPTH_EVERY = 4  # frames for the depth metrics: every 4th (10 of a rendered room's 40)
DEPTH_KEYS = ("AbsRel", "AbsDiff", "r1", "complete")


def evaluate_rooms(
    rooms: Sequence[Path],
    weights: dict[str, Optional[str]],
    recon_overrides: Optional[dict] = None,
    out_dir: Optional[Path] = None,
    box: bool = True,
) -> dict:
    """weights: label -> weights path. Returns {label: {room: metrics dict}, ...} plus means."""
    from ..capture import load_capture
    from ..eval.depth_metrics import capture_depth_views, mesh_depth_metrics
    from ..eval.mesh_metrics import evaluate_mesh
    from ..eval.room_box import room_box_from_tsdf
    from ..mesh_io import read_ply, write_ply
    from ..recon import reconstruct
    from ..recon.settings import ReconSettings
    from ..tsdf.volume import TsdfVolume

    results: dict = {label: {} for label in weights}
    if box:
        results["room box"] = {}
    for room in map(Path, rooms):
        volume = TsdfVolume.load(precompute_room(room))
        gt = read_ply(room / "mesh_gt.ply")
        capture = load_capture(room)
        depth_views = capture_depth_views(capture, every=DEPTH_EVERY)

        def depth_scores(mesh) -> dict:
            scores = mesh_depth_metrics(mesh.vertices, mesh.faces, depth_views)
            return {k: scores[k] for k in DEPTH_KEYS}

        for label, path in weights.items():
            settings = ReconSettings(weights=str(path) if path else None, **(recon_overrides or {}))
            t0 = time.time()
            res = reconstruct(capture, settings)
            m = evaluate_mesh(res.mesh, gt, observed=volume).as_dict() | depth_scores(res.mesh)
            m["seconds"] = round(time.time() - t0, 1)
            m["faces"] = int(len(res.mesh.faces))
            results[label][room.name] = m
            if out_dir is not None:
                Path(out_dir).mkdir(parents=True, exist_ok=True)
                write_ply(Path(out_dir) / f"{room.name}_{_slug(label)}.ply", res.mesh.vertices, res.mesh.faces)
            print(f"{room.name} {label}: F {m['fscore']:.3f} acc {m['acc']:.3f} comp {m['comp']:.3f}", flush=True)
        if box:
            box_mesh = room_box_from_tsdf(volume)
            m = evaluate_mesh(box_mesh, gt, observed=volume).as_dict() | depth_scores(box_mesh)
            results["room box"][room.name] = m
            print(f"{room.name} room box: F {m['fscore']:.3f}", flush=True)
        if out_dir is not None:  # partial results survive an interrupted run
            save_json({"per_room": results}, Path(out_dir) / "metrics_partial.json")
    summary = {}
    for label, per_room in results.items():
        keys = ("acc", "comp", "prec", "recall", "fscore") + DEPTH_KEYS
        summary[label] = {k: float(np.mean([m[k] for m in per_room.values()])) for k in keys} if per_room else {}
    return {"per_room": results, "mean": summary}


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label)


def metrics_table(result: dict) -> str:
    """Markdown table of the mean metrics."""
    lines = ["| method | F-score | precision | recall | acc (m) | comp (m) | AbsRel | AbsDiff (m) | r1 | depth complete |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for label, m in result["mean"].items():
        if m:
            lines.append(f"| {label} | {m['fscore']:.3f} | {m['prec']:.3f} | {m['recall']:.3f} | "
                         f"{m['acc']:.3f} | {m['comp']:.3f} | {m['AbsRel']:.3f} | {m['AbsDiff']:.3f} | "
                         f"{m['r1']:.3f} | {m['complete']:.3f} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Picture: shaded renders of meshes side by side (numpy rasteriser engine.geometry.depth_render)


def shade(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Grey-shaded uint8 image of a depth map (normals from depth gradients, headlight)."""
    h, w = depth.shape
    valid = np.isfinite(depth)
    d = np.where(valid, depth, 0.0)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], -1)
    dx = np.gradient(pts, axis=1)
    dy = np.gradient(pts, axis=0)
    n = np.cross(dx, dy)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
    light = np.abs(n[..., 2])
    img = (40 + 200 * light).clip(0, 255)
    img[~valid] = 255
    return img.astype(np.uint8)


def render_side_by_side(meshes: Sequence, labels: Sequence[str], out_path: Path, size=(320, 240),
                        clip_above: Optional[float] = None) -> Path:
    """One elevated view of each mesh (same camera), ceilings clipped, written as one PNG."""
    import cv2

    from ..meshops import subdivide
    from ..geometry.cameras import look_at
    from ..geometry.depth_render import render_depth

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


def ship_weights(src: Path, dst: Path, half: bool = True, config_changes: dict | None = None) -> Path:
    """Copy trained weights to the shipped location (safetensors + JSON sidecar), optionally with
    floating-point tensors stored as float16 (half the size; they load back into float32) and
    inference-only config fields changed (e.g. {"sparse_norm_statistics": "scene"})."""
    import dataclasses

    from safetensors import safe_open
    from safetensors.torch import save_file

    from ..model.weights import CONFIG_KEY, FORMAT, FORMAT_KEY, read_config, sidecar_path

    config = dataclasses.replace(read_config(src), **(config_changes or {}))
    tensors = {}
    with safe_open(str(src), framework="pt") as f:
        for key in f.keys():
            t = f.get_tensor(key)
            tensors[key] = t.half() if half and t.is_floating_point() else t
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(dst), metadata={FORMAT_KEY: FORMAT, CONFIG_KEY: config.to_json()})
    sidecar_path(dst).write_text(config.to_json() + "\n")
    return dst


def main(argv=None) -> int:
    """python -m engine.train.evaluate --rooms DIR --weights LABEL=PATH ... [--picture PNG]"""
    import argparse

    ap = argparse.ArgumentParser(description="held-out evaluation of trained VoRTX weights")
    ap.add_argument("--rooms", nargs="+", required=True)
    ap.add_argument("--weights", nargs="+", required=True, help="LABEL=PATH")
    ap.add_argument("--out", default="runs/eval")
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--frustum-depth", type=float, default=3.0)
    ap.add_argument("--max-room-size", type=float, nargs=3, default=[7.0, 7.0, 3.5])
    ap.add_argument("--no-box", action="store_true", help="skip the room-box baseline")
    ap.add_argument("--picture", default=None, help="PNG: first room, first weights vs ground truth")
    args = ap.parse_args(argv)
    weights = dict(w.split("=", 1) for w in args.weights)
    rooms = find_rooms(args.rooms)
    overrides = dict(image_long_side=args.image_size, views=args.views, frustum_depth=args.frustum_depth,
                     max_room_size=tuple(args.max_room_size))
    out = Path(args.out)
    result = evaluate_rooms(rooms, weights, overrides, out_dir=out, box=not args.no_box)
    result["settings"] = overrides
    save_json(result, out / "metrics.json")
    print(metrics_table(result))
    if args.picture:
        from ..mesh_io import read_ply

        room = rooms[0]
        label = next(iter(weights))
        pred = read_ply(out / f"{room.name}_{_slug(label)}.ply")
        gt = read_ply(room / "mesh_gt.ply")
        render_side_by_side([pred, gt], [f"{label} ({room.name})", "ground truth"], Path(args.picture))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
