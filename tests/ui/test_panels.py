"""The VoRTX sidebar tab: registration, and the panels' draw() run against a checking stand-in layout.

Headless there is no region to draw into, so draw() gets a recorder that checks every call the way
Blender would: the UILayout function exists, keywords are its parameters, enum values (icons,
progress type) are valid, `prop` names a property of the data and `operator` a registered operator.
(Blender itself only prints a warning and draws nothing for a wrong property name.)
"""

from __future__ import annotations

from dataclasses import fields
from types import SimpleNamespace

import pytest

from engine.recon.settings import ReconSettings
from fixtures_blender_ui import RecordingLayout, job_paused_at

RECON_NAMES = {f.name for f in fields(ReconSettings)}
PANELS = ("VORTX_PT_capture", "VORTX_PT_capture_details", "VORTX_PT_pose_settings", "VORTX_PT_reconstruction",
          "VORTX_PT_model", "VORTX_PT_tiles", "VORTX_PT_result", "VORTX_PT_advanced", "VORTX_PT_stereo")


def _draw(panel_name: str, context) -> list:
    import bpy

    calls: list = []
    panel_cls = getattr(bpy.types, panel_name)
    panel_cls.draw(SimpleNamespace(layout=RecordingLayout(calls)), context)
    return calls


def _lines(calls: list) -> list[dict]:
    """What a user reads, in order: each label and each status line drawn as the explain operator, with
    its icon and its tooltip (the explain operator's text; "" for a plain label)."""
    lines = []
    for name, bound in calls:
        if name == "label":
            lines.append({"text": bound.get("text") or "", "icon": bound.get("icon", "NONE"), "tooltip": ""})
        elif name == "operator" and bound["operator"] == "vortx.explain":
            assert bound.get("emboss") is False  # drawn as a label
            lines.append({"text": bound["text"], "icon": bound.get("icon", "NONE"), "tooltip": bound["properties"]["text"]})
    return lines


def _line(calls: list, start: str) -> dict:
    (line,) = [line for line in _lines(calls) if line["text"].startswith(start)]
    return line


def test_panels_registered_in_vortx_sidebar_tab(blender) -> None:
    import bpy

    for name in PANELS:
        cls = getattr(bpy.types, name)
        assert (cls.bl_space_type, cls.bl_region_type, cls.bl_category) == ("VIEW_3D", "UI", "VoRTX"), name
    for name in ("VORTX_PT_capture_details", "VORTX_PT_pose_settings"):
        assert getattr(bpy.types, name).bl_parent_id == "VORTX_PT_capture"
    for name in ("VORTX_PT_model", "VORTX_PT_tiles", "VORTX_PT_result", "VORTX_PT_advanced"):
        assert getattr(bpy.types, name).bl_parent_id == "VORTX_PT_reconstruction", name
    assert bpy.types.VORTX_PT_stereo.bl_parent_id == "VORTX_PT_advanced"
    # Details and raw knobs are closed until the user opens them.
    closed = {name for name in PANELS if "DEFAULT_CLOSED" in getattr(getattr(bpy.types, name), "bl_options", set())}
    assert closed == {"VORTX_PT_capture_details", "VORTX_PT_pose_settings", "VORTX_PT_model", "VORTX_PT_advanced"}


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
    lines = _lines(_draw("VORTX_PT_capture", bpy.context))
    assert [line["text"] for line in lines] == ["living-room", "Frames: 60, 1920 x 1080", "Poses: none (Estimate Poses)"]
    assert lines[0]["tooltip"] == "/captures/living-room/"  # the whole path on hovering the name
    assert lines[1]["tooltip"] == "60 photos of 1920 x 1080 px (transforms)"

    settings.posed_frame_count, settings.pose_source, settings.poses_metric = 60, "given", True
    settings.pose_status = "All 60 posed (transforms)"
    settings.scale_source = "metric capture"
    calls = _draw("VORTX_PT_capture", bpy.context)
    assert _line(calls, "Poses") == {"text": "Poses: 60 of 60, given", "icon": "NONE", "tooltip": "All 60 posed (transforms)"}
    assert _line(calls, "Scale")["text"] == "Scale: metric, from the capture"
    details = [line["text"] for line in _lines(_draw("VORTX_PT_capture_details", bpy.context))]
    assert details[:3] == ["Format: transforms", "Resolution: 1920 x 1080", "Poses: All 60 posed (transforms)"]


