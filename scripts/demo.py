"""`make demo`: the whole product on the bundled sample capture, checked against the sample's truth.

    .venv/bin/python scripts/demo.py [--method stereo|vortx] [--weights PATH|random] [--device cpu|cuda]
                                     [--sample samples/demo_room] [--no-compare]

1. Runs scripts/vortx_batch.py on the sample's photos only (samples/demo_room/images): Import
   Capture, Estimate Poses (structure from motion, gravity, scale from the floor and the 1.5 m
   camera height), Reconstruct with the default method -> out/demo.blend and out/demo.ply.
2. Pose error: the estimated cameras (read back from out/demo.blend) against truth/pose, after the
   similarity (Sim(3)) that best maps the estimated camera centres onto the true ones; SfM knows
   the world only up to such a transform.
3. out/demo.png: a capture photo beside a Workbench render (vertex colours) of the mesh from that
   photo's estimated camera, at the photo's resolution.
4. The other method (`engine reconstruct`) on the same estimated poses (out/demo_posed), unless
   --no-compare.
5. F-scores against truth/mesh_gt.ply, side by side with a plain room box: each mesh is moved into
   the truth frame with the same Sim(3) first, then scored with the Atlas metrics (5 cm threshold),
   trimmed to the space the truth TSDF observed, and with the surface metrics
   (engine/eval/surface_metrics.py: normal agreement, floater share, pieces, area ratio, open
   boundary per m^2).
6. The textured result: `engine texture` on the estimated poses -> out/demo.glb (VR preset, 4096 px);
   out/demo_glb.png: the photo of step 3 beside demo.glb imported with Blender's own glTF importer
   and rendered with Cycles from the same camera.
7. How it looks from photos it was not made from: HELDOUT_PHOTOS photos spread over the walk are held
   out, the texture (HELDOUT_TEXTURE_SIZE px), the vertex colours and the true mesh (moved into the
   estimated frame by the inverse Sim(3)) are made from the others, rendered from the held-out
   cameras and compared with the photos (PSNR, SSIM) -> a table and out/demo_texture.png.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from engine.capture.writers import write_scannet  # noqa: E402
from engine.eval import MeshMetrics, evaluate_mesh, room_box_from_tsdf  # noqa: E402
from engine.eval.surface_metrics import SURFACE_LEGEND, SurfaceMetrics, evaluate_surface, surface_table  # noqa: E402
from engine.mesh_io import Mesh, read_ply  # noqa: E402
from engine.poses import Similarity, pose_errors, umeyama  # noqa: E402
from engine.recon.settings import METHODS, ReconSettings  # noqa: E402
from engine.tsdf.volume import TsdfVolume  # noqa: E402

BATCH = REPO / "scripts" / "vortx_batch.py"
HELDOUT_PHOTOS = 4
HELDOUT_TEXTURE_SIZE = 2048  # the held-out measurement's bake; 4096 would add ~1 min on 2 cores for a 320 x 240 sample


class DemoError(Exception):
    pass


def say(message: str) -> None:
    print(f"demo: {message}", flush=True)


def run_batch(images: Path, blend: Path, ply: Path, extra: Sequence[str]) -> None:
    """The batch script in its own process, exactly as a user runs it (its progress streams through)."""
    command = [sys.executable, str(BATCH), str(images), "--out", str(blend), "--export", str(ply), *extra]
    say("running " + " ".join(Path(a).name if a == str(BATCH) else a for a in command[1:]))
    if subprocess.run(command, cwd=REPO).returncode != 0:
        raise DemoError("the batch run failed (its error is above)")


def run_reconstruct(capture: Path, mesh: Path, extra: Sequence[str]) -> None:
    """`python -m engine reconstruct` in its own process, as a user runs it."""
    command = [sys.executable, "-m", "engine", "reconstruct", str(capture), "--out", str(mesh), "--quiet", *extra]
    say("running " + " ".join(command[1:]))
    if subprocess.run(command, cwd=REPO).returncode != 0:
        raise DemoError(f"the reconstruction of {capture} failed (its error is above)")


def run_texture(capture: Path, mesh: Path, out: Path) -> None:
    """`python -m engine texture` in its own process, as a user runs it."""
    command = [sys.executable, "-m", "engine", "texture", str(capture), str(mesh), "--out", str(out), "--quiet"]
    say("running " + " ".join(command[1:]))
    if subprocess.run(command, cwd=REPO).returncode != 0:
        raise DemoError(f"texturing {mesh} failed (its error is above)")


def inverse(sim: Similarity) -> Similarity:
    """x = R^T (y - t) / s: the similarity undoing `sim`."""
    rotation = sim.rotation.T
    return Similarity(rotation, -rotation @ sim.translation / sim.scale, 1.0 / sim.scale)


def measure_texture(mesh_path: Path, posed_dir: Path, gt_mesh: Mesh, to_truth: Similarity, picture: Path) -> dict:
    """Step 7: the held-out report on the demo (the estimated frame), its table and picture."""
    from engine.capture import load_capture
    from engine.eval.texture_views import heldout_texture_report, report_table, spread_heldout, \
        write_comparison_picture
    from engine.poses.prepare import SFM_NEVER, prepare_capture

    # Prepared as `engine texture` and `engine reconstruct` prepare it, so the cameras see the mesh where it is.
    capture = prepare_capture(load_capture(posed_dir), sfm=SFM_NEVER).capture
    held = spread_heldout([f.image_path.stem for f in capture.posed_frames], HELDOUT_PHOTOS)
    options = ReconSettings(texture_size=HELDOUT_TEXTURE_SIZE).texture_options
    say(f"held-out views: baking without photos {', '.join(held)} ({options.texture_size} px texture, "
        f"face budget {options.face_budget}) ...")
    report = heldout_texture_report(read_ply(mesh_path), capture, held, options, aligned(gt_mesh, inverse(to_truth)))
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


def read_capture_cameras(blend: Path, render_to: Path, posed_dir: Path) -> tuple[dict[str, np.ndarray], str]:
    """Open the batch's .blend: return {photo stem: estimated camera-to-world} and render the mesh
    from the middle capture camera (Workbench, vertex colours, the photo's resolution) into
    `render_to`. Returns also the rendered photo's path. The posed capture is written to `posed_dir`
    (ScanNet layout), so the other methods are scored on exactly the same poses."""
    import bpy
    from vortx_batch import vortx_extension

    with vortx_extension() as addon:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        scene = bpy.context.scene
        capture = addon.vortx_blender.cameras.posed_capture_from_scene(scene)
        if capture is None or not capture.posed_frames:
            raise DemoError(f"{blend} has no posed capture cameras")
        estimated = {Path(f.image_path).stem: f.pose for f in capture.posed_frames}
        write_scannet(capture, posed_dir, overwrite=True)
        cameras = sorted((o for o in scene.objects if addon.vortx_blender.cameras.is_capture_camera(o)),
                         key=lambda o: int(o[addon.vortx_blender.cameras.PROP_FRAME]))
        camera = cameras[len(cameras) // 2]
        render_mesh(scene, camera, render_to)
        return estimated, str(camera[addon.vortx_blender.cameras.PROP_IMAGE])


def render_mesh(scene: Any, camera: Any, path: Path) -> None:
    import bpy

    scene.camera = camera
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "VERTEX"
    # The photos are sRGB and the vertex colours came from them: no filmic/AgX tone curve on top.
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_percentage = 100  # resolution_x/y were set to the photos' size on import
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise DemoError(f"the Workbench render did not write {path}")


def render_glb(blend: Path, glb: Path, photo: str, path: Path) -> None:
    """The GLB as a VR engine would get it, opened in Blender with its own glTF importer and rendered
    with Cycles from the capture camera of `photo` (the batch's mesh hidden), into `path`."""
    import bpy
    from vortx_batch import vortx_extension

    with vortx_extension() as addon:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        scene = bpy.context.scene
        for obj in scene.objects:
            if obj.type == "MESH":
                obj.hide_render = True
        if "FINISHED" not in bpy.ops.import_scene.gltf(filepath=str(glb)):
            raise DemoError(f"Blender's glTF importer could not read {glb}")
        cameras = addon.vortx_blender.cameras
        scene.camera = next(o for o in scene.objects if cameras.is_capture_camera(o) and o[cameras.PROP_IMAGE] == photo)
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False
        scene.view_settings.view_transform = "Standard"  # the texture holds photo colours: no tone curve on top
        scene.render.resolution_percentage = 100
        scene.render.image_settings.file_format = "PNG"
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise DemoError(f"the Cycles render did not write {path}")


def true_poses(truth: Path, stems: Sequence[str]) -> dict[str, np.ndarray]:
    return {s: np.loadtxt(truth / "pose" / f"{s}.txt").reshape(4, 4) for s in stems if (truth / "pose" / f"{s}.txt").is_file()}


def side_by_side(photo: Path, render: Path, out: Path, label: str) -> None:
    import cv2

    left, right = cv2.imread(str(photo)), cv2.imread(str(render))
    if left is None or right is None:
        raise DemoError(f"cannot read {photo if left is None else render}")
    if right.shape != left.shape:  # the render is made at the photo's size; a mismatch is a bug worth seeing, not hiding
        raise DemoError(f"render {right.shape[1]}x{right.shape[0]} does not match photo {left.shape[1]}x{left.shape[0]}")
    gap = np.full((left.shape[0], 4, 3), 255, np.uint8)
    picture = np.concatenate([left, gap, right], axis=1)
    for text, x in (("photo", 6), (label, left.shape[1] + 10)):
        cv2.putText(picture, text, (x, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(out), picture):
        raise DemoError(f"cannot write {out}")


def aligned(mesh: Mesh, sim: Similarity) -> Mesh:
    """The mesh moved by a similarity (normals rotate; colours and faces stay)."""
    normals = None if mesh.normals is None else (np.asarray(mesh.normals, np.float64) @ sim.rotation.T).astype(np.float32)
    return Mesh(vertices=sim.apply_points(mesh.vertices).astype(np.float32), faces=mesh.faces, normals=normals, colors=mesh.colors)


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", type=Path, default=REPO / "samples" / "demo_room", help="sample folder with images/ and truth/")
    parser.add_argument("--out-dir", type=Path, default=REPO / "out")
    parser.add_argument("--weights", help="weights file or 'random' (default: the shipped weights/vortx-default.safetensors)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--method", choices=METHODS, default=ReconSettings().method,
                        help="method of the main run (default: the product's default, %(default)s)")
    parser.add_argument("--no-compare", dest="compare", action="store_false",
                        help="skip reconstructing with the other method for the side-by-side table")
    args = parser.parse_args(argv)

    images, truth, out = args.sample / "images", args.sample / "truth", args.out_dir.resolve()
    # A private Blender user folder (unless one is set): the demo shows this checkout, and neither
    # uses nor touches the preferences and extensions of the user's own Blender.
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(out / "blender-user"))
    blend, ply, render, picture = out / "demo.blend", out / "demo.ply", out / "demo_render.png", out / "demo.png"
    posed_dir = out / "demo_posed"
    try:
        if not images.is_dir() or not (truth / "mesh_gt.ply").is_file():
            raise DemoError(f"the demo sample is incomplete at {args.sample}: regenerate it with scripts/make_demo_sample.py")
        if args.weights is None and (args.method == "vortx" or args.compare):
            from engine.model.weights import DEFAULT_WEIGHTS

            if not DEFAULT_WEIGHTS.is_file():
                raise DemoError(f"the default weights are not in the checkout yet ({DEFAULT_WEIGHTS.relative_to(REPO)}); "
                                "`scripts/demo.py --weights random` runs every stage with a random network (meaningless mesh)")
        out.mkdir(parents=True, exist_ok=True)
        # --weights only for VoRTX: a flag the method does not read is refused (engine/recon/settings.py).
        extra = ["--method", args.method, "--device", args.device] + (["--weights", args.weights]
                                                                      if args.weights and args.method == "vortx" else [])
        run_batch(images, blend, ply, extra)

        estimated, photo = read_capture_cameras(blend, render, posed_dir)
        truths = true_poses(truth, sorted(estimated))
        stems = sorted(truths)
        if len(stems) < 3:
            raise DemoError(f"only {len(stems)} estimated cameras have a true pose; a Sim(3) needs 3")
        errors = pose_errors([estimated[s] for s in stems], [truths[s] for s in stems])
        # The same fit pose_errors makes: estimated world -> truth world, from the camera centres.
        sim = umeyama(np.array([estimated[s][:3, 3] for s in stems]), np.array([truths[s][:3, 3] for s in stems]))
        total = len(list(truth.glob("pose/*.txt")))
        say(f"poses vs truth ({len(stems)} of {total} photos registered; after the Sim(3) fit of the camera centres, "
            f"scale {sim.scale:.3f}): rotation error mean {errors['rotation_deg_mean']:.2f} deg "
            f"(max {errors['rotation_deg_max']:.2f}), position error mean {100 * errors['position_mean']:.1f} cm "
            f"(max {100 * errors['position_max']:.1f} cm)")

        side_by_side(Path(photo), render, picture, f"{args.method} mesh")
        say(f"wrote {picture} ({Path(photo).name} beside a Workbench render of the mesh from its estimated camera)")

        gt_mesh, gt_volume = read_ply(truth / "mesh_gt.ply"), TsdfVolume.load(truth / "tsdf_gt.npz")

        def scored(name: str, mesh: Mesh) -> tuple[str, MeshMetrics, SurfaceMetrics]:
            return name, evaluate_mesh(mesh, gt_mesh, gt_volume), evaluate_surface(mesh, gt_mesh, gt_volume)

        rows = [scored(f"{args.method} (default method, the batch run above)", aligned(read_ply(ply), sim))]
        if args.compare:
            other = "vortx" if args.method == "stereo" else "stereo"
            other_ply = out / f"demo_{other}.ply"
            run_reconstruct(posed_dir, other_ply, ["--method", other, "--device", args.device]
                            + (["--weights", args.weights] if args.weights and other == "vortx" else []))
            label = "vortx (shipped appearance-only weights)" if other == "vortx" else "stereo (classical fusion)"
            rows.append(scored(label, aligned(read_ply(other_ply), sim)))
        # The metric's floor: a plain box fitted to the true room, scored the same way.
        rows.append(scored("room box fitted to the true walls (baseline)", room_box_from_tsdf(gt_volume)))
        say("meshes vs truth (moved into the truth frame by the camera-centre Sim(3), trimmed to the space the truth "
            "observed; F-score at 5 cm):")
        say(f"  {'method':<48} {'F':>6} {'prec':>6} {'recall':>6} {'acc cm':>7} {'comp cm':>8}")
        for name, m, _ in rows:
            say(f"  {name:<48} {m.fscore:6.3f} {m.prec:6.3f} {m.recall:6.3f} {100 * m.acc:7.1f} {100 * m.comp:8.1f}")
        say(f"surface quality, same meshes ({SURFACE_LEGEND}):")
        for line in surface_table({name: surface for name, _, surface in rows}).splitlines():
            say("  " + line)
        say(f"F-score {rows[0][1].fscore:.3f} for the default method against {rows[-1][1].fscore:.3f} for the room box")

        glb, texture_picture = out / "demo.glb", out / "demo_texture.png"
        started = time.perf_counter()
        run_texture(posed_dir, ply, glb)
        say(f"wrote {glb} in {time.perf_counter() - started:.0f} s")
        glb_render, glb_picture = out / "demo_glb_render.png", out / "demo_glb.png"
        render_glb(blend, glb, photo, glb_render)
        side_by_side(Path(photo), glb_render, glb_picture, "demo.glb in Blender (Cycles)")
        say(f"wrote {glb_picture} (demo.glb imported with Blender's glTF importer, rendered from {Path(photo).name}'s camera)")
        measure_texture(ply, posed_dir, gt_mesh, sim, texture_picture)
        say(f"outputs: {blend}, {ply}, {picture}, {glb}, {glb_picture}, {texture_picture}")
    except DemoError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
