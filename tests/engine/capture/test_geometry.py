"""Near-rigid poses: every loader makes rotations that are orthonormal only to a few digits exact,
with one warning naming the worst frame, and skips frames beyond the tolerance naming how far off.

The files are written with tests/fixtures_capture.py (its own quaternion code); the expected poses
are the exact rotations the files were made from, so the repair is checked against an independent
truth: for a matrix R (I + S) with S small and symmetric, the nearest rotation is R (polar
decomposition).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from engine.capture import load_capture
from engine.capture.geometry import (ROTATION_TOLERANCE, nearest_rotation, quaternion_deviation, rigid_pose,
                                     rotation_deviation)
from fixtures_capture import (colmap_image_entry, intrinsics, ring_poses, write_colmap_binary, write_colmap_text,
                              write_photo_folder, write_scannet, write_transforms_json)

SIZE = (64, 48)


def _stretched(pose: np.ndarray, amount: float, seed: int) -> np.ndarray:
    """`pose` with its rotation R replaced by R (I + S), S symmetric with entries up to `amount`:
    max |M^T M - I| is about 2 * amount, and the nearest rotation is still R."""
    rng = np.random.default_rng(seed)
    S = rng.uniform(-amount, amount, (3, 3))
    S = (S + S.T) / 2
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ (np.eye(3) + S)
    return out


def _assert_rigid_and_equal(loaded: np.ndarray, truth: np.ndarray, atol: float) -> None:
    R = loaded[:3, :3]
    assert np.max(np.abs(R.T @ R - np.eye(3))) < 1e-12 and np.linalg.det(R) > 0
    np.testing.assert_allclose(loaded, truth, atol=atol)


def test_nearest_rotation_recovers_the_rotation_under_a_symmetric_stretch():
    truth = ring_poses(3)[1]
    stretched = _stretched(truth, 3e-3, seed=1)
    assert 1e-3 < rotation_deviation(stretched[:3, :3]) < ROTATION_TOLERANCE
    np.testing.assert_allclose(nearest_rotation(stretched[:3, :3]), truth[:3, :3], atol=1e-12)
    repaired, deviation = rigid_pose(stretched)
    assert deviation == pytest.approx(rotation_deviation(stretched[:3, :3]))
    _assert_rigid_and_equal(repaired, truth, atol=1e-12)


def test_rigid_pose_refuses_reflections_scales_and_a_bad_last_row():
    pose = ring_poses(3)[0]
    reflected = pose @ np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="reflection"):
        rigid_pose(reflected)
    scaled = pose.copy()
    scaled[:3, :3] *= 1.05  # max |M^T M - I| = 1.05^2 - 1 = 0.1025
    with pytest.raises(ValueError, match=r"\|R\^T R - I\| = 0\.1\b"):
        rigid_pose(scaled)
    projective = pose.copy()
    projective[3] = [0.0, 0.0, 0.5, 1.0]
    with pytest.raises(ValueError, match="last row"):
        rigid_pose(projective)
    with pytest.raises(ValueError, match="non-finite"):
        rigid_pose(np.full((4, 4), np.inf))


def test_quaternion_deviation_is_that_of_the_scaled_rotation():
    q = np.array([0.5, 0.5, 0.5, 0.5]) * 1.002
    scaled_rotation = 1.002 * np.eye(3)
    assert quaternion_deviation(q) == pytest.approx(rotation_deviation(scaled_rotation), rel=1e-9)


def _tracker_poses(count: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(exact poses, poses as a tracker stores them: stretched by ~1e-4, frame 4 by ~3e-4)."""
    exact = ring_poses(count)
    stored = [_stretched(p, 1.5e-4 if i != 4 else 6e-4, seed=i) for i, p in enumerate(exact)]
    return exact, stored


def _warning_about_repairs(warnings: list[str]) -> str:
    found = [w for w in warnings if "were not exactly rotations" in w]
    assert len(found) == 1, warnings
    return found[0]


