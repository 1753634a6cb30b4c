"""`python -m engine reconstruct CAPTURE --out mesh.ply`: a capture with poses -> a mesh file + a JSON sidecar.

The capture's own warnings (photos skipped, poses repaired) are printed right after loading. With
`--refine-poses` the capture's poses are refined against the photos first (`engine.poses.refine`).

The sidecar (`mesh.json` beside `mesh.ply`) records what the run did: timings per stage, voxels per
level, views per tile, tile count, peak memory, the settings, the source capture, its warnings
("capture_warnings"), what capture preparation did ("poses": source, scale, refinement) and the mesh's
coordinates ("frame": `--frame world`, the Z-up floor-at-zero metric world, or `--frame capture`, the
capture's own; with the similarities capture <-> world <-> output both ways, `output_frame.py`). When no
surface is found the (empty) mesh and the sidecar are still written, the reason is printed and the
exit status is 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..capture import load_capture
from ..errors import VortxError
from ..jobs import TqdmProgress
from ..mesh_io import write_ply
from ..sidecar import sidecar_path
from ..poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from ..poses.prepare import KEEP_POSES_HELP, SFM_IF_UNPOSED, PreparedCapture, prepare_capture
from ..poses.sfm import SfmOptions, add_features_argument
from ..texture.files import write_textured
from ..texture.views import views_from_capture
from ..texture.vr import textured_result
from .output_frame import FRAME_CAPTURE, FRAME_WORLD, frame_record, moved_mesh, world_to_output
from .presets import add_quality_argument, quality_of, refuse_unused_quality, settings_from_quality_arguments
from .settings import (ReconSettings, add_setting_arguments, given_settings, refuse_ignored_settings,
                       refuse_untextured_settings)

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".usdz")  # .glb, .obj, .usdz are textured (engine/texture), .ply has vertex colours


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="capture folder (any layout `python -m engine info` reads), with poses")
    parser.add_argument("--images-dir", type=Path, help="COLMAP model: the folder holding its photos, when they are not in images/ beside it")
    parser.add_argument("--out", type=Path, required=True,
                        help="output mesh: .ply (every face, vertex colours, confidence layer), or a textured VR-ready "
                             "result: .glb (one file, texture embedded; --headset picks its budget and compression), .obj (+ .mtl + "
                             "_texture.png) or .usdz (Apple Vision Pro, Quick Look), decimated to "
                             "--face-budget, with the .ply beside it; a .json sidecar is written beside it")
    add_quality_argument(parser)  # --quality preview|standard|high (engine/recon/presets.py)
    add_setting_arguments(parser)  # one flag per ReconSettings field offered to the CLI (--frame among them)
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="metres above the floor, for the scale of captures whose poses are not metric "
                             "(default %(default)s)")
    add_features_argument(parser)  # for photos without poses (structure from motion first)
    parser.add_argument("--refine-poses", action="store_true",
                        help="refine the capture's own poses against the photos before reconstructing (for slightly-off "
                             "tracker, ARKit or SLAM poses; the report gives each frame's change)")
    parser.add_argument("--keep-poses", action="store_true", help=KEEP_POSES_HELP)
    parser.add_argument("--preview", action="store_true",
                        help="beside a .glb, also write <name>.html, a preview page (model-viewer: orbit and AR) that needs "
                             "no network; serve the folder to open it (python3 -m http.server)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def settings_from_args(args: argparse.Namespace) -> ReconSettings:
    """The flags' settings with the --quality preset under them (explicit flags win)."""
    return settings_from_quality_arguments(args)


def write_mesh(path: Path, mesh: Any) -> None:
    """A PLY with vertex colours and the confidence layer (the textured formats: engine/texture/files.py)."""
    write_ply(path, mesh.vertices, mesh.faces, normals=mesh.normals, colors=mesh.colors, attributes=mesh.attributes)


