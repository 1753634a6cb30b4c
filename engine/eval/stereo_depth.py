"""`python -m engine eval-depth ROOM [ROOM ...]`: the stereo depth maps against the rooms' true depth.

The reconstruction's own stereo depth maps (the same keyframes, references, sources and options as
`engine reconstruct --method stereo`, from the photos and poses only) are compared with each reference
frame's true depth (a rendered room's exact depth, or a sensor's registered depth), resampled to the
stereo resolution. The poses are those the product itself would use: given poses that the check
against the photos finds off are refined first, as `engine reconstruct` does (`--keep-poses` uses them
as given). Per map, then averaged over maps:

- `median_rel`: median of |d - t| / t over pixels where stereo gave a depth and the truth has one;
- `within_5pct`: share of those pixels with |d - t| / t < 5 %;
- `complete`: share of the pixels with a true depth where stereo gave a depth;
- `normals_30deg`: share of pixels (with stereo, true and neighbouring depths) whose normal from the
  stereo depth is within 30 degrees of the normal from the true depth (random orientations give
  ~13 %: 1 - cos 30deg);
- `scale`: median of d / t (1 for metric depth; a pose scale off by a few per cent moves it, and every
  depth with it);
- `within_5pct_scaled`: `within_5pct` after dividing the map by its `scale`: how well the matcher did,
  apart from the scale the poses gave it;
- confidence calibration: the median relative error in each confidence quartile (highest last
  should be lowest) and Spearman's rank correlation of confidence with the error (negative = calibrated).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..capture import load_capture, load_depth
from ..data.room_folders import find_rooms
from ..errors import VortxError
from ..geometry.depth_normals import depth_normals
from ..poses.prepare import SFM_NEVER, prepare_capture
from ..recon.driver import resolve_device
from ..recon.plan import plan_reconstruction
from ..recon.settings import ReconSettings, add_setting_arguments, settings_from_arguments
from ..recon.stereo_fusion import stereo_depth_maps, stereo_options

WITHIN = 0.05
NORMAL_ANGLE_DEG = 30.0
KEYS = ("median_rel", "within_5pct", "complete", "normals_30deg", "scale", "within_5pct_scaled")


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    if len(a) < 3:
        return float("nan")
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def compare_depth(depth: np.ndarray, confidence: np.ndarray, true: np.ndarray, K: np.ndarray) -> dict:
    """The metrics above for one stereo map against its true depth at the same size (0 = missing)."""
    has_true = true > 0
    both = has_true & (depth > 0)
    out: dict = {"complete": float(both.sum() / max(1, has_true.sum()))}
    if not both.any():
        return {**out, "median_rel": float("nan"), "within_5pct": float("nan"), "normals_30deg": float("nan"),
                "scale": float("nan"), "within_5pct_scaled": float("nan"),
                "confidence_quartiles": [float("nan")] * 4, "confidence_spearman": float("nan")}
    rel = np.abs(depth[both] - true[both]) / true[both]
    out["median_rel"] = float(np.median(rel))
    out["within_5pct"] = float(np.mean(rel < WITHIN))
    scale = float(np.median(depth[both] / true[both]))
    out["scale"] = scale
    out["within_5pct_scaled"] = float(np.mean(np.abs(depth[both] / scale - true[both]) / true[both] < WITHIN))
    n_pred, ok_pred = depth_normals(depth, K)
    n_true, ok_true = depth_normals(true, K)
    ok = ok_pred & ok_true
    cos = np.abs(np.sum(n_pred * n_true, axis=-1))[ok]
    out["normals_30deg"] = float(np.mean(cos >= np.cos(np.radians(NORMAL_ANGLE_DEG)))) if len(cos) else float("nan")
    conf = confidence[both]
    edges = np.quantile(conf, [0.25, 0.5, 0.75])
    bins = np.digitize(conf, edges)
    out["confidence_quartiles"] = [float(np.median(rel[bins == q])) if np.any(bins == q) else float("nan") for q in range(4)]
    out["confidence_spearman"] = spearman(conf, rel)
    return out


def true_depth_at(frame, size: tuple[int, int]) -> np.ndarray:
    """The frame's true depth resized to (w, h) by nearest neighbour (no mixing across edges)."""

    depth = load_depth(frame.depth_path).astype(np.float32)
    return cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)


