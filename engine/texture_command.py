"""`python -m engine texture CAPTURE MESH --out room.glb`: bake a texture for an existing mesh.

For a mesh made earlier (`engine reconstruct --out room.ply`), perhaps cleaned up elsewhere, and the
capture it was made from. The capture is prepared exactly as `reconstruct` prepared it (Z up, the
same scale), so its cameras see the mesh where it is; a posed capture written by `engine poses` or a
metric one (ScanNet, ARKit) works as it is. With the VR preset's defaults the mesh is decimated to
the face budget first. Writes a .glb (texture embedded) or .obj + .mtl + _texture.png, and a JSON
sidecar with what the bake did.

An entry point above both engine/recon (the settings it offers as flags, `ReconSettings`) and
engine/texture (the bake), as `engine reconstruct` is: engine/texture itself never imports engine/recon,
while recon's settings read the texture options (tests/engine/test_import_directions.py).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .capture import load_capture
from .errors import VortxError
from .jobs import TqdmProgress
from .mesh_io import read_ply
from .poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from .poses.prepare import SFM_NEVER, prepare_capture
from .recon.settings import ReconSettings, add_setting_arguments
from .sidecar import sidecar_path
from .texture.files import TEXTURED_SUFFIXES, write_textured
from .texture.views import views_from_capture
from .texture.vr import textured_result

TEXTURE_FLAGS = ("texture_size", "face_budget", "headset")
LITTLE_SEEN = 0.05  # below this share of the texels seen by a photo, the capture and mesh do not match


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="the capture the mesh was reconstructed from (with poses)")
    parser.add_argument("mesh", type=Path, help="the mesh (.ply, normals facing the cameras, as `reconstruct` writes it)")
    parser.add_argument("--out", type=Path, required=True, help="the textured result: .glb (one file), .obj "
                                                                "(+ .mtl + _texture.png) or .usdz (Apple)")
    add_setting_arguments(parser, only=TEXTURE_FLAGS)
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="as given to `reconstruct`, for captures whose poses are not metric (default %(default)s)")
    parser.add_argument("--voxel-size", type=float, default=0.04,
                        help="the voxel size the mesh was made at: two voxels are the occlusion test's tolerance "
                             "(default %(default)s)")
    parser.add_argument("--exclude", nargs="*", default=[], metavar="PHOTO",
                        help="photos (file names or stems) not to bake from, e.g. held out for checking")
    parser.add_argument("--preview", action="store_true",
                        help="beside a .glb, also write <name>.html: a preview page (model-viewer, orbit and AR) that "
                             "needs no network; serve the folder to open it (python3 -m http.server)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() not in TEXTURED_SUFFIXES:
        raise VortxError(f"--out {args.out}: a textured result is written as .glb, .obj or .usdz")
    if args.mesh.suffix.lower() != ".ply" or not args.mesh.is_file():
        raise VortxError(f"{args.mesh}: give the mesh as a .ply file (as `python -m engine reconstruct` writes it)")
    if args.preview and args.out.suffix.lower() != ".glb":
        raise VortxError(f"--preview: the preview page shows a .glb, not {args.out.name}")
    settings = ReconSettings(texture_size=args.texture_size, face_budget=args.face_budget, voxel_size=args.voxel_size,
                             headset=args.headset)
    settings.validate()
    mesh = read_ply(args.mesh)  # without normals, the bake computes them from the winding
    capture = load_capture(args.capture)
    for warning in capture.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    prepared = prepare_capture(capture, camera_height=args.camera_height, sfm=SFM_NEVER)
    views = views_from_capture(prepared.capture, exclude=args.exclude)
    progress = TqdmProgress(disable=args.quiet)
    try:
        textured, stats = textured_result(mesh, views, settings.texture_options, progress)
    finally:
        progress.close()
    written = write_textured(args.out, textured, options=settings.texture_options, preview=args.preview)
    return report_texture(args.out, written, stats)


def report_texture(out: Path, written: list[Path], stats: dict) -> int:
    """Sidecar beside `out` and one line for the user; a warning when the photos saw little of the mesh."""

    sidecar_path(out).write_text(json.dumps({"texture": stats, "files": [str(p) for p in written]}, indent=1) + "\n")
    seen = stats["texels_seen"] / max(stats["texels"], 1)
    if seen < LITTLE_SEEN:
        print(f"warning: the photos saw only {100 * seen:.1f} % of the surface; is the capture the one the mesh was "
              "made from, with the same poses?", file=sys.stderr)
    headset = f" ({stats['headset']} headset preset)" if stats.get("headset") else ""
    print(f"wrote {', '.join(p.name for p in written[:4])}{' ...' if len(written) > 4 else ''}: {stats['faces']} faces, "
          f"{stats['texture_size']} px texture{headset}, {100 * seen:.0f} % of it seen by the photos, in "
          f"{stats['timings_s']['total']:.1f} s")
    return 0
