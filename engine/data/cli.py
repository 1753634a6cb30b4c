"""`python -m engine synth --rooms N --out DIR [--seed S] [--frames F] [--resolution WxH] [--renderer R]
[--realism clean|real]` or `python -m engine synth --heldout-set realistic|clean --out DIR`.

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
from .room import CLUTTER_LEVELS, SURFACE_MIXES
from .synth import DEV_ROOM_SETS, REALISM, dev_room_set, realism_options, synthesize_rooms


def parse_resolution(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 320x240, not {text!r}") from None
    if width < 8 or height < 8:
        raise argparse.ArgumentTypeError("resolution must be at least 8x8")
    return width, height


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rooms", type=int, help="number of rooms (required unless --heldout-set)")
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
    parser.add_argument("--realism", choices=REALISM, default="clean",
                        help="clean: the render as it is; real: photos as a camera takes them (motion blur, "
                             "rolling focus, exposure and white-balance drift, sensor noise, JPEG 75-90), poses "
                             "with 0.5-2 deg / 1-3 cm errors (true ones in pose_true/), and unless set below: "
                             "mixed surfaces, dense clutter, half of the rooms in Cycles")
    parser.add_argument("--surfaces", choices=SURFACE_MIXES, default=None,
                        help="textured (clean default): every surface patterned; mixed (real default): also "
                             "plain painted walls and dark or glossy furniture, as real rooms have")
    parser.add_argument("--clutter", choices=CLUTTER_LEVELS, default=None,
                        help="normal (clean default): a few items on tables; dense (real default): more on "
                             "tables and cabinets and small things on the floor")
    parser.add_argument("--cycles-share", type=float, default=None,
                        help="share of rooms rendered with Cycles whatever --renderer says (0-1; clean "
                             "default 0, real default 0.5)")
    parser.add_argument("--heldout-set", choices=DEV_ROOM_SETS, default=None,
                        help="render a fixed held-out development set (4 rooms, seeds 5001-5004, 40 frames, "
                             "320x240) into --out; the other options are fixed by the set")
    parser.add_argument("--no-tsdf", action="store_true", help="do not fuse the ground-truth TSDF (tsdf_gt.npz)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.heldout_set is not None:
        chosen = [flag for flag, value in (("--rooms", args.rooms), ("--surfaces", args.surfaces),
                                           ("--clutter", args.clutter), ("--cycles-share", args.cycles_share))
                  if value is not None] + (["--realism"] if args.realism != "clean" else [])
        if chosen:
            raise VortxError(f"--heldout-set {args.heldout_set} fixes the rooms and their options; drop "
                             f"{', '.join(chosen)} (or drop --heldout-set to choose them)")
        first_seed, rooms, options = dev_room_set(args.heldout_set)
    else:
        if args.rooms is None:
            raise VortxError("--rooms is required (or --heldout-set realistic|clean for a fixed set)")
        if args.rooms < 1 or args.frames < 1:
            raise VortxError("--rooms and --frames must be at least 1")
        if args.cycles_share is not None and not 0.0 <= args.cycles_share <= 1.0:
            raise VortxError(f"--cycles-share must be within 0..1, not {args.cycles_share}")
        width, height = args.resolution
        settings = RenderSettings(renderer=args.renderer, width=width, height=height, hfov_deg=args.hfov,
                                  samples=args.samples, denoise=not args.no_denoise)
        chosen = {k: v for k, v in (("surfaces", args.surfaces), ("clutter", args.clutter),
                                    ("cycles_share", args.cycles_share)) if v is not None}
        options = realism_options(args.realism, frames=args.frames, render=settings, write_tsdf=not args.no_tsdf,
                                  **chosen)
        first_seed, rooms = args.seed, args.rooms
    progress = TqdmProgress(disable=args.quiet)
    try:
        folders = synthesize_rooms(rooms, args.out, options, first_seed=first_seed, progress=progress)
    finally:
        progress.close()
    for folder in folders:
        print(folder)
    return 0
