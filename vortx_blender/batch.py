"""The batch on one capture inside Blender (scripts/vortx_batch.py): the extension's own operators,
called exactly as a user clicks them (Import Capture, Estimate or Refine Poses, Reconstruct, Bake
Texture with --vr), then the .blend saved and the mesh exported; the report filled on the way.

The command line, the output plan, the report and the loop over captures are Blender-free
(engine/batch/); so is the Ray driver, which this module hands the captures to with --ray. The
command line is read here again with the extension's own engine (the script read it with the
checkout's before loading the extension), so that the settings are the classes this engine checks.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
from contextlib import redirect_stdout
from functools import partial
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, TextIO

import bpy

from ..engine.batch.arguments import argument_parser, parse_arguments
from ..engine.batch.plan import CaptureJob, expand_captures, plan_jobs
from ..engine.batch.ray_cluster import run_on_ray
from ..engine.batch.report import BatchError, CaptureReport, StepTimer, blank_report, print_progress
from ..engine.batch.runner import run_jobs
from ..engine.errors import VortxError
from ..engine.recon.settings import ReconSettings
from .capture import loaded_capture
from .export import export_result
from .poses import REFINEMENT_RECORD
from .reconstruct import write_scene_settings
from .result import result_objects
from .texture import bake_summary


class OutputCopy(io.TextIOBase):
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
    output = OutputCopy(sys.stdout)
    try:
        with redirect_stdout(output):
            outcome = operator(**kwargs)
    except RuntimeError as error:
        message = " ".join(str(error).split())
        raise BatchError(message.removeprefix("Error: ")) from None
    finally:
        if warnings is not None:
            warnings += [line.removeprefix("Warning: ") for line in output.copy.getvalue().splitlines()
                         if line.startswith("Warning: ")]
    if "FINISHED" not in outcome:
        raise BatchError(f"{label} did not finish ({', '.join(sorted(outcome))})")


def apply_recon_settings(settings: Any, recon: ReconSettings) -> None:
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
        write_scene_settings(settings, recon)
    except ValueError as error:
        if recon.device != "cpu":  # the enum offers CUDA only when PyTorch sees a GPU
            raise BatchError(f"--device {recon.device}: PyTorch sees no CUDA GPU here (or is not installed); "
                             "use --device cpu") from None
        raise BatchError(str(error)) from None


def run_capture(args: argparse.Namespace, job: CaptureJob, report: CaptureReport) -> None:
    """One capture: import, poses, reconstruct, save (under a temporary name), export, then rename the
    .blend into place; fills `report` on the way. Raises BatchError (or anything else) on failure."""
    steps = 4 + (job.export is not None) + bool(args.vr)
    number = iter(range(1, steps + 1))  # the printed step numbers, in order
    step = StepTimer(report)
    warnings: list[str] = []
    bpy.ops.wm.read_homefile(use_empty=True)  # no default cube/camera/light in the result
    scene = bpy.context.scene
    settings = scene.vortx
    settings.camera_height = args.camera_height  # scales the poses Estimate Poses finds
    settings.sfm_features = args.features.upper()  # what Estimate Poses matches
    # --frame: Import Capture shows the capture in these coordinates (and refuses 'capture' for photos
    # without poses, as `engine reconstruct` does); the export writes the mesh in them.
    settings.output_frame = args.settings.frame.upper()

    started = time.perf_counter()
    with step("import capture"):
        try:
            run_operator("Import Capture", bpy.ops.vortx.import_capture, warnings, filepath=str(job.capture.resolve()))
        finally:
            report.warn(warnings)
        loaded = loaded_capture(scene, Path(settings.capture_path))
        report.capture_format = settings.capture_format
        report.resolution = [settings.resolution_x, settings.resolution_y]
        skipped = list(loaded.skipped) if loaded is not None else []
        capture_warnings = list(loaded.warnings) if loaded is not None else []
        report.warn(capture_warnings)
        report.frames = {"loaded": settings.frame_count, "posed": settings.posed_frame_count, "used": 0,
                         "skipped": skipped,
                         "skip_reasons": [w for w in capture_warnings if any(name in w for name in skipped)]}
    print_progress(next(number), steps, "import capture", f"{settings.frame_count} frames ({settings.capture_format}), "
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
        if scene.get(REFINEMENT_RECORD):  # the refinement's numbers and time per stage
            report.poses["refinement"] = json.loads(scene[REFINEMENT_RECORD])
    print_progress(next(number), steps, "poses", detail, started)

    started = time.perf_counter()
    with step("reconstruct"):
        apply_recon_settings(settings, args.settings)
        try:
            run_operator("Reconstruct", bpy.ops.vortx.reconstruct, warnings)
        finally:
            report.warn(warnings)
        results = result_objects(scene)
        if not results:
            raise BatchError("Reconstruct finished but left no result mesh in the scene")
        mesh_object = results[-1]
        report.frames["used"] = settings.posed_frame_count  # the reconstruction reads every posed frame
        report.mesh = {"name": mesh_object.name, "vertices": len(mesh_object.data.vertices),
                       "faces": len(mesh_object.data.polygons)}
    print_progress(next(number), steps, "reconstruct", f"'{mesh_object.name}': {len(mesh_object.data.vertices)} vertices, "
                   f"{len(mesh_object.data.polygons)} faces", started)

    if args.vr:
        started = time.perf_counter()
        with step("texture"):
            try:
                run_operator("Bake Texture", bpy.ops.vortx.bake_texture, warnings)
            finally:
                report.warn(warnings)
            baked = bake_summary(mesh_object)
            if baked is None:
                raise BatchError(f"Bake Texture finished but '{mesh_object.name}' has no texture")
            report.texture = baked
            report.mesh.update(vertices=len(mesh_object.data.vertices), faces=len(mesh_object.data.polygons))
            if job.export is not None and job.export.suffix.lower() == ".ply":
                report.warn([f"{job.export.name}: PLY files hold no texture, so the vertex colours are written; "
                             "export .glb or .obj for the textured mesh"])
        print_progress(next(number), steps, "texture", f"{baked['texture_size']} px, {len(mesh_object.data.polygons)} faces "
                       f"(face budget {baked['face_budget']})", started)

    out = job.blend.resolve()
    # Saved under a temporary name and renamed only once everything else succeeded: a failed or
    # interrupted capture leaves no .blend that looks finished.
    partial_blend = out.with_name(f".{out.stem}.partial.blend")
    try:
        started = time.perf_counter()
        with step("save"):
            out.parent.mkdir(parents=True, exist_ok=True)
            if "FINISHED" not in bpy.ops.wm.save_as_mainfile(filepath=str(partial_blend), copy=True):
                raise BatchError(f"could not save {out}")
        print_progress(next(number), steps, "save", str(out), started)

        if job.export is not None:
            started = time.perf_counter()
            with step("export"):
                try:
                    written = export_result(mesh_object, job.export.resolve(), bpy.context.view_layer)
                except VortxError as error:
                    raise BatchError(str(error)) from None
                report.export = str(written)
                report.mesh["export_bytes"] = Path(written).stat().st_size
            print_progress(next(number), steps, "export", str(written), started)
        os.replace(partial_blend, out)
    finally:
        partial_blend.unlink(missing_ok=True)
    report.blend = str(out)
    report.mesh["blend_bytes"] = out.stat().st_size


def run_command_line(arguments: Sequence[str], script: Path) -> int:
    """The batch of scripts/vortx_batch.py (`script`) in this Blender: its captures in turn, or with
    --ray on the cluster; 1 when any failed, else 0."""
    args = parse_arguments(arguments)
    jobs = plan_jobs(args, captures_to_run(args))
    return run_batch_on_ray(args, jobs, script) if args.ray is not None else run_batch(args, jobs)


def captures_to_run(args: argparse.Namespace) -> list[Path]:
    """The captures of the command line; one folder of captures (with an --out folder) -> each of them."""
    return args.captures if args.single else expand_captures(args.captures, args.out)


def run_batch(args: argparse.Namespace, jobs: list[CaptureJob]) -> int:
    """Every capture in turn in this Blender; 1 when any failed, else 0."""
    return run_jobs(args, jobs, partial(run_capture, args))


def run_batch_on_ray(args: argparse.Namespace, jobs: list[CaptureJob], script: Path) -> int:
    """Every capture as a task on the Ray cluster at args.ray, each in a process of its own running
    `script` as this process runs it (Blender itself, or this Python with the bpy module)."""
    return run_on_ray(args, argument_parser(), jobs, lambda job: blank_report(job, args.settings), script,
                      bpy.app.binary_path)
