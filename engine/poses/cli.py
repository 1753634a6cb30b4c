"""`python -m engine poses CAPTURE --out DIR`: estimate camera poses and write the posed capture.

With `--refine`, the capture's own poses (tracker, ARKit, SLAM, RGB-D rig) are kept as the starting
point and refined against the photos instead (`refine.py`); the report gives each frame's change
(median and max) and the frames refused.

The output folder is a ScanNet-layout capture (color/, pose/, intrinsic/) plus a COLMAP text model
in colmap/ (with the sparse points), so both this engine and other tools can read the result.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..capture import load_capture
from ..capture.writers import write_colmap_text, write_scannet
from ..errors import PoseError
from ..jobs import TqdmProgress
from .camera_height import DEFAULT_CAMERA_HEIGHT_M
from .gravity import KnownDistance
from .prepare import SFM_ALWAYS, SFM_NEVER, prepare_capture
from .refine import RefineOptions
from .sfm import INTRINSICS, MATCHERS, SfmOptions, add_features_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="capture folder (photos, COLMAP, transforms.json, ScanNet) or video")
    parser.add_argument("--images-dir", type=Path, help="COLMAP model: the folder holding its photos, when they are not in images/ beside it")
    parser.add_argument("--out", type=Path, required=True, help="output folder (ScanNet layout + colmap/)")
    parser.add_argument("--refine", action="store_true",
                        help="refine the capture's own poses against the photos instead of estimating new ones "
                             "(for slightly-off tracker, ARKit or SLAM poses)")
    parser.add_argument("--matcher", choices=MATCHERS, default="auto",
                        help="feature matching: exhaustive for small photo sets, sequential for video (default: auto)")
    add_features_argument(parser)
    parser.add_argument("--max-side", type=int, default=None,
                        help=f"downscale photos to this larger side for SfM (default {SfmOptions.max_side}) or refinement "
                             f"(default {RefineOptions.max_side}); 0 = full size")
    parser.add_argument("--intrinsics", choices=INTRINSICS, default="auto",
                        help="fixed: trust the capture's K; prior: refine it; estimate: ignore it (default: auto)")
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="camera height above the floor in metres, sets the scale (default %(default)s)")
    parser.add_argument("--known-distance", nargs=3, metavar=("FRAME_A", "FRAME_B", "METRES"),
                        help="set the scale from the distance between the cameras of two photos (file names)")
    parser.add_argument("--overwrite", action="store_true", help="replace a capture already in --out")
    parser.add_argument("--work-dir", type=Path, default=None,
                        help="keep COLMAP's database, models and log here (default: a temporary folder)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def _known_distance(values: list[str] | None) -> KnownDistance | None:
    if values is None:
        return None
    frame_a, frame_b, metres = values
    try:
        distance = float(metres)
    except ValueError as error:
        raise PoseError(f"--known-distance: {metres!r} is not a number of metres") from error
    return KnownDistance(frame_a, frame_b, distance)


def run(args: argparse.Namespace) -> int:
    if args.refine and args.features != SfmOptions.features:
        raise PoseError(f"--features {args.features} is for structure from motion; --refine refines the given poses "
                        "with SIFT, whose keypoints are the more precise (drop --features, or --refine)")
    known_distance = _known_distance(args.known_distance)
    sizes = {} if args.max_side is None else {"max_side": args.max_side}
    options = SfmOptions(matcher=args.matcher, intrinsics=args.intrinsics, work_dir=args.work_dir, features=args.features,
                         **sizes)
    refine_options = RefineOptions(work_dir=args.work_dir, **sizes)
    progress = TqdmProgress(disable=args.quiet)
    try:
        capture = load_capture(args.capture, progress=progress, images_dir=args.images_dir)
        for warning in capture.warnings:
            print(f"warning: {warning}")
        already = len(capture.posed_frames)
        if args.refine and len(capture.posed_frames) < 3:
            raise PoseError(f"--refine refines the poses a capture has, and {capture.root} has poses for {already} of "
                            f"{len(capture.frames)} frames (at least 3 needed); run without --refine to estimate "
                            "poses with structure from motion")
        if already and not args.refine:
            print(f"note: {capture.root} already has poses for {already} of {len(capture.frames)} frames; "
                  "structure from motion replaces them (--refine keeps and refines them)")
        prepared = prepare_capture(capture, camera_height=args.camera_height, known_distance=known_distance,
                                   sfm=SFM_NEVER if args.refine else SFM_ALWAYS, sfm_options=options,
                                   refine=args.refine, refine_options=refine_options, progress=progress)
        written = write_scannet(prepared.capture, args.out, overwrite=args.overwrite)
        write_colmap_text(written, args.out / "colmap", prepared.points, prepared.point_colors)
    finally:
        progress.close()
    print("\n".join(prepared.report_lines))
    if prepared.sfm is None:  # the SfM report lists its own warnings
        for warning in prepared.warnings:
            print(f"warning: {warning}")
    print(f"wrote {len(written.frames)} posed photos to {args.out} (ScanNet layout) and a COLMAP text model "
          f"to {args.out / 'colmap'}")
    return 0
