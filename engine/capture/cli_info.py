"""`python -m engine info CAPTURE [--json]`: what the engine sees in a capture.

Loads the capture exactly as the pipeline would (so video frames are extracted and distorted photos
undistorted into the cache, once) and prints its format, frames, resolution, poses, intrinsics,
scale and warnings. Errors exit 1 with `error: ...` through the dispatcher.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from .detect import FORMATS
from .load import load_capture
from .model import Capture


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="photo folder, COLMAP/ScanNet/transforms.json folder, video file, or a "
                        "phone app's export (3D Scanner App, Stray Scanner, Record3D, Polycam: folder, .zip or .r3d)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--format", choices=FORMATS, help="skip detection and read the capture as this format")
    parser.add_argument("--fps", type=float, default=2.0, help="video: frames extracted per second (default 2)")
    parser.add_argument("--metric", action=argparse.BooleanOptionalAction, default=None,
                        help="override whether the poses are in metres (default: what the format says)")
    parser.add_argument("--no-undistort", dest="undistort", action="store_false",
                        help="keep distorted photos as they are instead of undistorting them into the cache")
    parser.add_argument("--cache-dir", type=Path, help="where extracted/undistorted images go "
                        "(default: the per-user cache, e.g. ~/.cache/vortx/)")
    parser.add_argument("--images-dir", type=Path, help="COLMAP: folder holding the photos, if not images/")


def describe(capture: Capture) -> dict[str, Any]:
    """JSON-serialisable summary of a capture (what `--json` prints)."""
    frames = capture.frames
    width, height = capture.resolution
    with_K = [f for f in frames if f.K is not None]
    shared_K = None
    if with_K and len(with_K) == len(frames) and all(np.allclose(f.K, with_K[0].K) for f in with_K):
        K = with_K[0].K
        shared_K = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    return {
        "path": str(capture.root),
        "format": capture.format,
        "frames": len(frames),
        "width": width,
        "height": height,
        "posed_frames": len(capture.posed_frames),
        "frames_with_intrinsics": len(with_K),
        "intrinsics": shared_K,
        "frames_with_depth": sum(f.depth_path is not None for f in frames),
        "frames_with_sensor_depth": capture.frames_with_sensor_depth,
        "pose_origin": capture.pose_origin,
        "points": 0 if capture.points is None else int(len(capture.points)),
        "metric": capture.metric,
        "first_image": str(frames[0].image_path) if frames else None,
        "warnings": list(capture.warnings),
        "notes": list(capture.notes),
    }


def format_text(summary: dict[str, Any]) -> str:
    """Human-readable lines of `describe`'s summary."""
    frames = summary["frames"]
    if summary["frames_with_intrinsics"] == 0:
        intrinsics = "unknown (estimated with the poses)"
    elif summary["intrinsics"] is not None:
        k = summary["intrinsics"]
        intrinsics = f"known, shared: fx {k['fx']:.2f}  fy {k['fy']:.2f}  cx {k['cx']:.2f}  cy {k['cy']:.2f}"
    else:
        intrinsics = f"known for {summary['frames_with_intrinsics']} of {frames} frames"
    lines = [
        f"capture     {summary['path']}",
        f"format      {summary['format']}",
        f"frames      {frames}",
        f"resolution  {summary['width']} x {summary['height']}",
        f"poses       {summary['posed_frames']} of {frames} frames"
        + (f", {summary['pose_origin']}" if summary["pose_origin"] else ""),
        f"intrinsics  {intrinsics}",
        f"metric      {'yes (metres)' if summary['metric'] else 'no (scale set by the poses stage)'}",
    ]
    if summary["frames_with_depth"]:
        lines.append(f"depth       {summary['frames_with_depth']} of {frames} frames (ground truth, not an input)")
    if summary["frames_with_sensor_depth"]:
        lines.append(f"sensor      depth maps for {summary['frames_with_sensor_depth']} of {frames} frames "
                     "(used by the reconstruction)")
    if summary["points"]:
        lines.append(f"points      {summary['points']}" + (" (from the sensor depth)" if summary["frames_with_sensor_depth"] else ""))
    for note in summary["notes"]:
        lines.append(f"note        {note}")
    lines.append(f"warnings    {len(summary['warnings'])}")
    lines += [f"  - {warning}" for warning in summary["warnings"]]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    capture = load_capture(args.capture, format=args.format, fps=args.fps, metric=args.metric,
                           undistort=args.undistort, cache_dir=args.cache_dir, images_dir=args.images_dir)
    summary = describe(capture)
    print(json.dumps(summary, indent=2) if args.json else format_text(summary))
    return 0
