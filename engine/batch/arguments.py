"""The batch's command line (scripts/vortx_batch.py): its flags and the checks that refuse a bad
combination before anything runs (argparse's exit status 2)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from ..poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from ..poses.prepare import KEEP_POSES_HELP
from ..poses.sfm import add_features_argument
from ..recon.presets import add_quality_argument, refuse_unused_quality, settings_from_quality_arguments
from ..recon.settings import add_setting_arguments, given_settings, refuse_ignored_settings, refuse_untextured_settings

EXPORT_SUFFIXES = (".glb", ".gltf", ".ply", ".obj", ".usdz")


def script_arguments(argv: Sequence[str]) -> list[str]:
    """The script's own arguments: after `--` under Blender (which reads everything before it), else
    everything after the script name (plain python with the bpy module)."""
    argv = list(argv)
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def argument_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vortx_batch.py", description="Reconstruct rooms from photos into .blend files (and mesh files), with a JSON "
                                           "report per capture.",
    )
    parser.add_argument("captures", type=Path, nargs="+", metavar="CAPTURE",
                        help="capture folder or file (photos, video, transforms.json, COLMAP, ScanNet); several, or one "
                             "folder whose sub-folders are captures")
    parser.add_argument("--out", type=Path, required=True,
                        help="the .blend file to write (one capture), or the folder for NAME.blend and NAME.report.json")
    parser.add_argument("--export", type=Path,
                        help="also write the mesh: .glb/.gltf (VR), .ply, .obj or .usdz (Apple); with an --out folder, only the suffix counts")
    add_quality_argument(parser)  # --quality preview|standard|high, as `engine reconstruct` (engine/recon/presets.py)
    add_setting_arguments(parser)  # one flag per ReconSettings field offered to the CLI
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="camera height above the floor in metres; scales poses that are not metric (default %(default)s)")
    add_features_argument(parser)  # what Estimate Poses matches, for captures without poses
    parser.add_argument("--skip-poses", action="store_true", help="never run structure from motion; fail if no frame has a pose")
    parser.add_argument("--refine-poses", action="store_true",
                        help="refine the capture's given poses against the photos (Blender's Refine Poses) before reconstructing")
    parser.add_argument("--keep-poses", action="store_true", help=KEEP_POSES_HELP)
    parser.add_argument("--vr", action="store_true",
                        help="the VR preset: after Reconstruct, Bake Texture (decimated to --face-budget faces, a "
                             "--texture-size texture from the photos); --export .glb or .obj then carries the texture")
    parser.add_argument("--ray", metavar="ADDRESS",
                        help="run the captures as tasks on the Ray cluster at ADDRESS (HOST:PORT, from `ray start --head`), "
                             "or on one started on this machine for the run ('local'); see engine/batch/ray_cluster.py")
    parser.add_argument("--ray-cpus", type=float, default=1.0,
                        help="with --ray: CPU cores each capture's task reserves (its torch threads follow) (default %(default)s)")
    return parser


def parse_arguments(args: Sequence[str]) -> argparse.Namespace:
    """The parsed flags, plus `single` (one capture into one .blend), `export_suffix` (with --export)
    and `settings` (the ReconSettings: the --quality preset under the explicit flags)."""
    parser = argument_parser()
    args = parser.parse_args(list(args))
    if not args.ray_cpus > 0:
        parser.error(f"--ray-cpus {args.ray_cpus}: give a positive number of cores")
    args.single = args.out.suffix.lower() == ".blend"
    if args.single and len(args.captures) > 1:
        parser.error(f"--out {args.out}: {len(args.captures)} captures need an output folder, not one .blend file")
    if not args.single and args.out.suffix:
        parser.error(f"--out {args.out}: give a .blend file (one capture) or a folder (no suffix)")
    if args.export is not None:
        suffix = (args.export.suffix or f".{args.export.name.lstrip('.')}").lower()
        if suffix not in EXPORT_SUFFIXES:
            parser.error(f"--export {args.export}: use a {', '.join(EXPORT_SUFFIXES)} file name")
        args.export_suffix = suffix
    args.settings = settings_from_quality_arguments(args)  # the preset under the explicit flags
    try:
        args.settings.validate()
        refuse_ignored_settings(args.settings, given_settings(args))  # no flag is silently ignored
        refuse_unused_quality(args.settings, args.quality, given_settings(args))  # nor a preset
        refuse_untextured_settings(given_settings(args), bool(args.vr), "--vr")
    except Exception as error:  # engine.errors.VortxError
        parser.error(str(error))
    return args
