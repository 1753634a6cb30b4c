"""The Reconstruct job: scene settings -> engine ReconSettings -> `engine.recon.reconstruct` off the main
thread -> a cleaned mesh ready to insert.

Everything the worker needs is read on the main thread into a `ReconRequest` (plain data: the posed
capture rebuilt from the camera objects, ReconSettings, clean-up options), and checked there, so
mistakes such as "no posed cameras" or a missing weights file are reported at once instead of after a
thread start. The worker imports torch (through the engine driver) only when a run actually starts:
the extension registers and draws without torch installed.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional

import bpy

from ..engine.capture import Capture
from ..engine.errors import PoseError, VortxError, WeightsError
from ..engine.jobs import CancelToken, ProgressCallback
from ..engine.mesh_io import Mesh
from ..engine.meshops import PieceStats, remove_small_pieces
from ..engine import poses as engine_poses  # its refine_poses looked up at call time: tests stand in for it
from ..engine.poses.prepare import SFM_NEVER, prepare_capture
from ..engine.recon import plan_reconstruction
from ..engine.recon.settings import BLENDER, ReconSettings, setting_fields
from .cameras import posed_capture_from_scene
from .capture import apply_prepared, scene_camera_height
from .frame import show_frame
from .jobs import JobFunction
from .properties import blender_name, scene_value, write_scene_value
from .result import Provenance

if TYPE_CHECKING:
    from ..engine.recon import ReconResult, Tile

# engine.recon.network.RANDOM, spelled out because that module imports torch (the tests check they agree).
RANDOM_WEIGHTS = "random"
# Suffixes of PyTorch pickles: VoRTX reads weights only as safetensors (never unpickles a download).
_CHECKPOINT_SUFFIXES = (".ckpt", ".pt", ".pth", ".bin")


@dataclass(frozen=True)
class CleanupOptions:
    """Blender-side output options (VR-ready meshes): small-piece removal and decimation."""

    min_piece_faces: int = 0
    min_piece_fraction: float = 0.0
    target_faces: int = 0  # 0 = keep every face

    @staticmethod
    def from_scene(settings: Any) -> "CleanupOptions":
        return CleanupOptions(
            min_piece_faces=int(settings.min_piece_faces),
            min_piece_fraction=float(settings.min_piece_fraction),
            target_faces=int(settings.target_faces),
        )


@dataclass
class ReconRequest:
    capture: Capture
    settings: ReconSettings
    weights_source: str  # DEFAULT / FILE / RANDOM
    cleanup: CleanupOptions
    result_mode: str  # REPLACE / ADD
    capture_path: str
    refine_poses: bool = False  # the pose check found the given poses off: refine them before stereo


@dataclass
class ReconOutcome:
    """What the worker hands back: the engine result (stats, tiles), and the mesh to insert."""

    result: "ReconResult"
    mesh: Mesh  # the engine mesh after small-piece removal
    pieces: PieceStats
    warnings: list[str] = field(default_factory=list)
    refined: Optional[engine_poses.RefineResult] = None  # the poses refined before reconstructing (request.refine_poses)


def weights_from_scene(settings: Any) -> Optional[str]:
    """ReconSettings.weights for the scene's choice: None (default), "random", or a checked file path."""
    source = settings.weights_source
    if source == "RANDOM":
        return RANDOM_WEIGHTS
    if source == "DEFAULT":
        return None
    if not settings.weights_path:
        raise WeightsError("Weights is set to File but no weights file is chosen: pick a .safetensors file in Reconstruction > Model")
    path = Path(bpy.path.abspath(settings.weights_path))
    if path.suffix.lower() in _CHECKPOINT_SUFFIXES:
        raise WeightsError(
            f"{path.name} is a PyTorch checkpoint. Convert it once with "
            f"'python -m engine convert-official {path.name} --out vortx.safetensors' and choose the .safetensors file"
        )
    if path.suffix.lower() != ".safetensors":
        raise WeightsError(f"{path.name}: weights must be a .safetensors file")
    if not path.is_file():
        raise WeightsError(f"weights file {path} does not exist")
    return str(path)


def recon_settings_from_scene(settings: Any, with_weights: bool = True) -> ReconSettings:
    """The engine settings for scene.vortx, validated (raises VortxError naming the setting).

    Every ReconSettings field offered to Blender is read from its property by its type (no field is
    mapped by hand); the weights come from the Weights source / file choice. with_weights=False
    leaves `weights` at its default and skips checking the weights choice, for work that runs no
    network (planning the tiles).
    """
    values = {f.name: scene_value(f, getattr(settings, blender_name(f))) for f in setting_fields(BLENDER)}
    recon = ReconSettings(weights=weights_from_scene(settings) if with_weights else None, **values)
    recon.validate()
    return recon


def write_scene_settings(settings: Any, recon: ReconSettings) -> None:
    """ReconSettings -> scene.vortx for every field offered to Blender (the batch script's flags).

    Raises ValueError naming the field when a value cannot be set (e.g. device "cuda" where PyTorch
    sees no GPU: the enum does not offer it).
    """
    for f in setting_fields(BLENDER):
        write_scene_value(settings, f, getattr(recon, f.name))