def evaluate_room_depth(room: Path, settings=None, keep_poses: bool = False, progress=None) -> dict:
    """Stereo depth metrics of one room: per reference frame and their mean, with the poses the
    product would use (refined when the photo check finds them off, unless `keep_poses`)."""

    settings = settings or ReconSettings()
    given = load_capture(room)
    # The world may turn (Z up) but stays metric, and each map is compared in its own camera: the
    # prepared capture's frames are the room's, in order.
    prepared = prepare_capture(given, sfm=SFM_NEVER, check_poses=not keep_poses, refine_when_off=not keep_poses,
                               progress=progress)
    capture = prepared.capture
    plan = plan_reconstruction(capture, settings)
    maps = stereo_depth_maps(capture, plan, stereo_options(settings, resolve_device(settings.device)))
    rows = []
    for m in maps:
        frame = capture.frames[plan.keyframe_ids[m.frame]]
        if frame.depth_path is None:
            raise VortxError(f"{room}: frame {frame.name} has no depth map to compare with")
        true = true_depth_at(frame, (m.depth.shape[1], m.depth.shape[0]))
        rows.append({"frame": frame.name, **compare_depth(m.depth, m.confidence, true, m.K)})
    mean = {k: float(np.nanmean([r[k] for r in rows])) for k in KEYS}
    mean["confidence_quartiles"] = [float(np.nanmean([r["confidence_quartiles"][q] for r in rows])) for q in range(4)]
    mean["confidence_spearman"] = float(np.nanmean([r["confidence_spearman"] for r in rows]))
    return {"room": str(room), "maps": len(rows), "mean": mean, "frames": rows, "poses": prepared.summary()}


def format_rows(results: Sequence[dict]) -> str:
    head = (f"{'room':<28} {'maps':>5} {'med.rel':>8} {'<5%':>6} {'compl.':>7} {'n<30deg':>8} {'scale':>6} "
            f"{'<5%@s':>6} {'conf.rho':>9}  err by conf. quartile")
    lines = [head, "-" * len(head)]
    for r in results:
        m = r["mean"]
        quart = " ".join(f"{q:.3f}" for q in m["confidence_quartiles"])
        lines.append(f"{Path(r['room']).name[:28]:<28} {r['maps']:>5} {m['median_rel']:>8.3f} {m['within_5pct']:>6.3f} "
                     f"{m['complete']:>7.3f} {m['normals_30deg']:>8.3f} {m['scale']:>6.3f} {m['within_5pct_scaled']:>6.3f} "
                     f"{m['confidence_spearman']:>9.3f}  {quart}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("rooms", nargs="+", type=Path, help="room folders with true depth (rendered rooms, the SUN3D "
                        "room of scripts/sun3d_room.py, ScanNet-layout scenes), or folders of them")
    parser.add_argument("--json", type=Path, help="write the per-frame and mean metrics here")
    parser.add_argument("--keep-poses", action="store_true",
                        help="use the rooms' poses as given (default: refined first when the check against the photos "
                             "finds them off, as engine reconstruct does)")
    add_setting_arguments(parser)


def run(args: argparse.Namespace) -> int:
    settings = settings_from_arguments(args, method="stereo")
    results = [evaluate_room_depth(room, settings, keep_poses=args.keep_poses) for room in find_rooms(args.rooms)]
    print(format_rows(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


def main(argv: Optional[list[str]] = None) -> int:  # for tests: the same as `python -m engine eval-depth`
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return run(parser.parse_args(argv))
