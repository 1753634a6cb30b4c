"""The GUI workflow's phone-capture variant (scripts/gui_workflow.py --phone-export DIR): a phone app's
export (e.g. the 3D Scanner App's "All Data" folder) imported and reconstructed with every default, as
a user does it in the window, with the README's screenshots of the imported capture and of the result.

Open the VoRTX tab -> Import Capture on the export (checked: every photo posed by ARKit, metric, the
sensor depth read, the cameras and the points from the depth in the scene; the viewport shows the points'
colours, Viewport Shading > Color > Attribute) -> Reconstruct with the panel as it is (stereo, Finish
Room, Sensor Depth on) -> the result framed from above at an angle across the walk (backface culling on,
the sparse points hidden, as a user looks into a room), then from a capture camera in the middle of the
walk."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Iterator, Optional

import bpy
import numpy as np
from bpy_extras.view3d_utils import location_3d_to_region_2d, region_2d_to_location_3d
from mathutils import Euler, Vector

from .report import WorkflowReport
from .steps import open_sidebar
from .window import addon, override, settle, shot, sidebar, view3d, wait_for_job

TILT_DEG = 50  # the overview's angle from straight down: the floor and the far wall both in view
FILL = 0.85  # the overview's points span this much of the free viewport's width or height
VIEW_LENS_MM = 24  # the viewport's lens from inside the corridor (Blender's default 50 mm sees a slot)


def phone_workflow(export: Path, report: WorkflowReport, quality: Optional[str] = None) -> Iterator[float]:
    """The steps, as a generator of seconds to wait before the next tick (bpy.app.timers); `quality`
    (PREVIEW, STANDARD, ...) is chosen in the panel's Quality menu before Reconstruct, None keeps its default."""
    yield from open_sidebar(report)
    scene = bpy.context.scene
    settings = scene.vortx

    report.begin("Import Capture (the phone app's export)")
    started = time.time()
    with override():
        outcome = bpy.ops.vortx.import_capture("EXEC_DEFAULT", filepath=str(export))
    report.data["import_seconds"] = round(time.time() - started, 1)
    report.check(outcome == {"FINISHED"}, f"Import Capture finished ({outcome})")
    total = settings.frame_count
    report.check(total > 0 and settings.posed_frame_count == total, f"every photo is posed ({settings.posed_frame_count} of {total})")
    report.check(settings.pose_source.startswith("ARKit"), f"the poses are the phone's ARKit poses ({settings.pose_source!r})")
    report.check(settings.poses_metric and settings.scale_source == "metric capture",
                 f"the poses are metric, from the capture ({settings.poses_metric}, {settings.scale_source!r})")
    loaded = addon("vortx_blender.capture").loaded_capture(scene, export)
    depth_frames = loaded.frames_with_sensor_depth if loaded is not None else 0
    report.check(depth_frames == total, f"every photo has its sensor depth map ({depth_frames} of {total})")
    cameras = addon("vortx_blender.cameras").capture_cameras(scene)
    report.check(len(cameras) == total, f"one camera per photo ({len(cameras)})")
    points = addon("vortx_blender.point_cloud").find_point_cloud(scene)
    n_points = len(points.data.vertices) if points is not None else 0
    report.check(n_points > 1000, f"the points from the sensor depth are in the scene ({n_points})")
    panels = addon("ui.panels")
    report.data["panel"] = {
        "frames": f"Frames: {settings.frame_count}, {settings.resolution_x} x {settings.resolution_y}",
        "poses": panels.poses_line(settings), "scale": panels.scale_line(settings)[0],
        "format": settings.capture_format, "pose_status": settings.pose_status,
        "scale_description": settings.scale_description, "pose_check": settings.pose_check,
        "sensor_depth_frames": depth_frames, "points": n_points}
    _, area, _ = view3d()
    area.spaces.active.shading.color_type = "VERTEX"  # Viewport Shading > Color > Attribute: the points' colours
    view_along_walk(cameras)  # the points are 1 cm across: seen from close, along the walk's start
    yield from settle()
    shot(report, "gui_phone_imported", "Import Capture on the 3D Scanner App's export: the Capture panel; the "
         "capture's cameras and the points from its LiDAR depth in the viewport, seen from above the first "
         "camera along the walk", False, png=True, width=1600)
    report.end()

    report.begin("Reconstruct with every default (stereo, Finish Room, the sensor depth)" if quality is None
                 else f"Reconstruct at the {quality.title()} quality, every other setting as it is")
    if quality is not None:
        settings.quality = quality
    report.data["settings"] = {"keep_given_poses": settings.keep_given_poses, "method": settings.method, "quality": settings.quality, "finish": settings.finish,
                               "sensor_depth": settings.sensor_depth, "voxel_size": round(settings.voxel_size, 4),
                               "max_room_size": [round(v, 2) for v in settings.max_room_size]}
    report.check(settings.method == "STEREO", f"the default method is stereo ({settings.method})")
    started = time.time()
    with override():
        outcome = bpy.ops.vortx.reconstruct("INVOKE_DEFAULT")
    report.check(outcome == {"RUNNING_MODAL"}, f"Reconstruct runs as a modal job ({outcome})")
    yield from wait_for_job("Reconstruct")
    report.data["reconstruct_seconds"] = round(time.time() - started, 1)
    results = addon("vortx_blender.result")
    objects = results.result_objects(scene)
    report.check(len(objects) == 1, f"one result mesh in the scene ({[o.name for o in objects]})")
    result = objects[0]
    recorded = json.loads(result[results.PROP_SETTINGS])
    report.data["recorded"] = {key: recorded.get(key) for key in ("method", "finish", "sensor_depth", "voxel_size", "max_room_size")}
    report.check(recorded.get("method") == "stereo", f"the result records the stereo method ({recorded.get('method')})")
    report.check(len(result.data.polygons) > 1000, f"the mesh has faces ({len(result.data.polygons)})")
    report.data["faces"] = len(result.data.polygons)
    corners = np.array([list(result.matrix_world @ Vector(c)) for c in result.bound_box])
    report.data["result_size_m"] = [round(float(v), 2) for v in corners.max(0) - corners.min(0)]
    points.hide_set(True)  # the outliner's eye: the points would cover the mesh
    settings.show_tiles = False  # the Tiles panel's Show Tiles: the tile grid would cover it too
    space = area.spaces.active
    space.shading.show_backface_culling = True  # the near wall and any ceiling seen from outside drop away
    yield from frame_from_above(cameras, np.vstack([sample(result), camera_positions(cameras)]))
    shot(report, "gui_phone_reconstructed", f"the result of Reconstruct ({report.data['recorded']}), from above at an "
         "angle (backface culling on)", False, quality=85)
    for camera in cameras:
        camera.hide_set(True)
    camera = cameras[len(cameras) // 2]
    space.shading.show_backface_culling = False  # inside, every face is seen from its front
    view_from(camera)
    yield from settle()
    shot(report, "gui_phone_inside", f"the result from inside the corridor, at capture camera {camera.name}", False, quality=85)
    report.end()


def frame_from_above(cameras: list[Any], points: np.ndarray) -> Iterator[float]:
    """The view from above at TILT_DEG, looking across the walk (its main horizontal direction, from the
    cameras' positions), `points` (N, 3) filling the part of the viewport the sidebar leaves free."""
    xy = np.array([list(c.matrix_world.translation)[:2] for c in cameras])
    xy -= xy.mean(0)
    axis = np.linalg.svd(xy, full_matrices=False)[2][0] if len(xy) > 1 else np.array([1.0, 0.0])
    _, _, region = view3d()
    r3d = region.data
    r3d.view_perspective = "PERSP"
    r3d.view_rotation = Euler((math.radians(TILT_DEG), 0.0, math.atan2(axis[1], axis[0]))).to_quaternion()
    r3d.view_location = Vector(((points.min(0) + points.max(0)) / 2).tolist())
    r3d.view_distance = 2.0 * float(np.linalg.norm(points.max(0) - points.min(0)))
    for _ in range(4):  # the projection is read back after each redraw (Blender updates it when drawing)
        yield from settle()
        screen = [location_3d_to_region_2d(region, r3d, Vector(p.tolist())) for p in points]
        screen = np.array([list(s) for s in screen if s is not None])
        free_width, height = region.width - sidebar().width, region.height  # the sidebar overlaps the viewport
        low, high = screen.min(0), screen.max(0)
        now, target = Vector(((low + high) / 2).tolist()), Vector((free_width / 2, height / 2))
        depth = r3d.view_location
        shift = (region_2d_to_location_3d(region, r3d, now, depth) - region_2d_to_location_3d(region, r3d, target, depth))
        r3d.view_location = r3d.view_location + shift
        r3d.view_distance *= max((high[0] - low[0]) / (FILL * free_width), (high[1] - low[1]) / (FILL * height))
    yield from settle()


def sample(obj: Any, count: int = 4000) -> np.ndarray:
    """Up to `count` of a mesh object's vertex positions in the world (N, 3), evenly through its vertices."""
    vertices = obj.data.vertices
    co = np.empty(len(vertices) * 3, dtype=np.float32)
    vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)[np.linspace(0, len(vertices) - 1, min(count, len(vertices))).astype(np.int64)]
    matrix = np.array(obj.matrix_world)
    return co @ matrix[:3, :3].T + matrix[:3, 3]


