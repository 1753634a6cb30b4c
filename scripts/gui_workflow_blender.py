"""The whole Blender workflow in a real, windowed Blender, driven through the add-on's operators and
panels as a user drives them; runs inside Blender (`blender --python scripts/gui_workflow_blender.py
-- --photos DIR --out DIR`), started by scripts/gui_workflow.py under Xvfb.

Import Capture -> Estimate Poses (the Capture panel's status lines, then its Details sub-panel opened)
-> Reconstruct with VoRTX (the panel's voxel size and views per tile, tiles shown while it runs; then
Esc, which must leave the scene unchanged: the network takes many minutes per tile on a loaded CPU) ->
Reconstruct with Stereo, the default, at the Preview quality chosen in the panel -> Show Observation ->
Bake Texture -> Export Result (GLB) -> the closed sub-panels opened and the sidebar scrolled to its last
panels. The panels stay as a new user finds them (sub-panels closed by default stay closed) until the
last step, so the first screenshots show what fits on the screen. The long jobs are invoked as the panel's buttons invoke them ('INVOKE_DEFAULT': modal, with
progress in the status bar and the sidebar), so the window keeps drawing while they run. After each
step the scene is checked; screenshots of the VoRTX sidebar and of the whole window are taken with
ImageMagick's `import` (Blender's own screenshot operator gives black images with software GL).

Everything happens in timer callbacks: a --python script runs before the window's first draw, and
modal operators need the event loop running. The outcome is written to <out>/report.json (steps,
checks, timings, screenshots); Blender then quits. A failed check ends the run there.
"""

import argparse
import importlib
import json
import os
import subprocess
import sys
import time
import traceback
from pathlib import Path

import bpy

ADDON = "bl_ext.user_default.vortx"
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
JOB_TIMEOUT_S = 1200


def parse_args() -> argparse.Namespace:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser()
    parser.add_argument("--photos", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    return parser.parse_args(argv)


ARGS = parse_args()
ARGS.out.mkdir(parents=True, exist_ok=True)
REPORT: dict = {"steps": [], "shots": [], "blender": bpy.app.version_string, "python": sys.version.split()[0]}


class CheckFailed(Exception):
    pass


def check(condition: bool, what: str) -> None:
    REPORT["steps"][-1]["checks"].append({"check": what, "ok": bool(condition)})
    if not condition:
        raise CheckFailed(what)


def begin(name: str) -> None:
    REPORT["steps"].append({"step": name, "checks": [], "started": time.time()})
    print(f"GUI-WORKFLOW step: {name}", flush=True)


def end() -> None:
    step = REPORT["steps"][-1]
    step["seconds"] = round(time.time() - step.pop("started"), 1)


def addon(module: str):
    return importlib.import_module(f"{ADDON}.{module}")


# --- the window ---------------------------------------------------------------------------------


def view3d():
    window = bpy.context.window_manager.windows[0]
    area = next(a for a in window.screen.areas if a.type == "VIEW_3D")
    region = next(r for r in area.regions if r.type == "WINDOW")
    return window, area, region


def sidebar():
    _, area, _ = view3d()
    return next(r for r in area.regions if r.type == "UI")


def override():
    window, area, region = view3d()
    return bpy.context.temp_override(window=window, screen=window.screen, area=area, region=region)


def redraw() -> None:
    for area in bpy.context.window_manager.windows[0].screen.areas:
        area.tag_redraw()


def settle():
    """Draw the window a few times: panels slide to their new places over several redraws when their
    contents change, and with no mouse moving nothing else asks for those redraws."""
    for _ in range(4):
        redraw()
        with override():
            bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=3)
        yield 0.3


