"""Photos of a room -> a .blend with the capture cameras and the reconstructed mesh, without the UI.

    blender --background --python-exit-code 1 --python scripts/vortx_batch.py -- CAPTURE --out scene.blend [options]
    .venv/bin/python scripts/vortx_batch.py CAPTURE --out scene.blend [options]     (the bpy module)
    .venv/bin/python scripts/vortx_batch.py CAPTURE_A CAPTURE_B ... --out OUT_FOLDER [--export .glb]
    .venv/bin/python scripts/vortx_batch.py FOLDER_OF_CAPTURES --out OUT_FOLDER

Runs the extension's own operators, exactly as a user would click them: Import Capture, Estimate
Poses (only when no frame has a pose), Refine Poses (with --refine-poses), Reconstruct (at --quality
preview|standard|high, the presets of Blender's Reconstruction panel; explicit flags win), Bake Texture
(with --vr: the VR preset, a mesh decimated to --face-budget with a --texture-size photo texture);
then saves the .blend and, with --export, writes the mesh as GLB, PLY or OBJ (metres, Z up for
PLY/OBJ; glTF is Y-up by specification and converts back on import; with --vr, GLB/glTF and OBJ carry
the texture; with --frame capture, the scene and the mesh are in the capture's own coordinates). Uses the `vortx` extension this Blender has
installed; otherwise this checkout is mounted as a temporary local extension repository
(scripts/_extension_dev.py, as the tests do).

One capture and `--out x.blend`: writes x.blend, the mesh at --export's path, and the report
x.report.json. Several captures, or one folder whose sub-folders are captures: `--out` is a folder
and each capture NAME gives NAME.blend, NAME.report.json and, with `--export .glb` (only the
suffix counts), NAME.glb there. A failed capture does not stop the others.

The report (JSON, one per capture, also for a failed one) says: the capture and its format, frames
loaded / posed / used and the photos skipped with the warning giving the reasons, where the poses
came from (given, refined, structure from motion) and the scale (source and how it was found),
seconds per step, mesh size, the texture bake's numbers (with --vr), every warning, and the error with
the step it happened in.

With --ray ADDRESS (or --ray local), each capture runs as a task on a Ray cluster, in a process of
its own as above, the memory its capture needs declared, a failed one run once more
(scripts/vortx_batch_ray.py); the reports are the same, with where it ran under "cluster".

Prints one line per finished stage; on failure prints `error: <reason>` and exits with status 1
(after finishing the other captures; 2 for bad arguments), also under `blender --background`
(sys.exit ends Blender with that status; --python-exit-code covers anything that escapes). The
.blend is saved under a temporary name and renamed at the very end, so a failed capture leaves none.
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from contextlib import contextmanager, redirect_stdout
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterator, Optional, Sequence, TextIO

sys.path.insert(0, str(Path(__file__).resolve().parent))  # Blender does not put the script's folder on sys.path
from _extension_dev import ExtensionLoadError, enable, find_extension, mount_checkout, unmount  # noqa: E402

# The reconstruction flags are generated from this checkout's ReconSettings (plain dataclasses, no
# torch), the one source the CLI and the Blender properties share.
sys.path.insert(1, str(Path(__file__).resolve().parent.parent))
from engine.poses.camera_height import DEFAULT_CAMERA_HEIGHT_M  # noqa: E402
from engine.poses.prepare import KEEP_POSES_HELP  # noqa: E402
from engine.recon.presets import (add_quality_argument, quality_of, refuse_unused_quality,  # noqa: E402
                                  settings_from_quality_arguments)
from engine.recon.settings import (ReconSettings, add_setting_arguments, given_settings,  # noqa: E402
                                   refuse_ignored_settings, refuse_untextured_settings)

EXPORT_SUFFIXES = (".glb", ".gltf", ".ply", ".obj", ".usdz")
REPORT_SUFFIX = ".report.json"
BATCH_REPO = "vortx_checkout"  # repository name when this checkout is mounted: bl_ext.vortx_checkout.vortx


class BatchError(Exception):
    """A failure the user can act on; printed as `error: <message>`."""


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
    parser.add_argument("--skip-poses", action="store_true", help="never run structure from motion; fail if no frame has a pose")
    parser.add_argument("--refine-poses", action="store_true",
                        help="refine the capture's given poses against the photos (Blender's Refine Poses) before reconstructing")
    parser.add_argument("--keep-poses", action="store_true", help=KEEP_POSES_HELP)
    parser.add_argument("--vr", action="store_true",
                        help="the VR preset: after Reconstruct, Bake Texture (decimated to --face-budget faces, a "
                             "--texture-size texture from the photos); --export .glb or .obj then carries the texture")
    parser.add_argument("--ray", metavar="ADDRESS",
                        help="run the captures as tasks on the Ray cluster at ADDRESS (HOST:PORT, from `ray start --head`), "
                             "or on one started on this machine for the run ('local'); see scripts/vortx_batch_ray.py")
    parser.add_argument("--ray-cpus", type=float, default=1.0,
                        help="with --ray: CPU cores each capture's task reserves (its torch threads follow) (default %(default)s)")
    return parser


def parse_arguments(args: Sequence[str]) -> argparse.Namespace:
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
    except Exception as error:  # engine.errors.VortxError of this checkout's engine
        parser.error(str(error))
    return args


@dataclass
class CaptureJob:
    """One capture of the batch and where its outputs go."""

    capture: Path
    blend: Path
    report: Path
    export: Optional[Path] = None


@dataclass
class CaptureReport:
    """What the batch did with one capture; written as NAME.report.json."""

    capture: str
    status: str = "failed"  # "ok" | "failed"
    error: Optional[str] = None
    failed_step: Optional[str] = None
    blend: Optional[str] = None
    export: Optional[str] = None
    capture_format: Optional[str] = None
    resolution: Optional[list[int]] = None
    frames: dict[str, Any] = field(default_factory=dict)  # loaded, posed, used, skipped (names), skip_reasons
    poses: dict[str, Any] = field(default_factory=dict)  # source, status, refined, scale_source, scale_description
    mesh: dict[str, Any] = field(default_factory=dict)  # vertices, faces, blend_bytes, export_bytes
    texture: dict[str, Any] = field(default_factory=dict)  # with --vr: the bake's settings and stats (vortx_texture)
    timings_s: dict[str, float] = field(default_factory=dict)  # per step, and total
    warnings: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    quality: Optional[str] = None  # the preset the settings match (--quality, changed by explicit flags: "custom")

    def warn(self, messages: Sequence[str]) -> None:
        self.warnings += [m for m in messages if m not in self.warnings]

    def write(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = path.with_name(f".{path.name}.partial")
        temporary.write_text(json.dumps(asdict(self), indent=1) + "\n")
        os.replace(temporary, path)


def capture_name(capture: Path) -> str:
    """The output name of a capture: its folder's name (a transforms.json file: its folder's), a video's stem."""
    capture = capture.absolute()
    if capture.suffix.lower() == ".json":
        return capture.parent.name or "capture"
    return (capture.stem if capture.is_file() else capture.name) or "capture"


