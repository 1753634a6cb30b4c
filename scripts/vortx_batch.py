"""Photos of a room -> a .blend with the capture cameras and the reconstructed mesh, without the UI.

    blender --background --python-exit-code 1 --python scripts/vortx_batch.py -- CAPTURE --out scene.blend [options]
    .venv/bin/python scripts/vortx_batch.py CAPTURE --out scene.blend [options]     (the bpy module)

Runs the extension's own operators, exactly as a user would click them: Import Capture, Estimate
Poses (only when no frame has a pose), Reconstruct; then saves the .blend and, with --export, writes
the mesh as GLB, PLY or OBJ (metres, Z up for PLY/OBJ; glTF is Y-up by specification and converts
back on import). Uses the `vortx` extension this Blender has installed; otherwise this checkout is
mounted as a temporary local extension repository (scripts/_extension_dev.py, as the tests do).

Prints one line per finished stage; on failure prints `error: <reason>` and exits with status 1
(or 2 for bad arguments), also under `blender --background` (sys.exit ends Blender with that status;
--python-exit-code covers anything that escapes).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterator, Optional, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parent))  # Blender does not put the script's folder on sys.path
from _extension_dev import ExtensionLoadError, enable, find_extension, mount_checkout, unmount  # noqa: E402

# The reconstruction flags are generated from this checkout's ReconSettings (plain dataclasses, no
# torch), the one source the CLI and the Blender properties share.
sys.path.insert(1, str(Path(__file__).resolve().parent.parent))
from engine.poses.camera_height import DEFAULT_CAMERA_HEIGHT_M  # noqa: E402
from engine.recon.settings import ReconSettings, add_setting_arguments, settings_from_arguments  # noqa: E402

EXPORT_SUFFIXES = (".glb", ".gltf", ".ply", ".obj")
BATCH_REPO = "vortx_checkout"  # repository name when this checkout is mounted: bl_ext.vortx_checkout.vortx


class BatchError(Exception):
    """A failure the user can act on; printed as `error: <message>`."""


def script_arguments(argv: Sequence[str]) -> list[str]:
    """The script's own arguments: after `--` under Blender (which reads everything before it), else
    everything after the script name (plain python with the bpy module)."""
    argv = list(argv)
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def parse_arguments(args: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="vortx_batch.py", description="Reconstruct a room from photos into a .blend file (and a mesh file).",
    )
    parser.add_argument("capture", type=Path, help="capture folder or file: photos, video, transforms.json, COLMAP, ScanNet")
    parser.add_argument("--out", type=Path, required=True, help="the .blend file to write")
    parser.add_argument("--export", type=Path, help="also write the mesh: .glb/.gltf (VR), .ply or .obj")
    add_setting_arguments(parser)  # one flag per ReconSettings field offered to the CLI
    parser.add_argument("--camera-height", type=float, default=DEFAULT_CAMERA_HEIGHT_M,
                        help="camera height above the floor in metres; scales poses that are not metric (default %(default)s)")
    parser.add_argument("--skip-poses", action="store_true", help="never run structure from motion; fail if no frame has a pose")
    parser.add_argument("--refine-poses", action="store_true",
                        help="refine the capture's given poses against the photos (Blender's Refine Poses) before reconstructing")
    args = parser.parse_args(list(args))
    if args.out.suffix.lower() != ".blend":
        parser.error(f"--out {args.out}: the output must be a .blend file")
    if args.export is not None and args.export.suffix.lower() not in EXPORT_SUFFIXES:
        parser.error(f"--export {args.export}: use a {', '.join(EXPORT_SUFFIXES)} file name")
    args.settings = settings_from_arguments(args)
    try:
        args.settings.validate()
    except Exception as error:  # engine.errors.VortxError of this checkout's engine
        parser.error(str(error))
    return args


def say(step: int, total: int, stage: str, detail: str, started: float) -> None:
    print(f"vortx [{step}/{total}] {stage}: {detail} ({time.perf_counter() - started:.1f} s)", flush=True)


def run_operator(label: str, operator: Callable[..., set[str]], **kwargs: Any) -> None:
    """Call a vortx operator; BatchError with its own error report when it fails.

    bpy.ops turns an operator's ERROR report into a RuntimeError("Error: <message>"); a CANCELLED
    return without one means the operator refused (its poll failed) or was cancelled.
    """
    if not operator.poll():
        raise BatchError(f"{label} cannot run now (its preconditions are not met)")
    try:
        outcome = operator(**kwargs)
    except RuntimeError as error:
        message = " ".join(str(error).split())
        raise BatchError(message.removeprefix("Error: ")) from None
    if "FINISHED" not in outcome:
        raise BatchError(f"{label} did not finish ({', '.join(sorted(outcome))})")


@contextmanager
def vortx_extension() -> Iterator[ModuleType]:
    """The enabled `vortx` add-on module: an installed one, else this checkout mounted for this run
    (and unmounted after, so nothing of it stays in the preferences)."""
    installed = find_extension()
    if installed is not None:
        yield enable(installed)
        return
    repo_dir = Path(tempfile.mkdtemp(prefix="vortx-batch-repo-"))
    try:
        module_name = mount_checkout(repo_dir, repo_module=BATCH_REPO)
        yield sys.modules[module_name]
    finally:
        try:
            unmount(BATCH_REPO)
        finally:
            shutil.rmtree(repo_dir, ignore_errors=True)


def apply_recon_settings(addon: ModuleType, settings: Any, recon: ReconSettings) -> None:
    """Command-line options -> scene.vortx (the operators read only the scene, as from the panel).

    Set just before Reconstruct: choosing the device probes PyTorch for a GPU (seconds), which a
    run that fails at import should not wait for.
    """
    settings.result_mode = "REPLACE"
    if recon.weights is None:
        settings.weights_source = "DEFAULT"
    elif recon.weights == "random":
        settings.weights_source = "RANDOM"
    else:
        settings.weights_source = "FILE"
        settings.weights_path = str(Path(recon.weights).resolve())
    try:
        addon.vortx_blender.reconstruct.write_scene_settings(settings, recon)
    except ValueError as error:
        if recon.device != "cpu":  # the enum offers CUDA only when PyTorch sees a GPU
            raise BatchError(f"--device {recon.device}: PyTorch sees no CUDA GPU here (or is not installed); "
                             "use --device cpu") from None
        raise BatchError(str(error)) from None


def run(args: argparse.Namespace, addon: ModuleType) -> None:
    import bpy

    steps = 4 + (args.export is not None)
    bpy.ops.wm.read_homefile(use_empty=True)  # no default cube/camera/light in the result
    scene = bpy.context.scene
    settings = scene.vortx
    settings.camera_height = args.camera_height  # scales the poses Estimate Poses finds

    started = time.perf_counter()
    run_operator("Import Capture", bpy.ops.vortx.import_capture, filepath=str(args.capture.resolve()))
    say(1, steps, "import capture", f"{settings.frame_count} frames ({settings.capture_format}), "
        f"{settings.posed_frame_count} posed, {settings.resolution_x}x{settings.resolution_y}", started)

    started = time.perf_counter()
    estimated = settings.posed_frame_count == 0
    if estimated:
        if args.skip_poses:
            raise BatchError(f"no frame of {args.capture} has a camera pose and --skip-poses was given")
        run_operator("Estimate Poses", bpy.ops.vortx.estimate_poses)
        detail = settings.pose_status
    elif settings.posed_frame_count < settings.frame_count:
        # Structure from motion would replace the capture's own (usually metric) poses for a few
        # frames' sake; reconstruct from the posed ones instead.
        detail = f"{settings.pose_status}; the {settings.frame_count - settings.posed_frame_count} frames without a pose are left out"
    else:
        detail = settings.pose_status
    if args.refine_poses and not estimated:
        # Poses SfM just estimated are already bundle-adjusted; given poses are refined here.
        run_operator("Refine Poses", bpy.ops.vortx.refine_poses)
        detail = f"{settings.pose_status}; refined against the photos"
    say(2, steps, "poses", detail, started)

    started = time.perf_counter()
    apply_recon_settings(addon, settings, args.settings)
    run_operator("Reconstruct", bpy.ops.vortx.reconstruct)
    results = addon.vortx_blender.result.result_objects(scene)
    if not results:
        raise BatchError("Reconstruct finished but left no result mesh in the scene")
    mesh_object = results[-1]
    say(3, steps, "reconstruct", f"'{mesh_object.name}': {len(mesh_object.data.vertices)} vertices, "
        f"{len(mesh_object.data.polygons)} faces", started)

    started = time.perf_counter()
    out = args.out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    if "FINISHED" not in bpy.ops.wm.save_as_mainfile(filepath=str(out)):
        raise BatchError(f"could not save {out}")
    say(4, steps, "save", str(out), started)

    if args.export is not None:
        started = time.perf_counter()
        try:
            written = addon.vortx_blender.export.export_result(mesh_object, args.export.resolve(), bpy.context.view_layer)
        except addon.engine.errors.VortxError as error:
            raise BatchError(str(error)) from None
        say(5, steps, "export", str(written), started)


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_arguments(script_arguments(sys.argv if argv is None else argv))
    if not args.capture.exists():
        print(f"error: {args.capture} does not exist", file=sys.stderr)
        return 1
    try:
        import bpy  # noqa: F401  (Blender's own, or the bpy module under plain python)

        with vortx_extension() as addon:
            run(args, addon)
    except (BatchError, ExtensionLoadError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except Exception as error:  # a bug rather than a user error: keep the traceback
        traceback.print_exc()
        print(f"error: unexpected {type(error).__name__}: {' '.join(str(error).split())}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