def view_along_walk(cameras: list[Any]) -> None:
    """The viewport just above the first camera, looking down the walk (towards the tenth camera) and
    slightly down, through a wide lens."""
    _, area, region = view3d()
    area.spaces.active.lens = VIEW_LENS_MM
    positions = camera_positions(cameras)
    ahead = positions[min(10, len(positions) - 1)] - positions[0]
    heading = math.atan2(-ahead[0], ahead[1])  # a view rotated by `heading` about Z looks along (-sin, cos)
    direction = Vector((-math.sin(heading), math.cos(heading), 0.0))
    r3d = region.data
    r3d.view_perspective = "PERSP"
    r3d.view_rotation = Euler((math.radians(78), 0.0, heading)).to_quaternion()
    r3d.view_location = Vector(positions[0].tolist()) + 4.0 * direction
    r3d.view_distance = 4.0  # the eye about 0.8 m above the first camera


def view_from(camera: Any) -> None:
    """The viewport placed where `camera` stood, looking where it looked, through a wide lens."""
    window, area, region = view3d()
    area.spaces.active.lens = VIEW_LENS_MM
    r3d = region.data
    r3d.view_perspective = "PERSP"
    r3d.view_distance = 0.5
    r3d.view_matrix = camera.matrix_world.inverted()


def camera_positions(cameras: list[Any]) -> np.ndarray:
    return np.array([list(c.matrix_world.translation) for c in cameras])