def plan_jobs(args: argparse.Namespace, captures: list[Path]) -> list[CaptureJob]:
    """Output paths per capture: --out itself for one .blend, else NAME.* in the --out folder (names made unique)."""
    if args.single:
        export = args.export if args.export is not None else None
        return [CaptureJob(captures[0], args.out, args.out.with_name(args.out.stem + REPORT_SUFFIX), export)]
    jobs, used = [], set()
    for capture in captures:
        name, n = capture_name(capture), 2
        while name in used:
            name, n = f"{capture_name(capture)}_{n}", n + 1
        used.add(name)
        export = args.out / f"{name}{args.export_suffix}" if args.export is not None else None
        jobs.append(CaptureJob(capture, args.out / f"{name}.blend", args.out / f"{name}{REPORT_SUFFIX}", export))
    return jobs


def expand_captures(captures: list[Path], out: Path, detect_format: Callable[[Path], str],
                    not_a_capture: type[Exception], file_suffixes: Sequence[str]) -> list[Path]:
    """A single folder that is no capture itself but holds captures -> its sub-folders and capture files
    (each then gets a report; one that is no capture fails with the loader's reason). Else as given."""
    if len(captures) != 1 or not captures[0].is_dir():
        return captures
    folder = captures[0]
    try:
        detect_format(folder)
        return captures
    except not_a_capture:
        pass
    def is_capture(path: Path) -> bool:
        try:
            detect_format(path)
            return True
        except not_a_capture:
            return False

    out = out.absolute()
    candidates = sorted(p for p in folder.iterdir() if not p.name.startswith(".") and p.absolute() != out
                        and (p.is_dir() or p.suffix.lower() in file_suffixes))
    detected = {p for p in candidates if is_capture(p)}
    if not detected:
        return captures  # the import then says why the folder is no capture
    return [p for p in candidates if p in detected or p.is_dir()]


