"""Estimate Poses brings SfM's sparse points in as the point cloud; Refine Poses moves the cameras to
the refined poses, reports the change and the refused frames, and changes nothing when it fails. The
engine's SfM and refinement are replaced by stand-ins here (the real ones have their own tests)."""

from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import look_at_pose, scene_state


def _capture(blender, root: Path, count: int = 5, posed: bool = True, fmt: str = "transforms"):
    model = blender.engine.capture
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    frames = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        pose = look_at_pose([2 * np.cos(angle), 2 * np.sin(angle), 1.5], [0, 0, 1]) if posed else None
        frames.append(model.Frame(image_path=root / f"{i:04d}.jpg", width=320, height=240, K=K.copy(), pose=pose))
    return model.Capture(root=root, format=fmt, frames=frames, metric=True)


def _camera_poses(bpy) -> list[np.ndarray]:
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o), key=lambda o: o["vortx_frame"])
    return [np.array(o["vortx_pose"]).reshape(4, 4) for o in cameras]


def _poses_module(blender):
    return importlib.import_module(f"{blender.__name__}.engine.poses")


def test_estimate_poses_shows_the_sfm_points(blender, empty_scene, monkeypatch, tmp_path: Path) -> None:
    import bpy

    poses = _poses_module(blender)
    blender.vortx_blender.capture.apply_capture(empty_scene, _capture(blender, tmp_path, posed=False, fmt="images"), tmp_path)
    blender.vortx_blender.capture.remember_loaded_capture(empty_scene, tmp_path, _capture(blender, tmp_path, posed=False, fmt="images"))
    rng = np.random.default_rng(0)
    points = rng.uniform(-2, 2, (50, 3))
    colours = rng.integers(0, 256, (50, 3)).astype(np.uint8)

    def fake_estimate(capture, options=None, progress=None, cancel=None):
        posed = _capture(blender, tmp_path)
        alignment = poses.Alignment(posed, poses.Similarity.identity(), points, "camera height", "scaled")
        return poses.PoseResult(
            capture=posed, registered=[f.name for f in posed.frames], unregistered=[], model_sizes=[5],
            matcher="exhaustive", camera_model="PINHOLE", K=posed.frames[0].K, radial_distortion=[],
            mean_reprojection_error=0.3, points=points, point_colors=colours, scaled_size=(320, 240), alignment=alignment,
        )

    monkeypatch.setattr(poses, "estimate_poses", fake_estimate)
    assert bpy.ops.vortx.estimate_poses() == {"FINISHED"}
    shown, shown_colours = blender.vortx_blender.point_cloud.scene_points(empty_scene)
    np.testing.assert_allclose(shown, points, atol=1e-6)
    np.testing.assert_array_equal(shown_colours, colours)
    assert blender.vortx_blender.point_cloud.find_point_cloud(empty_scene).hide_render, "a viewport guide, not in renders"
    # The stand-in's points show no floor, so the scale stays the camera-height guess and says so (scale.py).
    assert empty_scene.vortx.scale_source == "camera height guess (no floor seen)"
    assert empty_scene.vortx.scale_description.endswith("; scaled") and empty_scene.vortx.scale_uncertainty > 0


def _refine_result(blender, capture, moved: dict[int, np.ndarray], refused: list[int]):
    refine = importlib.import_module(f"{blender.__name__}.engine.poses.refine")
    frames, changes = [], []
    for index, frame in enumerate(capture.frames):
        pose = moved.get(index, frame.pose)
        frames.append(blender.engine.capture.Frame(frame.image_path, frame.width, frame.height, frame.K, pose))
        if index in refused:
            changes.append(refine.FrameChange(frame.name, 25.0, 1.8, refine.STATUS_REFUSED, "turned 25 deg"))
        else:
            shift = float(np.linalg.norm(pose[:3, 3] - frame.pose[:3, 3]))
            changes.append(refine.FrameChange(frame.name, 0.4 if index in moved else 0.0, shift, refine.STATUS_REFINED))
    return refine.RefineResult(
        capture=capture.with_frames(frames), changes=changes, units="m", points=np.zeros((0, 3)),
        point_colors=np.zeros((0, 3), np.uint8), mean_reprojection_error=0.4, error_given_px=1.6, scaled_size=(320, 240),
        adjusted_frames=len(frames), adjustment=refine.PASS_HELD, focal_scale=[1.0],
    )