def shot(name: str, what: str, crop_sidebar: bool) -> None:  # after `yield from settle()`
    """Screenshot of the X display: the VoRTX sidebar (PNG) or the whole window (JPEG)."""
    window, _, _ = view3d()
    path = ARGS.out / (f"{name}.png" if crop_sidebar else f"{name}.jpg")
    command = ["import", "-window", "root"]
    if crop_sidebar:
        region = sidebar()
        top = window.height - (region.y + region.height)  # X's origin is the top left, Blender's the bottom left
        command += ["-crop", f"{region.width}x{region.height}+{region.x}+{top}", "+repage"]
    else:
        command += ["-crop", f"{window.width}x{window.height}+0+0", "+repage", "-resize", "1200x", "-quality", "82"]
    subprocess.run(command + [str(path)], check=True, timeout=60)
    REPORT["shots"].append({"file": path.name, "what": what, "bytes": path.stat().st_size})


def show_vortx_tab():
    """Click the sidebar's VoRTX tab, as a user does (the active tab is read-only in Python): the tabs
    are a strip at the sidebar's right edge whose positions Python cannot read either, so xdotool
    clicks down the strip until the VoRTX tab is active."""
    window, _, _ = view3d()
    region = sidebar()
    top = window.height - (region.y + region.height)  # X's origin is the top left, Blender's the bottom left
    for y in range(top + 8, top + 600, 16):
        if sidebar().active_panel_category == "VoRTX":
            break
        subprocess.run(["xdotool", "mousemove", str(region.x + region.width - 12), str(y), "click", "1"], check=True, timeout=30)
        yield 0.4
    subprocess.run(["xdotool", "mousemove", "5", "5"], check=True, timeout=30)  # no hover highlight in the shots


OPENED: set = set()  # the sub-panels shown open
REGISTERED: list = []  # the panel classes registered in their place


def open_panels(names) -> None:
    """Show the sub-panels `names` open and every other one as it was, as a user clicks headers. Python
    can neither open a drawn panel nor reset it (one registered again keeps its state), so each is
    registered again under a new idname ("..._open", its children moved under it) without DEFAULT_CLOSED:
    a new panel, open; registered under its own idname again it is the closed one it was. All the add-on's
    panels are registered again, parents first, so they keep their order."""
    panels = addon("ui.panels")
    for cls in reversed(REGISTERED or panels.classes):
        bpy.utils.unregister_class(cls)
    OPENED.clear()
    OPENED.update(names)
    REGISTERED.clear()
    for cls in panels.classes:
        attributes = {}
        if cls.__name__ in OPENED:
            attributes = {"bl_idname": f"{cls.bl_idname}_open",
                          "bl_options": set(getattr(cls, "bl_options", set())) - {"DEFAULT_CLOSED"}}
        parent = getattr(cls, "bl_parent_id", "")
        if parent in OPENED:
            attributes["bl_parent_id"] = f"{parent}_open"
        if attributes:
            attributes.setdefault("bl_idname", f"{cls.bl_idname}_moved")
            cls = type(attributes["bl_idname"], (cls,), attributes)
        bpy.utils.register_class(cls)
        REGISTERED.append(cls)


def measure_sidebar() -> dict:
    """The sidebar's size and the UI's text widths in this window (blf at the UI font's size)."""
    import blf

    region = sidebar()
    style = bpy.context.preferences.ui_styles[0]
    points = getattr(getattr(style, "widget", None), "points", 11)  # the widgets' text (ThemeStyle.widget)
    blf.size(0, points * bpy.context.preferences.system.ui_scale)
    return {"width": region.width, "height": region.height, "ui_scale": bpy.context.preferences.system.ui_scale,
            "font_points": points, "text_widths": {t: blf.dimensions(0, t)[0] for t in MEASURED_TEXTS}}


def wait_for_job(title: str):
    """Yield until the add-on's job is over (the modal operator applies the result on its last tick)."""
    jobs = addon("vortx_blender.jobs")
    started = time.time()
    yield 0.5
    while jobs.active_job() is not None:
        if time.time() - started > JOB_TIMEOUT_S:
            raise CheckFailed(f"{title} still running after {JOB_TIMEOUT_S} s")
        yield 0.5
    yield 0.5  # the modal operator's last timer tick has run; let the window draw the outcome


# --- the workflow -------------------------------------------------------------------------------