def test_capture_panel_says_the_scale_in_one_line_and_warns_in_one_line(blender, empty_scene) -> None:
    """One line each for frames, poses and scale; a warning is one line with an icon whose tooltip is
    the whole text; the derivation is in the Details sub-panel, whole."""
    import bpy

    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 12, 12, False
    settings.pose_source = "SfM"
    settings.scale_source = "unknown"
    settings.scale_description = "no floor found in the sparse points (no points below the cameras): scale unknown, SfM units kept"
    settings.skipped_count, settings.skipped_names = 2, "IMG_0003.jpg, IMG_0007.jpg"
    calls = _draw("VORTX_PT_capture", bpy.context)
    assert _line(calls, "Poses")["text"] == "Poses: 12 of 12, by SfM"
    scale = _line(calls, "Scale")
    assert (scale["text"], scale["icon"]) == ("Scale: unknown", "ERROR")
    assert scale["tooltip"].startswith(settings.scale_description) and "Set Scale" in scale["tooltip"]
    skipped = _line(calls, "2 photos")
    assert (skipped["text"], skipped["icon"]) == ("2 photos skipped", "ERROR")
    assert "IMG_0003.jpg, IMG_0007.jpg" in skipped["tooltip"]
    # No line of the panel repeats the long description: it is in the tooltip and in Details.
    assert not any("sparse points" in line["text"] for line in _lines(calls))
    details = _lines(_draw("VORTX_PT_capture_details", bpy.context))
    shown = " ".join(line["text"] for line in details)
    assert f"Scale: {settings.scale_description}" in shown
    assert "2 skipped: IMG_0003.jpg, IMG_0007.jpg" in shown

    settings.poses_metric, settings.scale_source, settings.scale_uncertainty = True, "camera height over the floor", 0.12
    settings.scale_description = "metric scale x0.993 +-12 % from the camera height over the floor (sparse points)"
    settings.skipped_count = 0
    calls = _draw("VORTX_PT_capture", bpy.context)
    scale = _line(calls, "Scale")
    assert scale == {"text": "Scale: metric, +-12 %, from the floor", "icon": "NONE", "tooltip": settings.scale_description}
    assert not any("skipped" in line["text"] for line in _lines(calls))

    settings.scale_source = "camera height guess (no floor seen)"
    scale = _line(_draw("VORTX_PT_capture", bpy.context), "Scale")
    assert (scale["text"], scale["icon"]) == ("Scale: guessed, no floor seen", "ERROR")


def test_capture_panel_warns_in_one_line_when_the_poses_look_off(blender, empty_scene) -> None:
    import bpy

    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 40, 40, True
    settings.scale_source, settings.scale_uncertainty = "floor and ceiling", 0.06
    settings.scale_description = "metric scale x0.74 +-6 % from the floor and ceiling (dense depth): camera height 2.03 units"
    settings.pose_check = ("the given poses look off: points triangulated with them reproject 1.60 px from where the "
                           "photos show them; refine them against the photos: --refine-poses")
    calls = _draw("VORTX_PT_capture", bpy.context)
    assert _line(calls, "Scale")["text"] == "Scale: metric, +-6 %, floor and ceiling"
    off = _line(calls, "Poses look off")
    assert (off["text"], off["icon"], off["tooltip"]) == ("Poses look off: Refine Poses", "ERROR", settings.pose_check)
    # Reconstruct would refine them first: the switch that keeps them as given sits under its button.
    reconstruction = _draw("VORTX_PT_reconstruction", bpy.context)
    assert "keep_given_poses" in [bound.get("property") for name, bound in reconstruction if name == "prop"]
    settings.pose_check = ""
    assert not any("look off" in line["text"] for line in _lines(_draw("VORTX_PT_capture", bpy.context)))
    reconstruction = _draw("VORTX_PT_reconstruction", bpy.context)
    assert "keep_given_poses" not in [bound.get("property") for name, bound in reconstruction if name == "prop"]