def say(step: int, total: int, stage: str, detail: str, started: float) -> None:
    print(f"vortx [{step}/{total}] {stage}: {detail} ({time.perf_counter() - started:.1f} s)", flush=True)


class _Tee(io.TextIOBase):
    """Writes through to `stream` and keeps a copy: Blender prints an operator's reports to sys.stdout
    ("Warning: ..."), the only place a script calling bpy.ops can read them."""

    def __init__(self, stream: TextIO) -> None:
        self.stream, self.copy = stream, io.StringIO()

    def write(self, text: str) -> int:
        self.copy.write(text)
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


def run_operator(label: str, operator: Callable[..., set[str]], warnings: Optional[list[str]] = None, **kwargs: Any) -> None:
    """Call a vortx operator; BatchError with its own error report when it fails. Its WARNING reports
    are appended to `warnings`.

    bpy.ops turns an operator's ERROR report into a RuntimeError("Error: <message>"); a CANCELLED
    return without one means the operator refused (its poll failed) or was cancelled.
    """
    if not operator.poll():
        raise BatchError(f"{label} cannot run now (its preconditions are not met)")
    tee = _Tee(sys.stdout)
    try:
        with redirect_stdout(tee):
            outcome = operator(**kwargs)
    except RuntimeError as error:
        message = " ".join(str(error).split())
        raise BatchError(message.removeprefix("Error: ")) from None
    finally:
        if warnings is not None:
            warnings += [line.removeprefix("Warning: ") for line in tee.copy.getvalue().splitlines()
                         if line.startswith("Warning: ")]
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


class Step:
    """Times one step into the report and names it as the failed step when it raises."""

    def __init__(self, report: CaptureReport) -> None:
        self.report = report

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        started = time.perf_counter()
        self.report.failed_step = name
        try:
            yield
        finally:
            self.report.timings_s[name] = round(time.perf_counter() - started, 3)
        self.report.failed_step = None


