"""`python -m engine eval-texture CAPTURE MESH [--gt GT.ply]`: how the textured result looks from photos
it was not made from.

Holds out --heldout photos spread over the capture, bakes the texture (VR preset) and re-colours the
vertices from the others, renders both (and the ground-truth mesh textured the same way, with --gt)
from each held-out camera and prints PSNR / SSIM against the photo on the pixels every render covers.
--picture writes photo | vertex colours | texture (| ground truth) for the middle held-out photo.
--headset with a KTX2 preset (standalone, vision-pro, web) also scores the texture as the GPU shows it
after KTX2 / Basis Universal compression, and prints both textures' file size and GPU memory.
The capture is prepared as `reconstruct` prepared it, so its cameras see the mesh where it is.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..capture import load_capture
from ..errors import VortxError
from ..jobs import TqdmProgress
from ..mesh_io import read_ply
from ..poses.camera_height import DEFAULT_CAMERA_HEIGHT_M
from ..poses.prepare import SFM_NEVER, prepare_capture
from ..recon.settings import ReconSettings, add_setting_arguments
from .texture_views import heldout_texture_report, report_table, spread_heldout, write_comparison_picture


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", type=Path, help="the capture the mesh was reconstructed from (with poses)")
    parser.add_argument("mesh", type=Path, help="the reconstructed mesh (.ply)")
    parser.add_argument("--gt", type=Path, help="the true mesh (.ply) in the same frame: textured the same way, a ceiling")
    parser.add_argument("--heldout", type=int, default=4, help="photos to hold out, spread over the capture (default %(default)s)")
    add_setting_arguments(parser, only=("texture_size", "face_budget", "headset"))
    parser.add_argument("--voxel-size", type=float, default=0.04, help="the mesh's voxel size (occlusion tolerance: two voxels)")
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="as given to `reconstruct`, for captures whose poses are not metric (default %(default)s)")
    parser.add_argument("--picture", type=Path, help="write a side-by-side PNG of the middle held-out photo")
    parser.add_argument("--json", type=Path, help="write the numbers as JSON")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    for path in (args.mesh, args.gt):
        if path is not None and (path.suffix.lower() != ".ply" or not path.is_file()):
            raise VortxError(f"{path}: give meshes as .ply files")
    settings = ReconSettings(texture_size=args.texture_size, face_budget=args.face_budget, voxel_size=args.voxel_size,
                             headset=args.headset)
    settings.validate()
    capture = prepare_capture(load_capture(args.capture), camera_height=args.camera_height, sfm=SFM_NEVER).capture
    held = spread_heldout([f.image_path.stem for f in capture.posed_frames], args.heldout)
    progress = TqdmProgress(disable=args.quiet)
    try:
        report = heldout_texture_report(read_ply(args.mesh), capture, held, settings.texture_options,
                                        read_ply(args.gt) if args.gt else None, progress)
    finally:
        progress.close()
    renders = report.pop("renders")
    print("PSNR dB / SSIM against each held-out photo, on the pixels every render covers (made without that photo):")
    for line in report_table(report):
        print("  " + line)
    for fmt, sizes in report.get("texture_files", {}).items():
        print(f"  {fmt:<11} {sizes['bytes'] / 1e6:7.2f} MB in the file, {sizes['gpu_bytes'] / 2**20:7.1f} MiB of GPU memory "
              "(mipmaps included)")
    if args.picture:
        shown = report["views"][len(report["views"]) // 2]["photo"]
        images = dict(renders[shown])
        write_comparison_picture(args.picture, images.pop("photo"), images)
        print(f"wrote {args.picture} ({shown})")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0