def test_explain_shows_its_text_as_the_tooltip_and_reports_it(blender, empty_scene, capsys) -> None:
    import bpy

    explain = bpy.types.VORTX_OT_explain
    assert explain.description(bpy.context, SimpleNamespace(text="Skipped: IMG_0003.jpg")) == "Skipped: IMG_0003.jpg"
    assert bpy.ops.vortx.explain(text="Skipped: IMG_0003.jpg", level="WARNING") == {"FINISHED"}
    assert "Warning: Skipped: IMG_0003.jpg" in capsys.readouterr().out  # background mode prints reports


def test_capture_panel_shows_running_job(blender, empty_scene) -> None:
    import bpy

    with job_paused_at(blender.vortx_blender.jobs, "Estimate Poses", "matching", 3, 12):
        (progress,) = [c[1] for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.25)
        assert "matching 3/12" in progress["text"]
    assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]


@pytest.mark.parametrize(
    "panel, expected",
    [
        ("VORTX_PT_reconstruction", ["method", "quality", "voxel_size", "result_mode"]),
        ("VORTX_PT_stereo", ["stereo_matcher", "stereo_image_size", "stereo_views", "stereo_planes", "stereo_sources",
                             "stereo_min_ncc", "stereo_consistency"]),
        ("VORTX_PT_pose_settings", ["sfm_features", "sfm_matcher", "sfm_max_image_side", "camera_height"]),
        ("VORTX_PT_model", ["weights_source", "device", "seed", "view_count", "tile_size", "image_size"]),
        ("VORTX_PT_tiles", ["show_tiles"]),
        ("VORTX_PT_result", ["finish", "min_piece_faces", "min_piece_fraction", "target_faces", "texture_size", "face_budget",
                             *(["headset"] if "headset" in RECON_NAMES else [])]),  # the headset: being added
        ("VORTX_PT_advanced", ["frustum_depth", "max_room_size", "colour_views", "sensor_depth"]),
    ],
)
def test_settings_panels_show_their_properties(blender, empty_scene, panel: str, expected: list[str]) -> None:
    import bpy

    props = [c[1]["property"] for c in _draw(panel, bpy.context) if c[0] == "prop"]
    assert props == expected


def test_result_limits_say_off_while_they_do_nothing(blender, empty_scene) -> None:
    """A piece or face limit at 0 does nothing: the panel says "Off" beside it; a set limit shows no "Off"."""
    import bpy

    settings = empty_scene.vortx
    settings.min_piece_faces, settings.min_piece_fraction, settings.target_faces = 0, 0.0, 0
    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert labels.count("Off") == 3
    settings.min_piece_faces, settings.target_faces = 50, 200_000
    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert labels.count("Off") == 1  # the piece share only


