"""Reconstruction > Quality: choosing a preset sets the Advanced settings as `engine reconstruct --quality`
does; changing one of them by hand shows Custom; the panel shows the preset's measured time; the batch's
--quality arrives in the scene as the same preset."""

from __future__ import annotations

import importlib

import pytest

from fixtures_blender_ui import RecordingLayout


def _engine(blender):
    return blender.engine.recon.presets


@pytest.mark.parametrize("name", ["preview", "standard", "high"])
def test_a_preset_sets_the_settings_a_run_then_reads(blender, empty_scene, name: str) -> None:
    presets = _engine(blender)
    reconstruct = blender.vortx_blender.reconstruct
    settings = empty_scene.vortx
    settings.stereo_views, settings.stereo_image_size = 7, 999  # hand-set values the preset replaces
    assert settings.quality == "CUSTOM"
    settings.quality = name.upper()
    assert settings.quality == name.upper()
    recon = reconstruct.recon_settings_from_scene(settings, with_weights=False)
    assert recon == presets.apply_quality(blender.engine.recon.settings.ReconSettings(), name)


def test_changing_a_setting_by_hand_shows_custom_and_a_preset_gives_it_back(blender, empty_scene) -> None:
    settings = empty_scene.vortx
    assert settings.quality == "STANDARD"  # a new scene has the defaults
    settings.quality = "PREVIEW"
    settings.stereo_views += 1
    assert settings.quality == "CUSTOM"
    settings.quality = "CUSTOM"  # choosing Custom changes nothing
    assert settings.quality == "CUSTOM"
    settings.quality = "STANDARD"
    defaults = blender.engine.recon.settings.ReconSettings()
    assert (settings.stereo_matcher, settings.stereo_image_size, settings.stereo_views) == (
        defaults.stereo_matcher.upper(), defaults.stereo_image_size, defaults.stereo_views)


def test_the_panel_shows_the_presets_with_their_measured_time(blender, empty_scene) -> None:
    presets = _engine(blender)
    settings = empty_scene.vortx
    items = settings.bl_rna.properties["quality"].enum_items
    assert [item.name for item in items] == ["Preview", "Standard", "High", "Custom"]
    for item, chosen in zip(items, presets.PRESETS):
        assert item.description == chosen.description()  # the tooltip: what it does and its time
    for chosen in presets.PRESETS:
        settings.quality = chosen.name.upper()
        calls: list = []
        blender.ui.panels.draw_reconstruction(RecordingLayout(calls), settings, None)
        hints = [c[1] for c in calls if c[0] == "label" and c[1].get("icon") == "TIME"]
        expected = f"Demo room: {chosen.time_text()}" if chosen.demo_seconds is not None else "Not measured yet"
        assert [h["text"] for h in hints] == [expected]
    settings.stereo_views = 3
    calls = []
    blender.ui.panels.draw_reconstruction(RecordingLayout(calls), settings, None)
    assert not [c for c in calls if c[0] == "label" and c[1].get("icon") == "TIME"]  # Custom: no time to show


def test_the_batch_quality_arrives_in_the_scene_as_that_preset(blender, empty_scene) -> None:
    batch = importlib.import_module(f"{blender.__name__}.vortx_blender.batch")
    args = batch.parse_arguments(["cap", "--out", "a.blend", "--quality", "preview"])
    batch.apply_recon_settings(empty_scene.vortx, args.settings)
    assert empty_scene.vortx.quality == "PREVIEW"
    args = batch.parse_arguments(["cap", "--out", "a.blend", "--quality", "preview", "--stereo-views", "40"])
    batch.apply_recon_settings(empty_scene.vortx, args.settings)
    assert empty_scene.vortx.quality == "CUSTOM" and empty_scene.vortx.stereo_views == 40


def test_quality_is_greyed_out_for_the_vortx_method(blender, empty_scene) -> None:
    settings = empty_scene.vortx
    for method, active in (("STEREO", True), ("VORTX", False)):
        settings.method = method
        calls: list = []
        blender.ui.panels.draw_reconstruction(RecordingLayout(calls), settings, None)
        (quality,) = [c[1] for c in calls if c[0] == "prop" and c[1]["property"] == "quality"]
        assert quality.layout.inherited("active", True) is active


def test_menus_spell_the_method_and_matcher_names(blender, empty_scene) -> None:
    rna = empty_scene.vortx.bl_rna.properties
    assert [item.name for item in rna["method"].enum_items] == ["Stereo", "VoRTX"]
    assert [item.name for item in rna["stereo_matcher"].enum_items] == ["PatchMatch", "Fast"]