def run(args: argparse.Namespace, addon: ModuleType, job: CaptureJob, report: CaptureReport) -> None:
    """One capture: import, poses, reconstruct, save (under a temporary name), export, then rename the
    .blend into place; fills `report` on the way. Raises BatchError (or anything else) on failure."""
    import bpy

    steps = 4 + (job.export is not None) + bool(args.vr)
    number = iter(range(1, steps + 1))  # the printed step numbers, in order
    step = Step(report)
    warnings: list[str] = []
    bpy.ops.wm.read_homefile(use_empty=True)  # no default cube/camera/light in the result
    scene = bpy.context.scene
    settings = scene.vortx
    settings.camera_height = args.camera_height  # scales the poses Estimate Poses finds
    # --frame: Import Capture shows the capture in these coordinates (and refuses 'capture' for photos
    # without poses, as `engine reconstruct` does); the export writes the mesh in them.
    settings.output_frame = args.settings.frame.upper()

    started = time.perf_counter()
    with step("import capture"):
        try:
            run_operator("Import Capture", bpy.ops.vortx.import_capture, warnings, filepath=str(job.capture.resolve()))
        finally:
            report.warn(warnings)
        loaded = addon.vortx_blender.capture.loaded_capture(scene, Path(settings.capture_path))
        report.capture_format = settings.capture_format
        report.resolution = [settings.resolution_x, settings.resolution_y]
        skipped = list(loaded.skipped) if loaded is not None else []
        capture_warnings = list(loaded.warnings) if loaded is not None else []
        report.warn(capture_warnings)
        report.frames = {"loaded": settings.frame_count, "posed": settings.posed_frame_count, "used": 0,
                         "skipped": skipped,
                         "skip_reasons": [w for w in capture_warnings if any(name in w for name in skipped)]}
    say(next(number), steps, "import capture", f"{settings.frame_count} frames ({settings.capture_format}), "
        f"{settings.posed_frame_count} posed, {settings.resolution_x}x{settings.resolution_y}", started)

    started = time.perf_counter()
    with step("poses"):
        estimated = settings.posed_frame_count == 0
        try:
            if estimated:
                if args.skip_poses:
                    raise BatchError(f"no frame of {job.capture} has a camera pose and --skip-poses was given")
                run_operator("Estimate Poses", bpy.ops.vortx.estimate_poses, warnings)
                detail = settings.pose_status
            elif settings.posed_frame_count < settings.frame_count:
                # Structure from motion would replace the capture's own (usually metric) poses for a few
                # frames' sake; reconstruct from the posed ones instead.
                detail = f"{settings.pose_status}; the {settings.frame_count - settings.posed_frame_count} frames without a pose are left out"
            else:
                detail = settings.pose_status
            # Poses SfM just estimated are already bundle-adjusted; given poses are refined here when asked,
            # or when Import Capture's check found them off (as engine reconstruct does; --keep-poses not).
            refine = not estimated and (args.refine_poses or (bool(settings.pose_check) and not args.keep_poses))
            settings.keep_given_poses = bool(args.keep_poses)
            if refine:
                run_operator("Refine Poses", bpy.ops.vortx.refine_poses, warnings)
                detail = f"{settings.pose_status}; refined against the photos"
        finally:
            report.warn(warnings)
            report.poses = {"source": "structure from motion" if estimated else "given",
                            "refined": bool(not estimated and "refined" in settings.pose_status), "status": settings.pose_status,
                            "scale_source": settings.scale_source, "scale_description": settings.scale_description,
                            "scale_relative_sigma": round(float(settings.scale_uncertainty), 4),
                            "pose_check": settings.pose_check,
                            "metric": bool(settings.poses_metric)}
        report.frames["posed"] = settings.posed_frame_count
        # The similarity between the capture's own coordinates and the result's Z-up world, both ways.
        report.poses["frame"] = json.loads(settings.capture_frame) if settings.capture_frame else None
    say(next(number), steps, "poses", detail, started)

    started = time.perf_counter()
    with step("reconstruct"):
        apply_recon_settings(addon, settings, args.settings)
        try:
            run_operator("Reconstruct", bpy.ops.vortx.reconstruct, warnings)
        finally:
            report.warn(warnings)
        results = addon.vortx_blender.result.result_objects(scene)
        if not results:
            raise BatchError("Reconstruct finished but left no result mesh in the scene")
        mesh_object = results[-1]
        report.frames["used"] = settings.posed_frame_count  # the reconstruction reads every posed frame
        report.mesh = {"name": mesh_object.name, "vertices": len(mesh_object.data.vertices),
                       "faces": len(mesh_object.data.polygons)}
    say(next(number), steps, "reconstruct", f"'{mesh_object.name}': {len(mesh_object.data.vertices)} vertices, "
        f"{len(mesh_object.data.polygons)} faces", started)

    if args.vr:
        started = time.perf_counter()
        with step("texture"):
            try:
                run_operator("Bake Texture", bpy.ops.vortx.bake_texture, warnings)
            finally:
                report.warn(warnings)
            baked = addon.vortx_blender.texture.bake_summary(mesh_object)
            if baked is None:
                raise BatchError(f"Bake Texture finished but '{mesh_object.name}' has no texture")
            report.texture = baked
            report.mesh.update(vertices=len(mesh_object.data.vertices), faces=len(mesh_object.data.polygons))
            if job.export is not None and job.export.suffix.lower() == ".ply":
                report.warn([f"{job.export.name}: PLY files hold no texture, so the vertex colours are written; "
                             "export .glb or .obj for the textured mesh"])
        say(next(number), steps, "texture", f"{baked['texture_size']} px, {len(mesh_object.data.polygons)} faces "
            f"(face budget {baked['face_budget']})", started)

    out = job.blend.resolve()
    # Saved under a temporary name and renamed only once everything else succeeded: a failed or
    # interrupted capture leaves no .blend that looks finished.
    partial = out.with_name(f".{out.stem}.partial.blend")
    try:
        started = time.perf_counter()
        with step("save"):
            out.parent.mkdir(parents=True, exist_ok=True)
            if "FINISHED" not in bpy.ops.wm.save_as_mainfile(filepath=str(partial), copy=True):
                raise BatchError(f"could not save {out}")
        say(next(number), steps, "save", str(out), started)

        if job.export is not None:
            started = time.perf_counter()
            with step("export"):
                try:
                    written = addon.vortx_blender.export.export_result(mesh_object, job.export.resolve(), bpy.context.view_layer)
                except addon.engine.errors.VortxError as error:
                    raise BatchError(str(error)) from None
                report.export = str(written)
                report.mesh["export_bytes"] = Path(written).stat().st_size
            say(next(number), steps, "export", str(written), started)
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)
    report.blend = str(out)
    report.mesh["blend_bytes"] = out.stat().st_size


