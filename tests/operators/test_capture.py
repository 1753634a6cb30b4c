"""The capture operators through bpy.ops, headless (so they run blocking).

The engine's loader is replaced by a stand-in here, which pins down the operator's own behaviour
(what it writes, what it leaves alone on failure) independently of the loaders; the tests in
tests/vortx_blender/test_capture_real.py run the real loaders and SfM.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import look_at_pose, scene_state


def _capture(blender, root: Path, count: int, posed: bool = True, fmt: str = "transforms"):
    model = blender.engine.capture
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    frames = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        pose = look_at_pose([2 * np.cos(angle), 2 * np.sin(angle), 1.5], [0, 0, 1]) if posed else None
        frames.append(model.Frame(image_path=root / f"{i:04d}.jpg", width=320, height=240, K=K.copy(), pose=pose))
    return model.Capture(root=root, format=fmt, frames=frames, metric=posed, warnings=["2 duplicate photos dropped"])


@pytest.fixture
def fake_loader(blender, monkeypatch):
    """Make engine.capture.load_capture return (or raise) what the test says; records its calls."""
    calls: list = []
    outcome: dict = {}

    def load_capture(path, progress=None, cancel=None, **options):
        calls.append(Path(path))
        if progress is not None:
            progress("checking photos", 1, 1)
        if isinstance(outcome.get("value"), BaseException):
            raise outcome["value"]
        return outcome["value"]

    monkeypatch.setattr(blender.engine.capture, "load_capture", load_capture, raising=False)
    return outcome, calls


def test_import_fills_panel_and_creates_cameras(blender, empty_scene, fake_loader, tmp_path: Path) -> None:
    import bpy

    outcome, calls = fake_loader
    outcome["value"] = _capture(blender, tmp_path, 6)
    assert bpy.ops.vortx.import_capture(filepath=str(tmp_path)) == {"FINISHED"}
    assert calls == [tmp_path]
    settings = empty_scene.vortx
    assert settings.capture_path == str(tmp_path)
    assert (settings.capture_format, settings.frame_count, settings.posed_frame_count) == ("transforms", 6, 6)
    assert (settings.resolution_x, settings.resolution_y) == (320, 240)
    assert settings.pose_status == "All 6 posed (transforms), metric" and settings.poses_metric
    cameras = [o for o in bpy.data.collections["VoRTX Capture"].objects if o.type == "CAMERA"]
    assert len(cameras) == 6

    # Re-import a different capture: its cameras replace the old ones.
    outcome["value"] = _capture(blender, tmp_path, 4)
    assert bpy.ops.vortx.import_capture(filepath=str(tmp_path)) == {"FINISHED"}
    assert len([o for o in bpy.data.objects if o.type == "CAMERA"]) == 4
    assert empty_scene.vortx.frame_count == 4


def test_import_records_the_similarity_from_the_capture_frame(blender, empty_scene, fake_loader, tmp_path: Path) -> None:
    """A capture in arbitrary units and orientation is moved to the Z-up world; scene.vortx.capture_frame
    records the similarity that did it (as `engine reconstruct`'s sidecar does), so a script can map
    the scene's cameras and results back onto the capture's own coordinates, also after Set Scale."""
    import bpy

    from dataclasses import replace

    Similarity = blender.engine.poses.align.Similarity
    a = np.deg2rad(35.0)
    tilt = Similarity(np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]),
                      np.array([0.4, -2.0, 3.0]), 0.6)
    level = _capture(blender, tmp_path, 6)
    given = [tilt.apply_pose(f.pose) for f in level.frames]
    outcome, _ = fake_loader
    outcome["value"] = level.with_frames([replace(f, pose=p) for f, p in zip(level.frames, given)], metric=False)
    assert bpy.ops.vortx.import_capture(filepath=str(tmp_path)) == {"FINISHED"}

    def recorded(key: str):
        entry = json.loads(empty_scene.vortx.capture_frame)[key]
        return Similarity(np.array(entry["rotation"]), np.array(entry["translation"]), entry["scale"])

    scene_poses = [f.pose for f in blender.vortx_blender.cameras.posed_capture_from_scene(empty_scene).frames]
    to_world, to_capture = recorded("capture_to_world"), recorded("world_to_capture")
    assert abs(np.linalg.det(to_world.rotation) - 1) < 1e-9 and to_world.rotation[2] @ tilt.rotation[:, 2] > 0.99
    for given_pose, scene_pose in zip(given, scene_poses):
        np.testing.assert_allclose(to_world.apply_pose(given_pose), scene_pose, atol=1e-9)
        np.testing.assert_allclose(to_capture.apply_pose(scene_pose), given_pose, atol=1e-9)

    # Set Scale doubles the world: the record follows.
    cameras = sorted((o for o in bpy.data.collections["VoRTX Capture"].objects if o.type == "CAMERA"), key=lambda o: o.name)
    PickedPoint = blender.vortx_blender.scale.PickedPoint
    first, second = (np.array(c.matrix_world.translation) for c in cameras[:2])
    blender.vortx_blender.scale.set_scale(
        empty_scene, [PickedPoint("camera a", first), PickedPoint("camera b", second)], 2 * float(np.linalg.norm(first - second)))
    scene_poses = [f.pose for f in blender.vortx_blender.cameras.posed_capture_from_scene(empty_scene).frames]
    for given_pose, scene_pose in zip(given, scene_poses):
        np.testing.assert_allclose(recorded("capture_to_world").apply_pose(given_pose), scene_pose, atol=1e-6)


def test_import_without_poses_clears_old_cameras(blender, empty_scene, fake_loader, tmp_path: Path) -> None:
    import bpy

    outcome, _ = fake_loader
    outcome["value"] = _capture(blender, tmp_path, 5)
    bpy.ops.vortx.import_capture(filepath=str(tmp_path))
    outcome["value"] = _capture(blender, tmp_path, 5, posed=False, fmt="images")
    assert bpy.ops.vortx.import_capture(filepath=str(tmp_path)) == {"FINISHED"}
    assert not [o for o in bpy.data.objects if o.type == "CAMERA"]
    assert empty_scene.vortx.pose_status == "No poses: run Estimate Poses"
    assert not empty_scene.vortx.poses_metric


def _nan_pose_capture(blender, root: Path):
    capture = _capture(blender, root, 5)
    capture.frames[3].pose[1, 1] = np.nan
    return capture


@pytest.mark.parametrize(
    "failure, message",
    [
        (lambda blender, root: blender.engine.errors.CaptureError(f"no JPEG or PNG photos in {root}"), "no JPEG or PNG photos"),
        (lambda blender, root: blender.engine.errors.CaptureError("photo 0002.jpg is corrupt or truncated"), "0002.jpg is corrupt"),
        (_nan_pose_capture, "0003.jpg"),
    ],
    ids=["empty folder", "corrupt image", "NaN pose"],
)
def test_failed_import_reports_and_changes_nothing(blender, empty_scene, fake_loader, tmp_path: Path, failure, message: str) -> None:
    import bpy

    outcome, _ = fake_loader
    outcome["value"] = _capture(blender, tmp_path, 3)
    bpy.ops.vortx.import_capture(filepath=str(tmp_path))  # a previous import the failure must not disturb
    before = scene_state(empty_scene)

    outcome["value"] = failure(blender, tmp_path / "other")
    (tmp_path / "other").mkdir()
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.vortx.import_capture(filepath=str(tmp_path / "other"))
    assert scene_state(empty_scene) == before


def test_import_without_a_path_is_refused(blender, empty_scene, fake_loader) -> None:
    import bpy

    _, calls = fake_loader
    with pytest.raises(RuntimeError, match="Choose a capture folder or file"):
        bpy.ops.vortx.import_capture()
    assert calls == []


def test_resolve_capture_path(blender, tmp_path: Path) -> None:
    resolve = blender.vortx_blender.capture.resolve_capture_path
    json_file = tmp_path / "transforms.json"
    json_file.write_text("{}")
    assert resolve(str(json_file)) == json_file
    assert resolve(str(tmp_path) + "/") == tmp_path  # folder accepted in the browser with no file picked
    assert resolve("", str(tmp_path)) == tmp_path
    assert resolve(str(tmp_path / "missing.json"), str(tmp_path)) == tmp_path
    assert resolve("", "") is None


def test_estimate_poses_needs_an_imported_capture(blender, empty_scene) -> None:
    import bpy

    assert not bpy.ops.vortx.estimate_poses.poll()
    empty_scene.vortx.capture_path = "/somewhere"
    assert bpy.ops.vortx.estimate_poses.poll()


def test_estimate_poses_applies_engine_result(blender, empty_scene, fake_loader, monkeypatch, tmp_path: Path) -> None:
    """The operator's side of pose estimation, with the SfM run replaced (the real one: tests/vortx_blender/test_capture_real.py)."""
    import bpy

    poses = importlib.import_module(f"{blender.__name__}.engine.poses")  # loaded lazily by the extension
    outcome, calls = fake_loader
    imported = outcome["value"] = _capture(blender, tmp_path, 6, posed=False, fmt="images")
    bpy.ops.vortx.import_capture(filepath=str(tmp_path))
    seen_options, seen_captures = [], []

    def fake_estimate(capture, options=None, progress=None, cancel=None):
        seen_options.append(options)
        seen_captures.append(capture)
        posed = _capture(blender, tmp_path, 6)
        posed.frames[5].pose = None  # one photo SfM could not place
        alignment = poses.Alignment(posed, poses.Similarity.identity(), None, "camera height", "scaled")
        return poses.PoseResult(
            capture=posed, registered=[f.name for f in posed.frames[:5]], unregistered=[posed.frames[5].name],
            model_sizes=[5], matcher="exhaustive", camera_model="PINHOLE", K=posed.frames[0].K, radial_distortion=[],
            mean_reprojection_error=0.3, points=np.zeros((0, 3)), point_colors=np.zeros((0, 3), np.uint8),
            scaled_size=(320, 240), alignment=alignment, warnings=["1 of 6 photos not registered: 0005.jpg"],
        )

    monkeypatch.setattr(poses, "estimate_poses", fake_estimate)
    empty_scene.vortx.sfm_matcher = "SEQUENTIAL"
    empty_scene.vortx.sfm_features = "LEARNED"
    empty_scene.vortx.camera_height = 1.7
    empty_scene.vortx.sfm_max_image_side = 800
    assert bpy.ops.vortx.estimate_poses() == {"FINISHED"}
    (options,) = seen_options
    assert (options.matcher, options.camera_height, options.max_side, options.align) == ("sequential", pytest.approx(1.7), 800, True)
    assert options.features == "learned"
    settings = empty_scene.vortx
    assert settings.posed_frame_count == 5 and settings.frame_count == 6
    # No sparse points in the stand-in, so no floor: the camera-height guess, said as such (scale.py).
    assert settings.pose_status == "5 of 6 posed by SfM, scaled by the camera height guess (no floor seen), +-30 %"
    assert len([o for o in bpy.data.objects if o.type == "CAMERA"]) == 5
    # SfM ran on the capture Import loaded, which was not loaded from disk a second time.
    assert calls == [tmp_path] and seen_captures[0] is imported

    # SfM's poses have no coordinates of the capture's own: the record says so instead of a similarity.
    frame = json.loads(settings.capture_frame)
    assert frame["capture_to_world"] is None and "structure from motion" in frame["note"]

    # A scene this session did not import (a reopened .blend) loads the capture from disk.
    blender.vortx_blender.capture._loaded_captures.clear()
    assert bpy.ops.vortx.estimate_poses() == {"FINISHED"}
    assert calls == [tmp_path, tmp_path]


def test_estimate_poses_failure_changes_nothing(blender, empty_scene, fake_loader, monkeypatch, tmp_path: Path) -> None:
    import bpy

    poses = importlib.import_module(f"{blender.__name__}.engine.poses")  # loaded lazily by the extension
    outcome, _ = fake_loader
    outcome["value"] = _capture(blender, tmp_path, 6, posed=False, fmt="images")
    bpy.ops.vortx.import_capture(filepath=str(tmp_path))
    before = scene_state(empty_scene)

    def failing_estimate(capture, options=None, progress=None, cancel=None):
        raise blender.engine.errors.PoseError("no camera poses could be estimated for the 6 photos")

    monkeypatch.setattr(poses, "estimate_poses", failing_estimate)
    with pytest.raises(RuntimeError, match="no camera poses could be estimated"):
        bpy.ops.vortx.estimate_poses()
    assert scene_state(empty_scene) == before
