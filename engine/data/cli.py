"""`python -m engine synth --rooms N --out DIR [--seed S] [--frames F] [--resolution WxH] [--renderer R]`.

Renders synthetic rooms with Blender (bpy) into DIR/room_<seed>/ in the ScanNet layout plus ground
truth (mesh_gt.ply, tsdf_gt.npz, room.json). Re-running the same command resumes: complete rooms
are skipped and finished frames of an interrupted room are kept.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import VortxError
from ..jobs import TqdmProgress
from .render import RENDERERS, RenderSettings
from .room import SURFACE_MIXES
from .synth import SynthOptions, synthesize_rooms


def parse_resolution(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 320x240, not {text!r}") from None
    if width < 8 or height < 8:
        raise argparse.ArgumentTypeError("resolution must be at least 8x8")
    return width, height


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rooms", type=int, required=True, help="number of rooms")
    parser.add_argument("--out", type=Path, required=True, help="output folder (one sub-folder per room)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first room; room k uses seed + k")
    parser.add_argument("--frames", type=int, default=100, help="frames per room")
    parser.add_argument("--resolution", type=parse_resolution, default=(320, 240), help="WxH, e.g. 320x240 or 640x480")
    parser.add_argument("--renderer", choices=RENDERERS, default="cycles",
                        help="cycles: photo-like, ~4 s/frame at 320x240 on 2 cores; workbench: textured "
                             "flat shading, ~0.1 s/frame, for bulk data")
    parser.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel")
    parser.add_argument("--no-denoise", action="store_true", help="Cycles: skip OpenImageDenoise (faster, grainier)")
    parser.add_argument("--hfov", type=float, default=60.0, help="horizontal field of view in degrees")
    parser.add_argument("--surfaces", choices=SURFACE_MIXES, default="textured",
                        help="textured: every surface patterned; mixed: also plain painted walls and dark or "
                             "glossy furniture, as real rooms have")
    parser.add_argument("--no-tsdf", action="store_true", help="do not fuse the ground-truth TSDF (tsdf_gt.npz)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.rooms < 1 or args.frames < 1:
        raise VortxError("--rooms and --frames must be at least 1")
    width, height = args.resolution
    settings = RenderSettings(renderer=args.renderer, width=width, height=height, hfov_deg=args.hfov,
                              samples=args.samples, denoise=not args.no_denoise)
    options = SynthOptions(frames=args.frames, render=settings, write_tsdf=not args.no_tsdf,
                           surfaces=args.surfaces)
    progress = TqdmProgress(disable=args.quiet)
    try:
        folders = synthesize_rooms(args.rooms, args.out, options, first_seed=args.seed, progress=progress)
    finally:
        progress.close()
    for folder in folders:
        print(folder)
    return 0