def run_all(args: argparse.Namespace, addon: Optional[ModuleType], jobs: list[CaptureJob],
            load_error: Optional[str] = None) -> int:
    """Every capture in turn, each report written as soon as it is done; 1 when any failed, else 0."""
    failed: list[str] = []
    for number, job in enumerate(jobs, start=1):
        if len(jobs) > 1:
            print(f"vortx capture {number}/{len(jobs)}: {job.capture}", flush=True)
        report = CaptureReport(capture=str(job.capture.absolute()), settings=asdict(args.settings),
                               quality=quality_of(args.settings) or "custom")
        started = time.perf_counter()
        try:
            if load_error is not None:
                raise BatchError(load_error)
            if not job.capture.exists():
                raise BatchError(f"{job.capture} does not exist")
            assert addon is not None
            run(args, addon, job, report)
            report.status, report.failed_step = "ok", None
        except BatchError as error:
            report.error = str(error)
        except Exception as error:  # a bug rather than a user error: keep the traceback
            traceback.print_exc()
            report.error = f"unexpected {type(error).__name__}: {' '.join(str(error).split())}"
        report.timings_s["total"] = round(time.perf_counter() - started, 3)
        report.write(job.report)
        if report.error is not None:
            failed.append(str(job.capture))
            where = f"{job.capture}: " if len(jobs) > 1 else ""
            print(f"error: {where}{report.error}", file=sys.stderr, flush=True)
    if len(jobs) > 1:
        print(f"vortx batch: {len(jobs) - len(failed)} of {len(jobs)} captures reconstructed"
              + (f"; failed: {', '.join(failed)}" if failed else "") + f"; reports in {args.out}", flush=True)
    return 1 if failed else 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_arguments(script_arguments(sys.argv if argv is None else argv))
    if args.single and not args.captures[0].exists():  # no need to start the extension for that
        return run_all(args, None, plan_jobs(args, args.captures))
    try:
        import bpy  # noqa: F401  (Blender's own, or the bpy module under plain python)

        with vortx_extension() as addon:
            engine = addon.engine.__name__  # the extension's engine package (its dependencies are loaded)
            detect, video = (importlib.import_module(f"{engine}.capture.{m}") for m in ("detect", "video"))
            captures = args.captures if args.single else expand_captures(
                args.captures, args.out, detect.detect_format, importlib.import_module(f"{engine}.errors").CaptureError,
                video.VIDEO_SUFFIXES + (".json",))
            if args.ray is not None:
                from vortx_batch_ray import run_on_ray  # imports ray; nothing else needs it

                return run_on_ray(args, argument_parser(), plan_jobs(args, captures), addon.engine,
                                  lambda job: CaptureReport(capture=str(job.capture.absolute()), settings=asdict(args.settings),
                                                            quality=quality_of(args.settings) or "custom"),
                                  Path(__file__), bpy.app.binary_path)
            return run_all(args, addon, plan_jobs(args, captures))
    except ExtensionLoadError as error:
        return run_all(args, None, plan_jobs(args, args.captures), load_error=str(error))


if __name__ == "__main__":
    sys.exit(main())
