"""The demo's steps in order (devtools/demo/__init__.py lists them), each tool run as a user runs it:
the batch script, `engine reconstruct` and `engine texture` in processes of their own."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from contextlib import AbstractContextManager
from pathlib import Path
from types import ModuleType
from typing import Callable, Sequence

from engine.eval import room_box_from_tsdf
from engine.eval.cli import truth_tsdf_mesh
from engine.eval.against_truth import ScoredMesh, compare_poses, fscore_table, score_mesh, true_poses
from engine.eval.surface_metrics import SURFACE_LEGEND, surface_table
from engine.mesh_io import read_ply
from engine.model.weights import DEFAULT_WEIGHTS
from engine.recon.output_frame import moved_mesh
from engine.tsdf.volume import TsdfVolume

from .blender_views import read_capture_cameras, render_glb
from .heldout import measure_texture
from .messages import DemoError, say
from .pictures import side_by_side

REPO = Path(__file__).resolve().parent.parent.parent
BATCH = REPO / "scripts" / "vortx_batch.py"

# The enabled `vortx` add-on for the time of a `with` block (scripts/_extension_dev.py's vortx_extension).
ExtensionLoader = Callable[[], AbstractContextManager[ModuleType]]


def run_batch(images: Path, blend: Path, ply: Path, extra: Sequence[str]) -> None:
    """The batch script in its own process, exactly as a user runs it (its progress streams through)."""
    command = [sys.executable, str(BATCH), str(images), "--out", str(blend), "--export", str(ply), *extra]
    say("running " + " ".join(Path(a).name if a == str(BATCH) else a for a in command[1:]))
    if subprocess.run(command, cwd=REPO).returncode != 0:
        raise DemoError("the batch run failed (its error is above)")


def run_engine(command: Sequence[str], failure: str) -> None:
    """`python -m engine <command>` in its own process, as a user runs it."""
    command = [sys.executable, "-m", "engine", *command]
    say("running " + " ".join(command[1:]))
    if subprocess.run(command, cwd=REPO).returncode != 0:
        raise DemoError(f"{failure} failed (its error is above)")


def check_sample(args: argparse.Namespace) -> None:
    """DemoError saying what is missing before anything runs: the sample, or the default weights."""
    if not (args.sample / "images").is_dir() or not (args.sample / "truth" / "mesh_gt.ply").is_file():
        raise DemoError(f"the demo sample is incomplete at {args.sample}: regenerate it with scripts/make_demo_sample.py")
    if args.weights is None and (args.method == "vortx" or args.compare) and not DEFAULT_WEIGHTS.is_file():
        raise DemoError(f"the default weights are not in the checkout yet ({DEFAULT_WEIGHTS.relative_to(REPO)}); "
                        "`scripts/demo.py --weights random` runs every stage with a random network (meaningless mesh)")


def weights_flag(weights: str | None, method: str) -> list[str]:
    """--weights only for VoRTX: a flag the method does not read is refused (engine/recon/settings.py)."""
    return ["--weights", weights] if weights and method == "vortx" else []


def run_demo(args: argparse.Namespace, extension: ExtensionLoader) -> None:
    """Every step on args.sample into args.out_dir; DemoError when one cannot go on."""
    images, truth, out = args.sample / "images", args.sample / "truth", args.out_dir.resolve()
    # A private Blender user folder (unless one is set): the demo shows this checkout, and neither
    # uses nor touches the preferences and extensions of the user's own Blender.
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(out / "blender-user"))
    blend, ply, render, picture = out / "demo.blend", out / "demo.ply", out / "demo_render.png", out / "demo.png"
    posed_dir = out / "demo_posed"
    check_sample(args)
    out.mkdir(parents=True, exist_ok=True)
    run_batch(images, blend, ply, ["--method", args.method, "--device", args.device, *weights_flag(args.weights, args.method)])

    with extension() as addon:
        estimated, photo = read_capture_cameras(addon, blend, render, posed_dir)
    truths = true_poses(truth, sorted(estimated))
    if len(truths) < 3:
        raise DemoError(f"only {len(truths)} estimated cameras have a true pose; a Sim(3) needs 3")
    poses = compare_poses(estimated, truths)
    say(poses.summary(len(list(truth.glob("pose/*.txt")))))

    side_by_side(Path(photo), render, picture, f"{args.method} mesh")
    say(f"wrote {picture} ({Path(photo).name} beside a Workbench render of the mesh from its estimated camera)")

    gt_mesh, gt_volume = read_ply(truth / "mesh_gt.ply"), TsdfVolume.load(truth / "tsdf_gt.npz")
    rows = [score_mesh(f"{args.method} (default method, the batch run above)", moved_mesh(read_ply(ply), poses.to_truth),
                       gt_mesh, gt_volume)]
    if args.compare:
        other = "vortx" if args.method == "stereo" else "stereo"
        other_ply = out / f"demo_{other}.ply"
        run_engine(["reconstruct", str(posed_dir), "--out", str(other_ply), "--quiet", "--method", other,
                    "--device", args.device, *weights_flag(args.weights, other)], f"the reconstruction of {posed_dir}")
        label = "vortx (shipped appearance-only weights)" if other == "vortx" else "stereo (classical fusion)"
        rows.append(score_mesh(label, moved_mesh(read_ply(other_ply), poses.to_truth), gt_mesh, gt_volume))
    # The metrics' ceiling for a volumetric mesh (the area ratio's is under 1 on this room's thin parts),
    # and their floor: a plain box fitted to the true room, both scored the same way.
    rows.append(score_mesh("the truth's own TSDF meshed (ceiling)", truth_tsdf_mesh(gt_volume), gt_mesh, gt_volume))
    rows.append(score_mesh("room box fitted to the true walls (baseline)", room_box_from_tsdf(gt_volume), gt_mesh, gt_volume))
    report_scores(rows)

    glb, texture_picture = out / "demo.glb", out / "demo_texture.png"
    started = time.perf_counter()
    run_engine(["texture", str(posed_dir), str(ply), "--out", str(glb), "--quiet"], f"texturing {ply}")
    say(f"wrote {glb} in {time.perf_counter() - started:.0f} s")
    glb_render, glb_picture = out / "demo_glb_render.png", out / "demo_glb.png"
    with extension() as addon:
        render_glb(addon, blend, glb, photo, glb_render)
    side_by_side(Path(photo), glb_render, glb_picture, "demo.glb in Blender (Cycles)")
    say(f"wrote {glb_picture} (demo.glb imported with Blender's glTF importer, rendered from {Path(photo).name}'s camera)")
    measure_texture(ply, posed_dir, gt_mesh, poses.to_truth, texture_picture)
    say(f"outputs: {blend}, {ply}, {picture}, {glb}, {glb_picture}, {texture_picture}")


def report_scores(rows: list[ScoredMesh]) -> None:
    say("meshes vs truth (moved into the truth frame by the camera-centre Sim(3), trimmed to the space the truth "
        "observed; F-score at 5 cm):")
    for line in fscore_table(rows):
        say("  " + line)
    say(f"surface quality, same meshes ({SURFACE_LEGEND}):")
    for line in surface_table({row.name: row.surface for row in rows}).splitlines():
        say("  " + line)
    say(f"F-score {rows[0].mesh.fscore:.3f} for the default method against {rows[-1].mesh.fscore:.3f} for the room box")