def test_refine_poses_moves_the_cameras_and_lists_refused_frames(blender, empty_scene, monkeypatch, tmp_path: Path, capfd) -> None:
    import bpy

    poses = _poses_module(blender)
    assert not bpy.ops.vortx.refine_poses.poll()  # no posed capture yet
    blender.vortx_blender.capture.apply_capture(empty_scene, _capture(blender, tmp_path), tmp_path)
    given = _camera_poses(bpy)
    nudged = given[1].copy()
    nudged[:3, 3] += [0.03, -0.01, 0.0]
    seen = []

    def fake_refine(capture, options=None, progress=None, cancel=None):
        seen.append(capture)
        return _refine_result(blender, capture, {1: nudged}, refused=[3])

    monkeypatch.setattr(poses, "refine_poses", fake_refine)
    assert bpy.ops.vortx.refine_poses() == {"FINISHED"}
    (capture,) = seen
    np.testing.assert_allclose(np.stack([f.pose for f in capture.frames]), np.stack(given))  # the scene's cameras
    after = _camera_poses(bpy)
    np.testing.assert_allclose(after[1], nudged)
    for index in (0, 2, 3, 4):
        np.testing.assert_allclose(after[index], given[index])
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA"), key=lambda o: o["vortx_frame"])
    np.testing.assert_allclose(np.array(cameras[1].matrix_world)[:3, 3], nudged[:3, 3], atol=1e-6)
    out = capfd.readouterr().out
    assert "Refined 4 of 5 posed frames: rotation changed by" in out and "3.2 cm max" in out
    assert "0003.jpg refused (turned 25 deg); it keeps its given pose" in out
    assert empty_scene.vortx.pose_status.endswith(", refined")
    # The batch report's poses.refinement: the numbers and each stage's time, as the sidecar has them.
    record = json.loads(empty_scene[blender.vortx_blender.poses.REFINEMENT_RECORD])
    assert record["refined"] == 4 and record["refused"] == {"0003.jpg": "turned 25 deg"}
    assert record["given_reprojection_error_px"] == 1.6 and not record["kept_given"]


def test_a_refinement_that_kept_the_given_poses_leaves_the_cameras_and_says_so(blender, empty_scene, monkeypatch,
                                                                             tmp_path: Path, capfd) -> None:
    import bpy

    poses = _poses_module(blender)
    blender.vortx_blender.capture.apply_capture(empty_scene, _capture(blender, tmp_path), tmp_path)
    given = _camera_poses(bpy)
    nudged = given[1].copy()
    nudged[:3, 3] += [0.03, -0.01, 0.0]

    def fake_refine(capture, options=None, progress=None, cancel=None):
        result = _refine_result(blender, capture, {1: nudged}, refused=[])
        return dataclasses.replace(result, capture=capture, kept_given="the refined poses explain the photos no better: "
                                   "0.41 px mean reprojection error against 0.42 px with the given ones")

    monkeypatch.setattr(poses, "refine_poses", fake_refine)
    assert bpy.ops.vortx.refine_poses() == {"FINISHED"}
    np.testing.assert_allclose(np.stack(_camera_poses(bpy)), np.stack(given))
    assert "Kept the given poses: the refined poses explain the photos no better" in capfd.readouterr().out
    # The status line says so; its tooltip (the whole status) gives the numbers.
    assert ", kept as given (the refined poses explain the photos no better: " in empty_scene.vortx.pose_status
    assert not empty_scene.vortx.pose_check
    assert blender.ui.panels.poses_line(empty_scene.vortx).endswith(", kept as given")
    assert json.loads(empty_scene[blender.vortx_blender.poses.REFINEMENT_RECORD])["kept_given"].startswith("the refined")


def test_failed_refine_poses_changes_nothing(blender, empty_scene, monkeypatch, tmp_path: Path) -> None:
    import bpy

    poses = _poses_module(blender)
    blender.vortx_blender.capture.apply_capture(empty_scene, _capture(blender, tmp_path), tmp_path)
    bpy.context.view_layer.update()  # matrix_world as evaluated, as after any operator
    before = scene_state(empty_scene)

    def failing_refine(capture, options=None, progress=None, cancel=None):
        raise blender.engine.errors.PoseError("pose refinement refused: 3 of 5 frames moved by metres")

    monkeypatch.setattr(poses, "refine_poses", failing_refine)
    with pytest.raises(RuntimeError, match="3 of 5 frames moved by metres"):
        bpy.ops.vortx.refine_poses()
    assert scene_state(empty_scene) == before
