"""Step 7 of the demo: how the result looks from photos it was not made from."""

from __future__ import annotations

from pathlib import Path

from engine.capture import load_capture
from engine.eval.texture_views import heldout_texture_report, report_table, spread_heldout, write_comparison_picture
from engine.mesh_io import Mesh, read_ply
from engine.poses import Similarity
from engine.poses.prepare import SFM_NEVER, prepare_capture
from engine.recon.output_frame import moved_mesh
from engine.recon.settings import ReconSettings

from .messages import say

HELDOUT_PHOTOS = 4
HELDOUT_TEXTURE_SIZE = 2048  # the held-out measurement's bake; 4096 would add ~1 min on 2 cores for a 320 x 240 sample


def measure_texture(mesh_path: Path, posed_dir: Path, gt_mesh: Mesh, to_truth: Similarity, picture: Path) -> dict:
    """The held-out report on the demo (the estimated frame), its table and picture."""
    # Prepared as `engine texture` and `engine reconstruct` prepare it, so the cameras see the mesh where it is.
    capture = prepare_capture(load_capture(posed_dir), sfm=SFM_NEVER).capture
    held = spread_heldout([f.image_path.stem for f in capture.posed_frames], HELDOUT_PHOTOS)
    options = ReconSettings(texture_size=HELDOUT_TEXTURE_SIZE).texture_options
    say(f"held-out views: baking without photos {', '.join(held)} ({options.texture_size} px texture, "
        f"face budget {options.face_budget}) ...")
    report = heldout_texture_report(read_ply(mesh_path), capture, held, options, moved_mesh(gt_mesh, to_truth.inverse()))
    renders = report.pop("renders")
    say("held-out views: PSNR dB / SSIM against the photo, on the pixels all three cover — vertex colours, "
        "texture, ground-truth mesh textured (all made without that photo):")
    for line in report_table(report):
        say("  " + line)
    shown = report["views"][len(report["views"]) // 2]["photo"]
    images = renders[shown]
    write_comparison_picture(picture, images.pop("photo"), images)
    say(f"wrote {picture} (held-out {shown}: photo | vertex colours | texture | ground-truth mesh textured); "
        f"measurement took {sum(report['timings_s'].values()):.0f} s ({', '.join(f'{k} {v:.0f} s' for k, v in report['timings_s'].items())})")
    return report