def test_transforms_json_with_near_rigid_rotations_loads_repaired(tmp_path):
    exact, stored = _tracker_poses(8)
    write_photo_folder(tmp_path / "images", 8, SIZE, suffix=".jpg", names=[f"frame_{i:04d}.jpg" for i in range(8)])
    write_transforms_json(tmp_path / "transforms.json",
                          [(f"images/frame_{i:04d}.jpg", p) for i, p in enumerate(stored)],
                          fl_x=60.0, w=SIZE[0], h=SIZE[1])
    capture = load_capture(tmp_path)
    assert len(capture.frames) == 8
    for frame, truth in zip(capture.frames, exact):
        _assert_rigid_and_equal(frame.pose, truth, atol=1e-9)
    warning = _warning_about_repairs(capture.warnings)
    assert warning.startswith("transforms.json: 8 of 8 poses were not exactly rotations (worst: images/frame_0004.jpg")
    worst = float(re.search(r"\|R\^T R - I\| = ([0-9.e-]+)\)", warning).group(1))
    assert worst == pytest.approx(rotation_deviation(stored[4][:3, :3]), rel=0.05)


def test_transforms_json_frame_beyond_tolerance_is_skipped_naming_the_deviation(tmp_path):
    poses = ring_poses(4)
    poses[2] = poses[2].copy()
    poses[2][:3, :3] *= 1.05
    write_photo_folder(tmp_path / "images", 4, SIZE, suffix=".jpg")
    write_transforms_json(tmp_path / "transforms.json", [(f"images/frame{i}.jpg", p) for i, p in enumerate(poses)],
                          fl_x=60.0)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["frame0.jpg", "frame1.jpg", "frame3.jpg"]
    skipped = [w for w in capture.warnings if "images/frame2.jpg" in w]
    assert len(skipped) == 1 and "|R^T R - I| = 0.1" in skipped[0] and "no usable pose" in skipped[0]
    assert not any("were not exactly rotations" in w for w in capture.warnings)  # exact poses: no repair warning


def test_scannet_pose_files_with_four_decimals_load_repaired(tmp_path):
    exact = ring_poses(5)
    write_scannet(tmp_path, exact, intrinsics(60.0, *SIZE), SIZE, depth=False)
    for i in range(5):  # a tracker writing 4 decimals: rotations orthonormal to ~1e-4
        np.savetxt(tmp_path / "pose" / f"{i}.txt", exact[i], fmt="%.4f")
    capture = load_capture(tmp_path)
    for frame, truth in zip(capture.frames, exact):
        _assert_rigid_and_equal(frame.pose, truth, atol=2e-4)
    deviations = [rotation_deviation(np.round(p[:3, :3], 4)) for p in exact]
    warning = _warning_about_repairs(capture.warnings)
    repaired = sum(d > 1e-5 for d in deviations)
    assert f"{repaired} of 5 poses were not exactly rotations (worst: {int(np.argmax(deviations))}.txt" in warning


def test_scannet_pose_written_at_full_precision_is_kept_bit_exact_without_warning(tmp_path):
    exact = ring_poses(3)
    write_scannet(tmp_path, exact, intrinsics(60.0, *SIZE), SIZE, depth=False)
    for i in range(3):
        np.savetxt(tmp_path / "pose" / f"{i}.txt", exact[i], fmt="%.17g")
    capture = load_capture(tmp_path)
    assert all(np.array_equal(f.pose, p) for f, p in zip(capture.frames, exact))
    assert not any("rotations" in w for w in capture.warnings)


@pytest.mark.parametrize("writer", [write_colmap_text, write_colmap_binary])
def test_colmap_non_unit_quaternions_are_normalised_with_one_warning(tmp_path, writer):
    exact = ring_poses(5)
    names = [f"img{i}.png" for i in range(5)]
    write_photo_folder(tmp_path / "images", 5, SIZE, names=names)
    entries = []
    for i, (pose, name) in enumerate(zip(exact, names)):
        image_id, q, t, camera_id, _ = colmap_image_entry(i + 1, pose, 1, name)
        length = {1: 1.003, 3: 0.9995}.get(i, 1.0)  # rounded by a writer; img1 is the worst
        if i == 4:
            length = 1.2  # | |q|^2 - 1 | = 0.44: not a rounding error
        entries.append((image_id, q * length, t, camera_id, name))
    writer(tmp_path / "sparse" / "0", [(1, "PINHOLE", SIZE[0], SIZE[1], [60.0, 60.0, 32.0, 24.0])], entries)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == names[:4]
    for frame, truth in zip(capture.frames, exact):
        _assert_rigid_and_equal(frame.pose, truth, atol=1e-9)
    warning = _warning_about_repairs(capture.warnings)
    assert "2 of 4 poses were not exactly rotations (worst: img1.png, |R^T R - I| = 0.006)" in warning
    skipped = [w for w in capture.warnings if "img4.png" in w]
    assert len(skipped) == 1 and "length 1.2" in skipped[0] and "0.44" in skipped[0]
