"""The GUI workflow's steps (devtools/gui_workflow/__init__.py describes them), run inside a windowed
Blender from timer callbacks: each step acts as a user does, checks the scene, takes screenshots."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Iterator, Optional

import bpy

from .report import WorkflowReport
from .window import (JOB_TIMEOUT_S, PanelLayout, addon, measure_sidebar, override, redraw, settle, shot, show_vortx_tab,
                     sidebar, view3d, wait_for_job, x_command)
from .x11 import escape_command, scroll_down_command

# Child panels closed by default, opened as a user clicks them open: Details after Estimate Poses, the
# others for the last screenshot, so it shows every panel.
DETAILS_PANEL = "VORTX_PT_capture_details"
OPEN_PANELS = ("VORTX_PT_pose_settings", "VORTX_PT_model", "VORTX_PT_advanced")
# The settings chosen in the panels (small: the run stays a few minutes on two CPU cores).
VORTX_VOXEL_SIZE = 0.08
VORTX_VIEW_COUNT = 10
VOXEL_SIZE = 0.05
QUALITY = "PREVIEW"
# Texts whose width in this window (Blender's blf, the UI font) the report records beside the budgets
# of ui/sidebar.py, which tests/ui/test_label_widths.py measures with the bpy module.
MEASURED_TEXTS = ("Max room size X", "Min Match Score", "Source Views", "Clean Up Result",
                  "Scale: metric, +-12 %, from the floor")
TEXTURE_SIZE = 1024
FACE_BUDGET = 40000


def workflow(photo_folder: Path, report: WorkflowReport) -> Iterator[float]:
    """The steps, as a generator of seconds to wait before the next tick (bpy.app.timers)."""
    panels = PanelLayout()
    yield from open_sidebar(report, "gui_01_start")

    scene = bpy.context.scene
    settings = scene.vortx
    photos = sorted(photo_folder.iterdir())
    report.begin("Import Capture")
    with override():
        outcome = bpy.ops.vortx.import_capture("EXEC_DEFAULT", filepath=str(photo_folder))
    report.check(outcome == {"FINISHED"}, f"Import Capture finished ({outcome})")
    report.check(settings.frame_count == len(photos), f"the panel shows {len(photos)} frames ({settings.frame_count})")
    report.check(settings.posed_frame_count == 0, "the photos have no poses yet")
    yield from settle()
    shot(report, "gui_02_imported", "Capture panel after Import Capture", True)
    report.end()

    report.begin("Estimate Poses")
    with override():
        outcome = bpy.ops.vortx.estimate_poses("INVOKE_DEFAULT")
    report.check(outcome == {"RUNNING_MODAL"}, f"Estimate Poses runs as a modal job ({outcome})")
    yield from wait_for_job("Estimate Poses")
    collection = addon("vortx_blender.scene_objects").find_capture_collection(scene)
    n_cameras = len([o for o in collection.objects if o.type == "CAMERA"]) if collection else 0
    report.check(settings.posed_frame_count >= len(photos) // 2, f"most photos are posed ({settings.posed_frame_count} of {len(photos)})")
    report.check(n_cameras == settings.posed_frame_count, f"one camera per posed photo in the capture collection ({n_cameras})")
    report.check(bool(settings.scale_source), f"the scale source is shown ({settings.scale_source!r})")
    report.data["posed"] = settings.posed_frame_count
    with override():
        bpy.ops.view3d.view_all()  # the cameras in view, as a user frames them (Home)
    report.check(settings.pose_source == "SfM", f"the Poses line says SfM made them ({settings.pose_source!r})")
    yield from settle()
    shot(report, "gui_03_posed", "Capture panel after Estimate Poses: one line each for frames, poses and scale; "
                 "the Reconstruction panel below it on a 1600 x 1000 screen", True)
    panels.open([DETAILS_PANEL])
    yield from settle()
    shot(report, "gui_03_details", "the Details sub-panel opened: the pose status and the scale's derivation in full", True)
    panels.open([])  # closed again, as the user leaves it
    yield from settle()
    report.end()

    report.begin("Reconstruct with VoRTX, tiles shown, then Esc")
    settings.method = "VORTX"
    settings.voxel_size = VORTX_VOXEL_SIZE
    settings.view_count = VORTX_VIEW_COUNT
    settings.show_tiles = True
    yield from settle()
    with override():
        outcome = bpy.ops.vortx.reconstruct("INVOKE_DEFAULT")
    report.check(outcome == {"RUNNING_MODAL"}, f"Reconstruct runs as a modal job ({outcome})")
    overlay_module = addon("vortx_blender.tile_overlay")
    jobs = addon("vortx_blender.jobs")
    results = addon("vortx_blender.result")
    deadline = time.time() + JOB_TIMEOUT_S
    counts: dict = {}
    while jobs.active_job() is not None and time.time() < deadline and counts.get("running", 0) + counts.get("done", 0) == 0:
        overlay = overlay_module.current(scene)
        counts = overlay.counts() if overlay is not None else {}
        yield 0.2
    report.check(counts.get("running", 0) + counts.get("done", 0) >= 1, f"the tile grid shows a tile running ({counts})")
    report.data["tiles_while_running"] = counts
    yield from settle()
    shot(report, "gui_04_reconstructing", "Reconstruct running: progress in the panel and the tile grid in the viewport", False)
    shot(report, "gui_04_reconstructing_sidebar", "Reconstruction panel while Reconstruct runs", True)
    # The network's tiles take many minutes on a loaded CPU: Esc (the key, over the viewport) cancels,
    # which must leave the scene as it was.
    objects_before = sorted(o.name for o in scene.objects)
    window, area, _ = view3d()
    x_command(escape_command(area.x + area.width // 3, window.height // 2))
    yield from wait_for_job("Reconstruct")
    report.check(sorted(o.name for o in scene.objects) == objects_before and not results.result_objects(scene),
                 "Esc cancelled Reconstruct and the scene is unchanged (no result, same objects)")
    overlay = overlay_module.current(scene)
    report.check(overlay is None or not overlay.tiles, "the cancelled run's tiles are gone from the viewport")
    report.end()

    report.begin("Reconstruct with Stereo (the default method) at the Preview quality")
    settings.method = "STEREO"
    settings.voxel_size = VOXEL_SIZE
    settings.quality = QUALITY  # chosen in the panel's Quality menu
    presets = addon("engine.recon.presets")
    expected = presets.preset_values(QUALITY.lower())
    report.check(settings.quality == QUALITY and settings.stereo_views == expected["stereo_views"],
                 f"Quality {QUALITY} sets the stereo settings ({settings.stereo_views} views, {settings.stereo_image_size} px)")
    yield from settle()
    with override():
        outcome = bpy.ops.vortx.reconstruct("INVOKE_DEFAULT")
    report.check(outcome == {"RUNNING_MODAL"}, f"Reconstruct runs as a modal job ({outcome})")
    yield from wait_for_job("Reconstruct")
    objects = results.result_objects(scene)
    report.check(len(objects) == 1, f"one result mesh in the scene ({[o.name for o in objects]})")
    result = objects[0]
    recorded = json.loads(result[results.PROP_SETTINGS])
    report.check(recorded.get("method") == "stereo", f"the result records the stereo method ({recorded.get('method')})")
    report.check(abs(recorded.get("voxel_size", 0) - VOXEL_SIZE) < 1e-6
                 and all(recorded.get(key) == value for key, value in expected.items()),
                 f"the result records the panel's voxel size and the preset's settings ({recorded.get('voxel_size')}, "
                 f"{ {key: recorded.get(key) for key in expected} })")
    report.check(len(result.data.polygons) > 1000, f"the stereo mesh has faces ({len(result.data.polygons)})")
    report.data["stereo_faces"] = len(result.data.polygons)
    bpy.ops.object.select_all(action="DESELECT")
    result.select_set(True)
    bpy.context.view_layer.objects.active = result
    with override():
        bpy.ops.view3d.view_selected()
    yield from settle()
    shot(report, "gui_05_reconstructed", "the stereo mesh in the viewport (vertex colours) and the VoRTX tab", False)
    shot(report, "gui_05_reconstructed_sidebar", "Reconstruction, Tiles and Result panels after Reconstruct", True)
    report.end()

    report.begin("Show Observation")
    report.check(results.has_observation(result.data), "the result carries the observation layer")
    setattr(result, results.SHOW_OBSERVATION, True)  # the Result panel's toggle
    yield from settle()
    report.check(results.shown_colour_attribute(result.data) == results.OBSERVATION_ATTRIBUTE,
                 f"the viewport shows the observation colours ({results.shown_colour_attribute(result.data)})")
    shot(report, "gui_06_observation", "Show Observation on: the confidence colours", False)
    setattr(result, results.SHOW_OBSERVATION, False)
    report.check(results.shown_colour_attribute(result.data) != results.OBSERVATION_ATTRIBUTE, "Show Observation off: the photo colours again")
    report.end()

    report.begin("Bake Texture")
    settings.texture_size = TEXTURE_SIZE
    settings.face_budget = FACE_BUDGET
    redraw()
    yield 0.5
    with override():
        outcome = bpy.ops.vortx.bake_texture("INVOKE_DEFAULT")
    report.check(outcome == {"RUNNING_MODAL"}, f"Bake Texture runs as a modal job ({outcome})")
    yield from wait_for_job("Bake Texture")
    texture = addon("vortx_blender.texture")
    summary = texture.bake_summary(result)
    report.check(summary is not None and summary["texture_size"] == TEXTURE_SIZE, f"the result records the bake ({summary and summary.get('texture_size')})")
    report.check(result.data.uv_layers.get("UVMap") is not None, "the result has a UVMap")
    image = results.texture_image_of(result.active_material)
    report.check(image is not None and image.packed_file is not None and tuple(image.size) == (TEXTURE_SIZE, TEXTURE_SIZE),
                 f"the texture is a packed {TEXTURE_SIZE} px image ({image and tuple(image.size)})")
    report.check(len(result.data.polygons) <= FACE_BUDGET, f"the mesh is within the face budget ({len(result.data.polygons)})")
    report.data["textured_faces"] = len(result.data.polygons)
    window, _, _ = view3d()
    for area in window.screen.areas:
        if area.type == "VIEW_3D":
            area.spaces.active.shading.type = "MATERIAL"  # Material Preview: the texture as it renders
    yield 2.0
    yield from settle()
    shot(report, "gui_07_textured", "the baked texture in Material Preview", False)
    shot(report, "gui_07_textured_sidebar", "Result panel after Bake Texture", True)
    report.end()

    report.begin("Export Result (GLB)")
    glb = report.out / "room.glb"
    with override():
        outcome = bpy.ops.vortx.export_result("EXEC_DEFAULT", filepath=str(glb))
    report.check(outcome == {"FINISHED"}, f"Export Result finished ({outcome})")
    data = glb.read_bytes() if glb.exists() else b""
    report.check(data[:4] == b"glTF", "the GLB starts with the glTF magic")
    length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20:20 + length])
    report.check(len(gltf.get("images", [])) == 1 and len(gltf.get("meshes", [])) >= 1, f"the GLB has the mesh and its texture image ({len(gltf.get('images', []))} images)")
    report.data["glb_bytes"] = len(data)
    report.end()

    report.begin("open the closed sub-panels and scroll the sidebar to its last panels")
    panels.open(list(OPEN_PANELS))
    yield from settle()
    window, _, _ = view3d()
    region = sidebar()
    x, y = region.x + region.width // 2, window.height - (region.y + region.height // 2)
    x_command(scroll_down_command(x, y), timeout=60)  # the mouse wheel, as a user scrolls
    yield from settle()
    shot(report, "gui_08_sidebar_end", "the Model, Advanced and Stereo panels opened (the sidebar scrolled down)", True)
    report.end()


def open_sidebar(report: WorkflowReport, shot_name: Optional[str] = None) -> Iterator[float]:
    """The first step: the new file's objects deleted, the sidebar's VoRTX tab opened (clicked), the
    engine's packages checked; a screenshot of the tab as `shot_name` when given."""
    yield 3.0  # the window's first draws
    report.begin("open the VoRTX sidebar")
    # A new file's cube, light and camera would sit inside the room: a user deletes them first.
    for obj in list(bpy.context.scene.objects):
        bpy.data.objects.remove(obj)
    _, area, _ = view3d()
    area.spaces.active.show_region_ui = True
    redraw()
    yield 1.0
    yield from show_vortx_tab()
    yield from settle()
    report.check(sidebar().active_panel_category == "VoRTX", f"the sidebar shows the VoRTX tab ({sidebar().active_panel_category})")
    dependencies = addon("vortx_blender.dependencies")
    missing = [s.describe() for s in dependencies.status(refresh=True) if s.needs_install]
    report.check(not missing, f"the engine's packages are installed (missing: {missing})")
    report.data["sidebar"] = measure_sidebar(MEASURED_TEXTS)
    if shot_name:
        shot(report, shot_name, "the VoRTX tab before a capture is imported", True)
    report.end()
