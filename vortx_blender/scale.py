"""Set Scale: the user picks two points and types their real distance; the capture becomes metric.

Picked points are either two selected vertices in Edit Mode (of a result mesh, the sparse point cloud,
or any mesh standing in the capture's world) or two selected capture cameras in Object Mode (their
exact stored camera centres). The factor comes from `engine.poses.scale_from_known_distance` and the
capture (poses and sparse points) is scaled by `engine.poses.rescale_capture`, the implementation
behind the CLI's `--known-distance`, about the world origin (the floor stays at z = 0). Result meshes
are scaled by the same factor about the origin.

Everything that can fail (the picking, the distance, the engine's checks) happens before the first
write, so a refused Set Scale changes nothing. The scene then says "known distance" as its scale
source and the capture is metric, so the next reconstruction uses the cameras as they are
(`engine.poses.prepare` never rescales a metric capture).
"""

from __future__ import annotations

from dataclasses import dataclass
import bmesh
import bpy
import numpy as np
from mathutils import Matrix

from ..engine.errors import PoseError
from ..engine.poses import rescale_capture, scale_from_known_distance
from ..engine.poses.align import Similarity
from ..engine.poses.prepare import PreparedCapture
from .cameras import PROP_POSE, is_capture_camera, move_capture_cameras, posed_capture_from_scene
from .frame import show_frame
from .point_cloud import find_point_cloud, scale_point_cloud
from .result import result_objects
from .scene_objects import engine_matrix, find_frame_empty, set_engine_matrix

KNOWN_DISTANCE = "known distance"  # the scale source Set Scale leaves (engine.poses.gravity's name)


@dataclass(frozen=True)
class PickedPoint:
    label: str  # for the report: "camera VoRTX IMG_1" or "vertex 12 of VoRTX Result"
    position: np.ndarray  # (3,) float64 in the engine's world (whichever coordinates the scene shows)


@dataclass(frozen=True)
class ScaleChange:
    factor: float
    before: float  # distance between the picked points before, scene units
    metres: float
    description: str


def picked_points(context: "bpy.types.Context") -> list[PickedPoint]:
    """The two points the user picked: selected vertices of the meshes in Edit Mode, or the selected
    capture cameras in Object Mode. PoseError saying what to select when it is not exactly two."""
    if context.mode == "EDIT_MESH":
        points = _selected_vertices(context)
        what = "vertices"
        hint = ("select exactly two vertices (of the result mesh or the sparse points) in Edit Mode, "
                "or two capture cameras in Object Mode")
    else:
        points = [PickedPoint(f"camera {obj.name}", np.array(obj[PROP_POSE], dtype=np.float64).reshape(4, 4)[:3, 3])
                  for obj in context.selected_objects if is_capture_camera(obj)]
        what = "capture cameras"
        hint = ("select exactly two capture cameras in Object Mode, or two vertices (of the result mesh or the "
                "sparse points) in Edit Mode")
    if len(points) != 2:
        raise PoseError(f"Set Scale needs two picked points, {len(points)} {what} are selected: {hint}")
    return points


def _selected_vertices(context: "bpy.types.Context") -> list[PickedPoint]:
    points = []
    for obj in context.objects_in_mode_unique_data:
        if obj.type != "MESH":
            continue
        matrix = engine_matrix(obj, context.scene)
        bm = bmesh.from_edit_mesh(obj.data)
        for vertex in bm.verts:
            if vertex.select:
                local = np.array(vertex.co, dtype=np.float64)
                points.append(PickedPoint(f"vertex {vertex.index} of {obj.name}", matrix[:3, :3] @ local + matrix[:3, 3]))
    return points


def set_scale(scene: "bpy.types.Scene", picked: list[PickedPoint], metres: float) -> ScaleChange:
    """Scale the scene's capture cameras, sparse points and result meshes so the two `picked` points
    are `metres` apart; the capture is then metric with "known distance" as its scale source.

    Raises PoseError (nothing changed) for a distance that is not positive, points at the same spot,
    or a scene without capture cameras.
    """
    if len(picked) != 2:
        raise PoseError(f"Set Scale needs two picked points, got {len(picked)}")
    factor = scale_from_known_distance(picked[0].position, picked[1].position, metres)
    capture = posed_capture_from_scene(scene)
    if capture is None or not capture.posed_frames:
        raise PoseError("Set Scale needs the capture's cameras: import a capture with poses or run Estimate Poses first")
    rescaled = rescale_capture(capture, factor, points=capture.points)
    before = float(np.linalg.norm(picked[0].position - picked[1].position))
    description = (f"scale from a known distance: {picked[0].label} <-> {picked[1].label} = {metres:g} m "
                   f"(was {before:.4g} units) -> scaled x{factor:.4g}")

    # Writes start here; nothing below can fail on the user's input.
    move_capture_cameras(scene, [f.pose for f in rescaled.capture.frames])
    cloud = find_point_cloud(scene)
    if cloud is not None and rescaled.points is not None:
        scale_point_cloud(scene, cloud, rescaled.points)
    for obj in result_objects(scene):
        _scale_about_origin(scene, obj, factor)
    settings = scene.vortx
    prepared = PreparedCapture(rescaled.capture, KNOWN_DISTANCE, description)
    settings.poses_metric = True
    settings.pose_status = prepared.pose_status()
    settings.scale_source = KNOWN_DISTANCE
    # The capture's own coordinates map to the scaled world: shown in them, nothing moves.
    show_frame(scene, world_change=Similarity(np.eye(3), np.zeros(3), factor))
    if find_frame_empty(scene) is not None:
        description += ("; the scene shows the capture's own coordinates, which stay as they are: the world VoRTX "
                        "reconstructs in is now metric")
    settings.scale_description = description
    settings.scale_uncertainty = 0.0  # the user's measurement: taken as exact
    return ScaleChange(factor, before, float(metres), description)


def _scale_about_origin(scene: "bpy.types.Scene", obj: "bpy.types.Object", factor: float) -> None:
    """Engine-world positions x -> factor * x, keeping the object's rotation and unit scale: the mesh
    data scales by `factor` and the object's location with it (uniform scaling commutes with rotation)."""
    mesh = obj.data
    if mesh.is_editmode:
        bm = bmesh.from_edit_mesh(mesh)
        bmesh.ops.scale(bm, vec=(factor, factor, factor), verts=bm.verts)
        bmesh.update_edit_mesh(mesh)
    else:
        mesh.transform(Matrix.Scale(factor, 4))
        mesh.update()
    matrix = engine_matrix(obj, scene)
    matrix[:3, 3] *= factor
    set_engine_matrix(obj, scene, matrix)
