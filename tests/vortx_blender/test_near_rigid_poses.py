"""A tracker's transforms.json whose rotations are orthonormal only to ~1e-4 imports into Blender
(issue 12: the CLI accepted it, Blender refused it), and Blender refuses what the engine refuses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fixtures_capture import ring_poses, write_photo_folder, write_transforms_json

OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def _stretched(pose: np.ndarray, amount: float, seed: int) -> np.ndarray:
    """Rotation R replaced by R (I + S), S symmetric: the nearest rotation is still R."""
    S = np.random.default_rng(seed).uniform(-amount, amount, (3, 3))
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ (np.eye(3) + (S + S.T) / 2)
    return out


def test_near_rigid_transforms_json_imports_with_a_warning(blender, empty_scene, tmp_path: Path, capfd) -> None:
    import bpy

    exact = ring_poses(5, radius=2.0, height=1.4)
    stored = [_stretched(p, 2e-4, seed=i) for i, p in enumerate(exact)]  # det ~0.9998, as in the issue
    assert max(abs(np.linalg.det(p[:3, :3]) - 1.0) for p in stored) > 1e-4
    write_photo_folder(tmp_path / "cap" / "images", 5, (64, 48), suffix=".jpg")
    path = write_transforms_json(tmp_path / "cap" / "transforms.json",
                                 [(f"images/frame{i}.jpg", p) for i, p in enumerate(stored)], fl_x=60.0, w=64, h=48)

    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o),
                     key=lambda o: o["vortx_frame"])
    assert len(cameras) == 5
    for obj, truth in zip(cameras, exact):
        pose = np.array(obj["vortx_pose"]).reshape(4, 4)  # the engine's repaired pose, stored exactly
        assert np.max(np.abs(pose[:3, :3].T @ pose[:3, :3] - np.eye(3))) < 1e-12
        np.testing.assert_allclose(np.array(obj.matrix_world), pose @ OPENGL_FROM_OPENCV, atol=1e-5)
    # The scene shows the file's cameras (repaired), in the frame the import put them in: relative
    # rotations between cameras are those of the exact poses.
    first = np.array(cameras[0]["vortx_pose"]).reshape(4, 4)
    for obj, truth in zip(cameras[1:], exact[1:]):
        relative = first[:3, :3].T @ np.array(obj["vortx_pose"]).reshape(4, 4)[:3, :3]
        np.testing.assert_allclose(relative, exact[0][:3, :3].T @ truth[:3, :3], atol=1e-9)
    assert "5 of 5 poses were not exactly rotations" in capfd.readouterr().out


def test_blender_refuses_a_scaled_rotation_naming_the_frame_and_deviation(blender, tmp_path: Path) -> None:
    from_engine = blender.engine.capture
    pose = ring_poses(2)[0]
    pose[:3, :3] *= 1.05
    K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    capture = from_engine.Capture(root=tmp_path, format="transforms",
                                  frames=[from_engine.Frame(tmp_path / "a.jpg", 64, 48, K, pose)])
    with pytest.raises(blender.engine.errors.PoseError, match=r"frame a\.jpg.*\|R\^T R - I\| = 0\.1"):
        blender.vortx_blender.cameras.plan_capture_cameras(capture)
