"""The VoRTX sidebar tab: registration, and the panels' draw() run against a checking stand-in layout.

Headless there is no region to draw into, so draw() gets a recorder that checks every call the way
Blender would: the UILayout function exists, keywords are its parameters, enum values (icons,
progress type) are valid, `prop` names a property of the data and `operator` a registered operator.
(Blender itself only prints a warning and draws nothing for a wrong property name.)
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from fixtures_blender_ui import RecordingLayout

PANELS = ("VORTX_PT_capture", "VORTX_PT_pose_settings", "VORTX_PT_reconstruction", "VORTX_PT_model", "VORTX_PT_tiles",
          "VORTX_PT_result", "VORTX_PT_advanced", "VORTX_PT_stereo")


def _draw(panel_name: str, context) -> list:
    import bpy

    calls: list = []
    panel_cls = getattr(bpy.types, panel_name)
    panel_cls.draw(SimpleNamespace(layout=RecordingLayout(calls)), context)
    return calls


def test_panels_registered_in_vortx_sidebar_tab(blender) -> None:
    import bpy

    for name in PANELS:
        cls = getattr(bpy.types, name)
        assert (cls.bl_space_type, cls.bl_region_type, cls.bl_category) == ("VIEW_3D", "UI", "VoRTX"), name
    assert bpy.types.VORTX_PT_pose_settings.bl_parent_id == "VORTX_PT_capture"
    for name in ("VORTX_PT_model", "VORTX_PT_tiles", "VORTX_PT_result", "VORTX_PT_advanced"):
        assert getattr(bpy.types, name).bl_parent_id == "VORTX_PT_reconstruction", name


def test_capture_panel_before_and_after_import(blender, empty_scene) -> None:
    import bpy

    calls = _draw("VORTX_PT_capture", bpy.context)
    operators = [c[1]["operator"] for c in calls if c[0] == "operator"]
    assert operators == ["vortx.import_capture", "vortx.estimate_poses", "vortx.refine_poses", "vortx.set_scale"]
    assert any(c[0] == "label" and c[1].get("text") == "No capture imported" for c in calls)

    settings = empty_scene.vortx
    settings.capture_path = "/captures/living-room/"
    settings.capture_format = "transforms"
    settings.frame_count, settings.resolution_x, settings.resolution_y = 60, 1920, 1080
    settings.pose_status = "All 60 posed (transforms)"
    texts = [c[1].get("text") for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    for expected in ("living-room", "transforms", "60", "1920 x 1080", "All 60 posed (transforms)"):
        assert expected in texts, (expected, texts)


def test_capture_panel_shows_the_scale_source_and_skipped_photos(blender, empty_scene) -> None:
    import bpy

    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 12, 12, False
    settings.scale_source = "unknown"
    settings.scale_description = "no floor found in the sparse points (no points below the cameras): scale unknown, SfM units kept"
    settings.skipped_count, settings.skipped_names = 2, "IMG_0003.jpg, IMG_0007.jpg"
    labels = [c[1] for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    texts = [label.get("text") for label in labels]
    assert "arbitrary (unknown)" in texts
    shown = " ".join(t for t in texts if t)
    assert "no floor found in the sparse points" in shown and "scale unknown" in shown
    assert "2 photo(s) skipped: IMG_0003.jpg, IMG_0007.jpg" in shown
    assert [label.get("icon") for label in labels if (label.get("text") or "").startswith(("no floor", "2 photo"))] == ["ERROR", "ERROR"]

    settings.poses_metric, settings.scale_source = True, "camera height"
    settings.scale_description = "floor plane from 800 points (RANSAC inliers 60 %), median camera height 1.2 units -> scaled x1.25 to 1.5 m"
    settings.skipped_count = 0
    texts = [c[1].get("text") for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    assert "metres (camera height)" in texts
    assert any(t and t.startswith("floor plane from 800 points") for t in texts)
    assert not any(t and "skipped" in t for t in texts)


def test_capture_panel_shows_the_scale_uncertainty_and_poses_that_look_off(blender, empty_scene) -> None:
    import bpy

    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 40, 40, True
    settings.scale_source, settings.scale_uncertainty = "floor and ceiling", 0.06
    settings.scale_description = "metric scale x0.74 +-6 % from the floor and ceiling (dense depth): camera height 2.03 units"
    settings.pose_check = ("the given poses look off: points triangulated with them reproject 1.60 px from where the "
                           "photos show them; refine them against the photos: --refine-poses")
    labels = [c[1] for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    texts = [label.get("text") or "" for label in labels]
    assert "metres (floor and ceiling, +-6 %)" in texts
    assert "the given poses look off" in " ".join(texts) and "--refine-poses" in " ".join(texts)
    assert [label.get("icon") for label in labels if (label.get("text") or "").startswith("the given poses")] == ["ERROR"]
    settings.pose_check = ""
    texts = [c[1].get("text") or "" for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    assert not any("look off" in t for t in texts)


def test_capture_panel_shows_running_job(blender, empty_scene) -> None:
    import bpy

    jobs = blender.vortx_blender.jobs
    release, reported = threading.Event(), threading.Event()

    def work(progress, cancel):
        progress("matching", 3, 12)
        reported.set()
        release.wait(10)

    job = jobs.Job("Estimate Poses", work).start()
    try:
        reported.wait(5)
        job.poll()
        (progress,) = [c[1] for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.25)
        assert "matching 3/12" in progress["text"]
    finally:
        release.set()
        job.wait()
    assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]


@pytest.mark.parametrize(
    "panel, expected",
    [
        ("VORTX_PT_reconstruction", ["method", "voxel_size", "result_mode"]),
        ("VORTX_PT_stereo", ["stereo_image_size", "stereo_views", "stereo_planes", "stereo_sources", "stereo_min_ncc",
                             "stereo_consistency"]),
        ("VORTX_PT_pose_settings", ["sfm_matcher", "sfm_max_image_side", "camera_height"]),
        ("VORTX_PT_model", ["weights_source", "device", "seed"]),
        ("VORTX_PT_tiles", ["show_tiles"]),
        ("VORTX_PT_result", ["min_piece_faces", "min_piece_fraction", "target_faces", "texture_size", "face_budget"]),
        ("VORTX_PT_advanced", ["frustum_depth", "max_room_size", "image_size", "colour_views"]),
    ],
)
def test_settings_panels_show_their_properties(blender, empty_scene, panel: str, expected: list[str]) -> None:
    import bpy

    props = [c[1]["property"] for c in _draw(panel, bpy.context) if c[0] == "prop"]
    assert props == expected


def test_weights_file_shown_only_when_chosen(blender, empty_scene) -> None:
    import bpy

    empty_scene.vortx.weights_source = "FILE"
    props = [c[1]["property"] for c in _draw("VORTX_PT_model", bpy.context) if c[0] == "prop"]
    assert props == ["weights_source", "weights_path", "device", "seed"]


@pytest.mark.parametrize(
    "panel, expected",
    [
        ("VORTX_PT_reconstruction", ["vortx.reconstruct"]),
        ("VORTX_PT_tiles", ["vortx.preview_tiles", "vortx.bake_tiles"]),
        ("VORTX_PT_result", ["vortx.clean_result", "vortx.export_result", "vortx.bake_texture"]),
    ],
)
def test_reconstruction_panels_show_their_operators(blender, empty_scene, panel: str, expected: list[str]) -> None:
    import bpy

    assert [c[1]["operator"] for c in _draw(panel, bpy.context) if c[0] == "operator"] == expected


def test_reconstruction_progress_shows_in_its_own_panel(blender, empty_scene) -> None:
    import bpy

    jobs = blender.vortx_blender.jobs
    release, reported = threading.Event(), threading.Event()

    def work(progress, cancel):
        progress("fusion 16 cm", 2, 8)
        reported.set()
        release.wait(10)

    job = jobs.Job("Reconstruct", work, detail=lambda: "tiles 2/8 done, 1 running").start()
    try:
        reported.wait(5)
        job.poll()
        (progress,) = [c[1] for c in _draw("VORTX_PT_reconstruction", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.25)
        assert "fusion 16 cm 2/8, tiles 2/8 done, 1 running" in progress["text"]
        assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]
    finally:
        release.set()
        job.wait()


def test_recorder_rejects_unknown_property(blender, empty_scene) -> None:
    # The checks above can fail: a draw function naming a property that does not exist.
    draw = blender.ui.panels.draw_reconstruction
    layout = RecordingLayout([])
    draw(layout, empty_scene.vortx, None)
    with pytest.raises(AssertionError, match="no property"):
        layout.prop(empty_scene.vortx, "voxel_sise")
    with pytest.raises(KeyError):
        layout.operator("vortx.no_such_operator")
    with pytest.raises(AssertionError, match="not a valid value"):
        layout.label(text="x", icon="NO_SUCH_ICON")


def test_file_import_and_export_menu_entries(blender, empty_scene) -> None:
    import bpy

    calls: list = []
    blender.ui.menu_import(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    blender.ui.menu_export(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    assert [c[1]["operator"] for c in calls if c[0] == "operator"] == ["vortx.import_capture", "vortx.export_result"]
    assert blender.ui.menu_export in getattr(bpy.types.TOPBAR_MT_file_export.draw, "_draw_funcs", [])


def test_result_panel_offers_the_bake_with_the_vr_preset_and_its_progress(blender, empty_scene) -> None:
    import json

    import bpy
    import numpy as np

    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert " ".join(t for t in labels if t).startswith("VR preset: 100k faces, 4096 px (2048 px for mobile headsets)")
    assert not any(t and t.startswith("Textured") for t in labels)

    results = blender.vortx_blender.result
    mesh = blender.engine.mesh_io.Mesh(vertices=np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), faces=np.int32([[0, 1, 2]]))
    obj = results.insert_result(empty_scene, mesh, results.Provenance("/captures/hall", {}, "stereo", {}))
    obj["vortx_texture"] = json.dumps({"texture_size": 2048, "stats": {"faces": 1}})
    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert "Textured: 2048 px, 1 faces" in labels

    jobs = blender.vortx_blender.jobs
    release, reported = threading.Event(), threading.Event()

    def work(progress, cancel):
        progress("texture: bake", 3, 6)
        reported.set()
        release.wait(10)

    job = jobs.Job("Bake Texture", work).start()
    try:
        reported.wait(5)
        job.poll()
        (progress,) = [c[1] for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.5) and "texture: bake 3/6" in progress["text"]
        assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]
    finally:
        release.set()
        job.wait()


def test_long_pose_and_scale_values_are_shown_whole_not_cut(blender, empty_scene) -> None:
    """Blender cuts a label that does not fit with "..." in its middle: beside its label a value has
    about 60 % of the sidebar; a longer one goes whole on its own lines under the label, and wrapped
    text follows the sidebar's width."""
    import bpy

    panels = blender.ui.panels
    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 36, 36, True
    settings.pose_status = "36 of 36 posed by SfM, scaled by the camera height over the floor, +-12 %"
    settings.scale_source, settings.scale_uncertainty = "camera height over the floor", 0.12
    texts = [c[1].get("text") or "" for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    assert "Poses:" in texts and "Scale:" in texts
    assert " ".join(texts[texts.index("Poses:") + 1:texts.index("Scale:")]) == settings.pose_status
    assert "metres (camera height over the floor, +-12 %)" in " ".join(texts)
    assert max(len(t) for t in texts) <= panels.WRAP_CHARS
    settings.pose_status = "All 6 posed (colmap)"  # short: beside its label, as before
    texts = [c[1].get("text") or "" for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "label"]
    assert "Poses" in texts and "All 6 posed (colmap)" in texts
    # A wider sidebar holds more per line; a narrow one fewer, never below the minimum.
    wide = SimpleNamespace(region=SimpleNamespace(width=600))
    narrow = SimpleNamespace(region=SimpleNamespace(width=80))
    scale = bpy.context.preferences.system.ui_scale or 1.0  # 0 without a window
    assert panels.wrap_chars(wide) == int((600 / scale - panels.MARGIN_PX) / panels.CHAR_PX) > panels.WRAP_CHARS
    assert panels.wrap_chars(narrow) == panels.MIN_WRAP_CHARS
    assert panels.wrap_chars(SimpleNamespace(region=None)) == panels.WRAP_CHARS
