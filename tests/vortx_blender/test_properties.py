"""scene.vortx: defaults, units, and values saved with the .blend file."""

from __future__ import annotations

from pathlib import Path

import pytest


def test_defaults_and_units(blender, empty_scene) -> None:
    settings = empty_scene.vortx
    assert settings.voxel_size == pytest.approx(0.04)
    assert settings.view_count == 60
    assert settings.tile_size == 96
    assert settings.show_tiles is True
    assert settings.sfm_matcher == "AUTO"
    assert settings.camera_height == pytest.approx(1.5)
    assert settings.capture_path == "" and settings.frame_count == 0
    rna = settings.bl_rna.properties
    assert (rna["voxel_size"].subtype, rna["voxel_size"].unit) == ("DISTANCE", "LENGTH")
    assert (rna["camera_height"].subtype, rna["camera_height"].unit) == ("DISTANCE", "LENGTH")
    assert set(rna["sfm_matcher"].enum_items.keys()) == {"AUTO", "SEQUENTIAL", "EXHAUSTIVE"}
    # The Features menu offers the engine's choices, its default the engine's default.
    from engine.poses.sfm import FEATURES, SfmOptions

    assert [k.lower() for k in rna["sfm_features"].enum_items.keys()] == list(FEATURES)
    assert settings.sfm_features.lower() == SfmOptions.features
    assert (settings.weights_source, settings.weights_path, settings.device, settings.seed) == ("DEFAULT", "", "CPU", 0)
    assert (settings.result_mode, settings.min_piece_faces, settings.min_piece_fraction, settings.target_faces) == ("REPLACE", 0, 0.0, 0)
    assert (settings.image_size, settings.colour_views) == (0, 40)  # 0: the weights decide
    assert tuple(settings.max_room_size) == pytest.approx((20.0, 20.0, 6.0))
    assert set(rna["weights_source"].enum_items.keys()) == {"DEFAULT", "FILE", "RANDOM"}
    assert set(rna["result_mode"].enum_items.keys()) == {"REPLACE", "ADD"}


def test_values_survive_save_and_reopen(blender, empty_scene, tmp_path: Path) -> None:
    import bpy

    values = {
        "output_frame": "CAPTURE",  # set before capture_frame: with no record yet, the choice waits for an import
        "capture_path": str(tmp_path / "room"),
        "capture_format": "scannet",
        "frame_count": 321,
        "posed_frame_count": 300,
        "resolution_x": 640,
        "resolution_y": 480,
        "poses_metric": True,
        "pose_status": "300 of 321 posed by SfM",
        "pose_source": "SfM",
        "scale_source": "camera height",
        "scale_description": "floor plane from 900 points, median camera height 1.1 units -> scaled x1.1 to 1.25 m",
        "scale_uncertainty": 0.12,
        "pose_check": "the given poses look off: points triangulated with them reproject 1.60 px from where the photos show them",
        "capture_frame": '{"frame": "world"}',
        "skipped_count": 2,
        "skipped_names": "IMG_7.jpg, IMG_9.jpg",
        "voxel_size": 0.08,
        "view_count": 24,
        "tile_size": 64,
        "show_tiles": False,
        "sfm_matcher": "EXHAUSTIVE",
        "sfm_features": "LEARNED",
        "sfm_max_image_side": 1024,
        "camera_height": 1.25,
        "weights_source": "FILE",
        "weights_path": "//weights/official.safetensors",
        "device": "CPU",
        "seed": 7,
        "image_size": 480,
        "colour_views": 12,
        "max_room_size": (8.0, 9.0, 3.0),
        "frustum_depth": 3.5,
        "sensor_depth": False,
        "result_mode": "ADD",
        "min_piece_faces": 50,
        "min_piece_fraction": 0.02,
        "target_faces": 300000,
        "method": "VORTX",
        "stereo_matcher": "PATCHMATCH",
        "stereo_image_size": 240,
        "stereo_views": 50,
        "stereo_planes": 96,
        "stereo_sources": 6,
        "stereo_min_ncc": 0.4,
        "stereo_consistency": 1,
        "finish": "CLEAN",
        "keep_given_poses": True,
        "quality": "CUSTOM",  # read from the stereo settings above (no preset has them); choosing Custom sets nothing
        "texture_size": 2048,
        "face_budget": 50000,
        "headset": "VISION-PRO",
    }
    settings = empty_scene.vortx
    for name, value in values.items():
        setattr(settings, name, value)
    path = tmp_path / "settings.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.context.scene.vortx.view_count == 60  # really a different scene now
    bpy.ops.wm.open_mainfile(filepath=str(path))

    reopened = blender.vortx_blender.properties.settings_values(bpy.context.scene.vortx)
    assert set(reopened) == set(values), "a scene setting is missing from this test"
    for name, value in values.items():
        assert reopened[name] == (pytest.approx(value) if isinstance(value, float) else value), name


def test_capture_summary_reports_pose_coverage(blender, tmp_path: Path) -> None:
    import numpy as np

    model = blender.engine.capture
    K = np.diag([500.0, 500.0, 1.0])
    frames = [model.Frame(tmp_path / f"{i}.jpg", 640, 480, K, np.eye(4) if i < 2 else None) for i in range(3)]
    summary = blender.vortx_blender.properties.capture_summary
    partial = summary(model.Capture(tmp_path, "colmap", frames, metric=True), str(tmp_path))
    assert partial["pose_status"] == "2 of 3 posed (colmap)"
    assert (partial["frame_count"], partial["posed_frame_count"], partial["poses_metric"]) == (3, 2, True)
    unposed = summary(model.Capture(tmp_path, "images", [model.Frame(tmp_path / "a.jpg", 640, 480, None)], metric=True), "p")
    assert unposed["pose_status"] == "No poses: run Estimate Poses" and unposed["poses_metric"] is False