def scene_capture(scene: "bpy.types.Scene") -> Capture:
    """The posed capture rebuilt from the scene's capture cameras, prepared (`engine.poses.prepare`) as
    the CLI prepares a capture; PoseError when there is none.

    Import Capture and Estimate Poses already place the cameras in the prepared world, where preparing
    again changes nothing. Cameras from elsewhere (a .blend saved by an older version, with a COLMAP
    model's tilted world) are moved to the prepared world here, main thread, before the run, so the
    mesh and the cameras stay together; the capture summary's pose status says what was done.
    """
    capture = posed_capture_from_scene(scene)
    if capture is None or not capture.posed_frames:
        raise PoseError(
            "The scene has no posed capture cameras: import a capture with poses (transforms.json, COLMAP, "
            "ScanNet) or run Estimate Poses first"
        )
    prepared = prepare_capture(capture, camera_height=scene_camera_height(scene.vortx), sfm=SFM_NEVER)
    if prepared.moved():
        print(f"VoRTX: capture cameras moved to the reconstruction world: {prepared.description}")
        settings = scene.vortx
        skipped = (settings.skipped_count, settings.skipped_names)  # the cameras do not carry them
        apply_prepared(scene, prepared, settings.capture_path)
        settings.skipped_count, settings.skipped_names = skipped
        show_frame(scene, world_change=prepared.similarity)  # the capture's own coordinates map to the new world
    return prepared.capture


def request_from_scene(scene: "bpy.types.Scene") -> ReconRequest:
    """Everything a Reconstruct run needs, read from `scene` (main thread). Raises VortxError."""
    settings = scene.vortx
    capture = scene_capture(scene)
    return ReconRequest(
        capture=capture,
        settings=recon_settings_from_scene(settings),
        weights_source=settings.weights_source,
        cleanup=CleanupOptions.from_scene(settings),
        result_mode=settings.result_mode,
        capture_path=settings.capture_path,
        # The same rule as `engine reconstruct`: given poses the photo check found off are refined first.
        refine_poses=bool(settings.pose_check) and not settings.keep_given_poses,
    )


def reconstruct_job(request: ReconRequest, on_tiles: Callable[[list["Tile"]], None]) -> JobFunction:
    """A bpy-free job function: plan, hand the plan's tiles to `on_tiles` (the overlay, whose colours
    then follow the engine's in-place state changes), reconstruct, drop small pieces."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> ReconOutcome:
        from ..engine.recon import driver  # defers torch: the extension registers and draws without it

        if request.settings.weights is None:
            _check_default_weights()
        capture, refined = request.capture, None
        if request.refine_poses:
            # In the scene's world already: the refinement fits its result back onto the given poses.
            refined = engine_poses.refine_poses(capture, progress=progress, cancel=cancel)
            capture = refined.capture
        plan = plan_reconstruction(capture, request.settings, progress, cancel)
        on_tiles(plan.tiles)
        result = driver.reconstruct(capture, request.settings, progress, cancel, plan=plan)
        if result.is_empty:
            raise VortxError(f"No mesh: {result.message}")
        cancel.check()
        cleanup = request.cleanup
        mesh, pieces = remove_small_pieces(result.mesh, cleanup.min_piece_faces, cleanup.min_piece_fraction)
        if len(mesh.faces) == 0:
            raise VortxError(
                f"every one of the {pieces.pieces} mesh pieces is smaller than the minimum piece size; "
                "lower Min Piece Faces / Min Piece Size"
            )
        warnings = (list(refined.warnings) if refined is not None else []) + list(result.warnings)
        return ReconOutcome(result, mesh, pieces, warnings, refined)

    return run


def plan_tiles_job(capture: Capture, settings: ReconSettings) -> JobFunction:
    """A job function planning the run (keyframes, bounds, tiles, views per tile) without a network:
    numpy only, so the tile overlay can be previewed before reconstructing."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> list["Tile"]:
        return plan_reconstruction(capture, settings, progress, cancel).tiles

    return run


def _check_default_weights() -> None:
    # The engine's own message speaks CLI (--weights); this one names the panel settings.
    from ..engine.model import weights  # defers torch: the extension registers and draws without it

    path = Path(weights.DEFAULT_WEIGHTS)  # read at call time: the one place that defines it
    if not path.is_file():
        raise WeightsError(
            f"The default VoRTX weights are not installed (expected at {path}). In Reconstruction > Model set "
            "Weights to File (a .safetensors, e.g. the official checkpoint converted with "
            "'python -m engine convert-official') or to Random (tests the pipeline; the mesh is meaningless)"
        )


def run_summary(outcome: ReconOutcome) -> dict[str, Any]:
    """The JSON-friendly part of the engine stats kept on the result object."""
    stats = outcome.result.stats
    keys = ("device", "frames", "keyframes", "image_size", "levels", "tiles", "timings_s", "mesh", "bounds", "grid")
    summary = {key: stats[key] for key in keys if key in stats}
    summary["pieces"] = outcome.pieces.to_dict()
    return summary


def provenance(request: ReconRequest, outcome: ReconOutcome) -> Provenance:
    settings = request.settings.to_dict()
    settings["blender"] = {"weights_source": request.weights_source, "result_mode": request.result_mode, **asdict(request.cleanup)}
    weights = str(outcome.result.stats.get("model", {}).get("weights", request.settings.weights))
    return Provenance(capture_path=request.capture_path, settings=settings, weights=weights, stats=run_summary(outcome))