def workflow():
    yield 3.0  # the window's first draws
    begin("open the VoRTX sidebar")
    # A new file's cube, light and camera would sit inside the room: a user deletes them first.
    for obj in list(bpy.context.scene.objects):
        bpy.data.objects.remove(obj)
    _, area, _ = view3d()
    area.spaces.active.show_region_ui = True
    redraw()
    yield 1.0
    yield from show_vortx_tab()
    yield from settle()
    check(sidebar().active_panel_category == "VoRTX", f"the sidebar shows the VoRTX tab ({sidebar().active_panel_category})")
    dependencies = addon("vortx_blender.dependencies")
    missing = [s.describe() for s in dependencies.status(refresh=True) if s.needs_install]
    check(not missing, f"the engine's packages are installed (missing: {missing})")
    REPORT["sidebar"] = measure_sidebar()
    shot("gui_01_start", "the VoRTX tab before a capture is imported", True)
    end()

    scene = bpy.context.scene
    settings = scene.vortx
    photos = sorted(ARGS.photos.iterdir())
    begin("Import Capture")
    with override():
        outcome = bpy.ops.vortx.import_capture("EXEC_DEFAULT", filepath=str(ARGS.photos))
    check(outcome == {"FINISHED"}, f"Import Capture finished ({outcome})")
    check(settings.frame_count == len(photos), f"the panel shows {len(photos)} frames ({settings.frame_count})")
    check(settings.posed_frame_count == 0, "the photos have no poses yet")
    yield from settle()
    shot("gui_02_imported", "Capture panel after Import Capture", True)
    end()

    begin("Estimate Poses")
    with override():
        outcome = bpy.ops.vortx.estimate_poses("INVOKE_DEFAULT")
    check(outcome == {"RUNNING_MODAL"}, f"Estimate Poses runs as a modal job ({outcome})")
    yield from wait_for_job("Estimate Poses")
    collection = addon("vortx_blender.scene_objects").find_capture_collection(scene)
    n_cameras = len([o for o in collection.objects if o.type == "CAMERA"]) if collection else 0
    check(settings.posed_frame_count >= len(photos) // 2, f"most photos are posed ({settings.posed_frame_count} of {len(photos)})")
    check(n_cameras == settings.posed_frame_count, f"one camera per posed photo in the capture collection ({n_cameras})")
    check(bool(settings.scale_source), f"the scale source is shown ({settings.scale_source!r})")
    REPORT["posed"] = settings.posed_frame_count
    with override():
        bpy.ops.view3d.view_all()  # the cameras in view, as a user frames them (Home)
    check(settings.pose_source == "SfM", f"the Poses line says SfM made them ({settings.pose_source!r})")
    yield from settle()
    shot("gui_03_posed", "Capture panel after Estimate Poses: one line each for frames, poses and scale; "
         "the Reconstruction panel below it on a 1600 x 1000 screen", True)
    open_panels([DETAILS_PANEL])
    yield from settle()
    shot("gui_03_details", "the Details sub-panel opened: the pose status and the scale's derivation in full", True)
    open_panels([])  # closed again, as the user leaves it
    yield from settle()
    end()

    begin("Reconstruct with VoRTX, tiles shown, then Esc")
    settings.method = "VORTX"
    settings.voxel_size = VORTX_VOXEL_SIZE
    settings.view_count = VORTX_VIEW_COUNT
    settings.show_tiles = True
    yield from settle()
    with override():
        outcome = bpy.ops.vortx.reconstruct("INVOKE_DEFAULT")
    check(outcome == {"RUNNING_MODAL"}, f"Reconstruct runs as a modal job ({outcome})")
    overlay_module = addon("vortx_blender.tile_overlay")
    jobs = addon("vortx_blender.jobs")
    results = addon("vortx_blender.result")
    deadline = time.time() + JOB_TIMEOUT_S
    counts: dict = {}
    while jobs.active_job() is not None and time.time() < deadline and counts.get("running", 0) + counts.get("done", 0) == 0:
        overlay = overlay_module.current(scene)
        counts = overlay.counts() if overlay is not None else {}
        yield 0.2
    check(counts.get("running", 0) + counts.get("done", 0) >= 1, f"the tile grid shows a tile running ({counts})")
    REPORT["tiles_while_running"] = counts
    yield from settle()
    shot("gui_04_reconstructing", "Reconstruct running: progress in the panel and the tile grid in the viewport", False)
    shot("gui_04_reconstructing_sidebar", "Reconstruction panel while Reconstruct runs", True)
    # The network's tiles take many minutes on a loaded CPU: Esc (the key, over the viewport) cancels,
    # which must leave the scene as it was.
    objects_before = sorted(o.name for o in scene.objects)
    window, area, _ = view3d()
    subprocess.run(["xdotool", "mousemove", str(area.x + area.width // 3), str(window.height // 2), "key", "Escape",
                    "mousemove", "5", "5"], check=True, timeout=30)
    yield from wait_for_job("Reconstruct")
    check(sorted(o.name for o in scene.objects) == objects_before and not results.result_objects(scene),
          "Esc cancelled Reconstruct and the scene is unchanged (no result, same objects)")
    overlay = overlay_module.current(scene)
    check(overlay is None or not overlay.tiles, "the cancelled run's tiles are gone from the viewport")
    end()

    begin("Reconstruct with Stereo (the default method) at the Preview quality")
    settings.method = "STEREO"
    settings.voxel_size = VOXEL_SIZE
    settings.quality = QUALITY  # chosen in the panel's Quality menu
    presets = addon("engine.recon.presets")
    expected = presets.preset_values(QUALITY.lower())
    check(settings.quality == QUALITY and settings.stereo_views == expected["stereo_views"],
          f"Quality {QUALITY} sets the stereo settings ({settings.stereo_views} views, {settings.stereo_image_size} px)")
    yield from settle()
    with override():
        outcome = bpy.ops.vortx.reconstruct("INVOKE_DEFAULT")
    check(outcome == {"RUNNING_MODAL"}, f"Reconstruct runs as a modal job ({outcome})")
    yield from wait_for_job("Reconstruct")
    objects = results.result_objects(scene)
    check(len(objects) == 1, f"one result mesh in the scene ({[o.name for o in objects]})")
    result = objects[0]
    recorded = json.loads(result[results.PROP_SETTINGS])
    check(recorded.get("method") == "stereo", f"the result records the stereo method ({recorded.get('method')})")
    check(abs(recorded.get("voxel_size", 0) - VOXEL_SIZE) < 1e-6
          and all(recorded.get(key) == value for key, value in expected.items()),
          f"the result records the panel's voxel size and the preset's settings ({recorded.get('voxel_size')}, "
          f"{ {key: recorded.get(key) for key in expected} })")
    check(len(result.data.polygons) > 1000, f"the stereo mesh has faces ({len(result.data.polygons)})")
    REPORT["stereo_faces"] = len(result.data.polygons)
    bpy.ops.object.select_all(action="DESELECT")
    result.select_set(True)
    bpy.context.view_layer.objects.active = result
    with override():
        bpy.ops.view3d.view_selected()
    yield from settle()
    shot("gui_05_reconstructed", "the stereo mesh in the viewport (vertex colours) and the VoRTX tab", False)
    shot("gui_05_reconstructed_sidebar", "Reconstruction, Tiles and Result panels after Reconstruct", True)
    end()

    begin("Show Observation")
    check(results.has_observation(result.data), "the result carries the observation layer")
    setattr(result, results.SHOW_OBSERVATION, True)  # the Result panel's toggle
    yield from settle()
    check(results.shown_colour_attribute(result.data) == results.OBSERVATION_ATTRIBUTE,
          f"the viewport shows the observation colours ({results.shown_colour_attribute(result.data)})")
    shot("gui_06_observation", "Show Observation on: the confidence colours", False)
    setattr(result, results.SHOW_OBSERVATION, False)
    check(results.shown_colour_attribute(result.data) != results.OBSERVATION_ATTRIBUTE, "Show Observation off: the photo colours again")
    end()

    begin("Bake Texture")
    settings.texture_size = TEXTURE_SIZE
    settings.face_budget = FACE_BUDGET
    redraw()
    yield 0.5
    with override():
        outcome = bpy.ops.vortx.bake_texture("INVOKE_DEFAULT")
    check(outcome == {"RUNNING_MODAL"}, f"Bake Texture runs as a modal job ({outcome})")
    yield from wait_for_job("Bake Texture")
    texture = addon("vortx_blender.texture")
    summary = texture.bake_summary(result)
    check(summary is not None and summary["texture_size"] == TEXTURE_SIZE, f"the result records the bake ({summary and summary.get('texture_size')})")
    check(result.data.uv_layers.get("UVMap") is not None, "the result has a UVMap")
    image = results.texture_image_of(result.active_material)
    check(image is not None and image.packed_file is not None and tuple(image.size) == (TEXTURE_SIZE, TEXTURE_SIZE),
          f"the texture is a packed {TEXTURE_SIZE} px image ({image and tuple(image.size)})")
    check(len(result.data.polygons) <= FACE_BUDGET, f"the mesh is within the face budget ({len(result.data.polygons)})")
    REPORT["textured_faces"] = len(result.data.polygons)
    window, _, _ = view3d()
    for area in window.screen.areas:
        if area.type == "VIEW_3D":
            area.spaces.active.shading.type = "MATERIAL"  # Material Preview: the texture as it renders
    yield 2.0
    yield from settle()
    shot("gui_07_textured", "the baked texture in Material Preview", False)
    shot("gui_07_textured_sidebar", "Result panel after Bake Texture", True)
    end()

    begin("Export Result (GLB)")
    glb = ARGS.out / "room.glb"
    with override():
        outcome = bpy.ops.vortx.export_result("EXEC_DEFAULT", filepath=str(glb))
    check(outcome == {"FINISHED"}, f"Export Result finished ({outcome})")
    data = glb.read_bytes() if glb.exists() else b""
    check(data[:4] == b"glTF", "the GLB starts with the glTF magic")
    length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20:20 + length])
    check(len(gltf.get("images", [])) == 1 and len(gltf.get("meshes", [])) >= 1, f"the GLB has the mesh and its texture image ({len(gltf.get('images', []))} images)")
    REPORT["glb_bytes"] = len(data)
    end()

    begin("open the closed sub-panels and scroll the sidebar to its last panels")
    open_panels(list(OPEN_PANELS))
    yield from settle()
    window, _, _ = view3d()
    region = sidebar()
    x, y = region.x + region.width // 2, window.height - (region.y + region.height // 2)
    subprocess.run(["xdotool", "mousemove", str(x), str(y), "click", "--repeat", "40", "--delay", "30", "5",
                    "mousemove", "5", "5"], check=True, timeout=60)  # the mouse wheel, as a user scrolls
    yield from settle()
    shot("gui_08_sidebar_end", "the Model, Advanced and Stereo panels opened (the sidebar scrolled down)", True)
    end()


def finish(ok: bool, error: str = "") -> None:
    REPORT["ok"] = ok
    if error:
        REPORT["error"] = error
        if REPORT["steps"]:
            REPORT["steps"][-1]["error"] = error
            REPORT["steps"][-1].pop("started", None)
    (ARGS.out / "report.json").write_text(json.dumps(REPORT, indent=1))
    print(f"GUI-WORKFLOW {'OK' if ok else 'FAILED: ' + error}", flush=True)
    bpy.ops.wm.quit_blender()


STEPS = workflow()


def tick():
    try:
        return next(STEPS)
    except StopIteration:
        finish(True)
    except CheckFailed as failed:
        finish(False, f"check failed: {failed}")
    except Exception as error:  # a bug in the add-on or here: the report keeps the traceback
        finish(False, "".join(traceback.format_exception(error))[-3000:])
    return None


bpy.app.timers.register(tick, first_interval=1.0)