def report_preparation(prepared: PreparedCapture) -> None:
    """What capture preparation did, on stderr (stdout carries the result line)."""
    for line in prepared.report_lines:
        print(line, file=sys.stderr)
    if prepared.sfm is None:  # the SfM report lists its own warnings
        for warning in prepared.warnings:
            print(f"warning: {warning}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    out: Path = args.out
    if out.suffix.lower() not in MESH_SUFFIXES:
        raise VortxError(f"--out {out}: the mesh file must end in .ply, .obj, .glb or .usdz")
    if getattr(args, "preview", False) and out.suffix.lower() != ".glb":
        raise VortxError(f"--preview: the preview page shows a .glb, not {out.name}")
    if args.refine_poses and args.keep_poses:
        raise VortxError("--refine-poses and --keep-poses contradict each other: give one (neither: poses are refined "
                         "when the check against the photos finds them off)")
    settings = settings_from_args(args)
    settings.validate()
    refuse_ignored_settings(settings, given_settings(args))  # before the capture loads: an early, clear error
    refuse_unused_quality(settings, args.quality, given_settings(args))
    refuse_untextured_settings(given_settings(args), out.suffix.lower() != ".ply", "--out room.glb, room.obj or room.usdz")

    # defers torch (the driver loads it): `engine reconstruct --help` and refused settings answer at once
    from .driver import reconstruct

    capture = load_capture(args.capture, images_dir=args.images_dir)
    if settings.frame == FRAME_CAPTURE and not capture.posed_frames:  # before structure from motion spends minutes
        raise VortxError(f"--frame {FRAME_CAPTURE}: {args.capture} has no camera poses of its own, so there are no capture "
                         f"coordinates to write the mesh in; structure from motion's poses are in the Z-up world "
                         f"(use --frame {FRAME_WORLD})")
    capture_warnings = list(capture.warnings)
    for warning in capture_warnings:
        print(f"warning: {warning}", file=sys.stderr)
    progress = TqdmProgress(disable=args.quiet)
    try:
        # Photos without poses get structure from motion first, as `python -m engine poses` would.
        # Given poses that are not refined are checked against the photos; poses that look off are refined
        # (--keep-poses: a warning instead).
        prepared = prepare_capture(capture, camera_height=args.camera_height, sfm=SFM_IF_UNPOSED,
                                   sfm_options=SfmOptions(features=args.features),
                                   refine=args.refine_poses, progress=progress, check_poses=True,
                                   refine_when_off=not args.keep_poses)
        report_preparation(prepared)
        if args.features != SfmOptions.features and not prepared.ran_sfm:
            print(f"note: --features {args.features} was not used: {args.capture} has poses, so structure from motion "
                  "did not run", file=sys.stderr)
        # Reconstructed in the world, written in the frame asked for (output_frame.py).
        to_output = world_to_output(prepared, settings.frame)
        capture = prepared.capture
        result = reconstruct(capture, settings, progress=progress)
        # The full mesh with vertex colours and the confidence layer comes first, as a PLY (beside a
        # textured .glb / .obj too): a bake that fails or is interrupted loses no reconstruction.
        ply = out.with_suffix(".ply")
        write_mesh(ply, moved_mesh(result.mesh, to_output))
        textured, written = None, [ply]
        if out.suffix.lower() != ".ply":
            out.unlink(missing_ok=True)  # no stale textured file of an earlier run
            if not result.is_empty:

                try:
                    textured, texture_stats = textured_result(result.mesh, views_from_capture(capture),
                                                              settings.texture_options, progress)
                except VortxError as error:
                    raise VortxError(f"{error} (the untextured mesh is in {ply})") from error
                result.stats["texture"] = texture_stats
                frame = frame_record(prepared, settings.frame)
                written = write_textured(out, moved_mesh(textured, to_output),
                                         extras={"vortx_settings": settings.to_dict(), "vortx_frame": frame},
                                         options=settings.texture_options,
                                         preview=getattr(args, "preview", False)) + [ply]
            else:
                out = ply
    finally:
        progress.close()

    sidecar = {
        "capture": str(Path(args.capture).resolve()),
        "capture_format": capture.format,
        "capture_warnings": capture_warnings,
        "poses": prepared.summary(),
        # The mesh's frame and the similarities capture <-> world <-> output; bounds and grid below are in the world.
        "frame": frame_record(prepared, settings.frame),
        "output": str(out.resolve()),
        "quality": quality_of(settings) or "custom",  # the preset the settings match (flags can change it)
        "files": [str(p.resolve()) for p in written],
        **result.stats,
        "tile_details": [t.to_dict() for t in result.tiles],
    }
    sidecar_path(out).write_text(json.dumps(sidecar, indent=1) + "\n")
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    seconds = result.stats.get("timings_s", {}).get("total", 0.0)
    if result.message is not None:
        print(f"error: no surface was reconstructed: {result.message}. Wrote an empty {out} and {sidecar_path(out)}.",
              file=sys.stderr)
        return 1
    if textured is not None:
        texture = result.stats["texture"]
        print(f"wrote {', '.join(str(p) for p in written)}: {texture['faces']} faces (of {len(result.mesh.faces)}), "
              f"{texture['texture_size']} px texture, in {seconds + texture['timings_s']['total']:.1f} s "
              f"(details in {sidecar_path(out)})")
        return 0
    print(f"wrote {out}: {len(result.mesh.vertices)} vertices, {len(result.mesh.faces)} faces in {seconds:.1f} s "
          f"(details in {sidecar_path(out)})")
    return 0