def test_weights_file_shown_only_when_chosen(blender, empty_scene) -> None:
    import bpy

    empty_scene.vortx.weights_source = "FILE"
    props = [c[1]["property"] for c in _draw("VORTX_PT_model", bpy.context) if c[0] == "prop"]
    assert props[:4] == ["weights_source", "weights_path", "device", "seed"]


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

    with job_paused_at(blender.vortx_blender.jobs, "Reconstruct", "fusion 16 cm", 2, 8, "tiles 2/8 done, 1 running"):
        (progress,) = [c[1] for c in _draw("VORTX_PT_reconstruction", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.25)
        assert progress["text"] in ("fusion 16 cm 2/8, tiles 2/8 done, 1 running", "fusion 16 cm 2/8")  # as fits
        assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]


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
    shown = " ".join(t for t in labels if t)  # wrapped to the sidebar's width, whole
    assert "Desktop VR: 4096 px, 100,000 faces, PNG" in shown  # the Headset preset's budget (issue 28)
    empty_scene.vortx.headset = "STANDALONE"
    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert "Standalone Headset: 2048 px, 100,000 faces, KTX2 ETC1S, Draco" in " ".join(t for t in labels if t)
    empty_scene.vortx.headset = "DESKTOP"
    assert not any(t and t.startswith("Textured") for t in labels)

    results = blender.vortx_blender.result
    mesh = blender.engine.mesh_io.Mesh(vertices=np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), faces=np.int32([[0, 1, 2]]))
    obj = results.insert_result(empty_scene, mesh, results.Provenance("/captures/hall", {}, "stereo", {}))
    obj["vortx_texture"] = json.dumps({"texture_size": 2048, "stats": {"faces": 1}})
    labels = [c[1].get("text") for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "label"]
    assert "Textured: 2048 px, 1 faces" in labels

    with job_paused_at(blender.vortx_blender.jobs, "Bake Texture", "texture: bake", 3, 6):
        (progress,) = [c[1] for c in _draw("VORTX_PT_result", bpy.context) if c[0] == "progress"]
        assert progress["factor"] == pytest.approx(0.5) and "texture: bake 3/6" in progress["text"]
        assert not [c for c in _draw("VORTX_PT_capture", bpy.context) if c[0] == "progress"]


def test_details_wrap_long_text_whole_to_the_sidebar_width(blender, empty_scene) -> None:
    """Long text (Details) is wrapped by Blender's own text width to the sidebar it is drawn in: every
    word is shown, no line is wider than the sidebar shows, and a wider sidebar takes fewer lines."""
    import bpy

    sidebar = blender.ui.sidebar
    settings = empty_scene.vortx
    settings.capture_path = "/captures/kitchen/"
    settings.frame_count, settings.posed_frame_count, settings.poses_metric = 36, 36, True
    settings.pose_status = "36 of 36 posed by SfM, scaled by the camera height over the floor, +-12 %"
    settings.scale_source, settings.scale_uncertainty = "camera height over the floor", 0.12
    settings.scale_description = ("metric scale x0.993 +-12 % from the camera height over the floor (sparse points): camera "
                                  "height 1.5 units (sparse points); floor plane from 891 points (RANSAC inliers 37 % of "
                                  "the 2377 points below the cameras)")

    def details(width_px: float) -> list[dict]:
        calls: list = []
        blender.ui.panels.draw_capture_details(RecordingLayout(calls), settings, width_px)
        return _lines(calls)

    lines = details(sidebar.CONTENT_PX)
    texts = [line["text"] for line in lines]
    start = next(i for i, t in enumerate(texts) if t.startswith("Scale:"))
    assert " ".join(texts[start:]) == f"Scale: {settings.scale_description}"
    assert len(texts) - start >= 4  # wrapped, not one cut line
    assert max(sidebar.text_width(t) for t in texts) <= sidebar.line_px()
    assert len(details(2 * sidebar.CONTENT_PX)) < len(lines)
    for width in range(120, 400, 7):  # a unit never starts a line: "+-12" then "%" read as two things
        assert not any(line == "%" or line.startswith("% ") for line in sidebar.wrap(settings.pose_status, width))
    # The width a panel draws into: the region's, less the tab strip and margins, at UI scale 1.
    scale = bpy.context.preferences.system.ui_scale or 1.0  # 0 without a window
    assert sidebar.content_px(SimpleNamespace(region=SimpleNamespace(width=600))) == pytest.approx(
        600 / scale * sidebar.WINDOW_SCALE - sidebar.MARGIN_PX)
    assert sidebar.content_px(SimpleNamespace(region=None)) == sidebar.CONTENT_PX
