"""Gravity and scale: a known room, moved by a known similarity, comes back Z up, floor at 0, metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures_capture import look_yaw_pitch as look

from engine.capture.model import Capture, Frame
from engine.errors import PoseError
from engine.poses.align import Similarity, pose_errors, rotation_angle_deg
from engine.poses.gravity import KnownDistance, align_gravity_and_scale, bent_walk_warning, mean_up_direction, rotation_taking

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])


def room(rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """12 cameras on a loop looking inward, median height exactly 1.5 m; floor and wall points.

    Yaws are evenly spaced and the pitches alternate, so the cameras' mean up is exactly +Z.
    Returns (poses, all points (N, 3), floor mask (N,)).
    """
    poses = []
    for k in range(12):
        a = 2 * np.pi * k / 12
        height = 1.5 + (0.1 if k % 2 else -0.1) * (k % 3 != 0)  # median 1.5
        position = np.array([3 + 1.2 * np.cos(a), 2.5 + 1.2 * np.sin(a), height])
        poses.append(look(position, a + np.pi, np.radians(-10 if k % 2 else -20)))
    floor = np.column_stack([rng.uniform(0, 6, 600), rng.uniform(0, 5, 600), np.zeros(600)])
    wall = np.column_stack([rng.uniform(0, 6, 400), np.full(400, 5.0), rng.uniform(0, 2.8, 400)])
    strays = np.column_stack([rng.uniform(0, 6, 4), rng.uniform(0, 5, 4), rng.uniform(-1.0, -0.3, 4)])
    points = np.vstack([floor, wall, strays])
    is_floor = np.r_[np.ones(600, bool), np.zeros(404, bool)]
    return poses, points, is_floor


def random_similarity(rng: np.random.Generator) -> Similarity:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return Similarity(q if np.linalg.det(q) > 0 else -q, rng.uniform(-10, 10, 3), 0.37)


def capture_of(poses: list[np.ndarray], metric: bool = False) -> Capture:
    frames = [Frame(Path(f"/room/{i:03d}.jpg"), 640, 480, K.copy(), p) for i, p in enumerate(poses)]
    return Capture(Path("/room"), "images", frames, metric=metric)


def test_camera_height_recovers_up_floor_and_metres():
    rng = np.random.default_rng(0)
    poses, points, is_floor = room(rng)
    sim = random_similarity(rng)
    moved = capture_of([sim.apply_pose(p) for p in poses])
    result = align_gravity_and_scale(moved, camera_height=1.5, points=sim.apply_points(points))

    aligned = [f.pose for f in result.capture.frames]
    assert np.allclose(mean_up_direction(np.stack(aligned)), [0, 0, 1], atol=1e-3)  # the floor normal refines it
    # Floor at z = 0 despite the stray points below it. Millimetres, not exactly: the floor plane is a
    # least-squares fit on the points in its band, which include the foot of the wall.
    assert np.abs(result.points[is_floor, 2]).max() < 1e-3
    assert np.allclose([p[2, 3] for p in aligned], [p[2, 3] for p in poses], atol=1e-3)  # true heights, metres
    # What is left is a turn about Z and a horizontal shift: no scale, no tilt.
    errors = pose_errors(aligned, poses)
    assert errors["scale"] == pytest.approx(1.0, abs=1e-3)
    assert errors["rotation_deg_max"] < 0.02 and errors["position_max"] < 1e-3
    assert result.floor_method == "plane" and "floor plane from" in result.description
    assert result.scale_source == "camera height"
    assert result.capture.metric
    assert result.similarity.scale == pytest.approx(1 / 0.37, rel=1e-3)


def test_known_distance_sets_the_scale():
    rng = np.random.default_rng(1)
    poses, points, is_floor = room(rng)
    sim = random_similarity(rng)
    moved = capture_of([sim.apply_pose(p) for p in poses])
    # Cameras 0 and 6 face each other across the 2.4 m loop; call it 3 m: everything grows by 1.25.
    result = align_gravity_and_scale(moved, known_distance=KnownDistance("000.jpg", "006.jpg", 3.0),
                                     points=sim.apply_points(points))
    frames = {f.name: f.pose for f in result.capture.frames}
    assert np.linalg.norm(frames["000.jpg"][:3, 3] - frames["006.jpg"][:3, 3]) == pytest.approx(3.0)
    assert np.abs(result.points[is_floor, 2]).max() < 1e-3  # the floor is still found and put at zero
    assert np.median([p[2, 3] for p in frames.values()]) == pytest.approx(1.5 * 1.25, rel=1e-3)
    assert result.scale_source == "known distance"


def test_without_points_the_scale_is_unknown_and_said_so():
    rng = np.random.default_rng(2)
    poses, _, _ = room(rng)
    sim = random_similarity(rng)
    result = align_gravity_and_scale(capture_of([sim.apply_pose(p) for p in poses]), camera_height=1.5)
    heights = [f.pose[2, 3] for f in result.capture.frames]
    assert result.similarity.scale == pytest.approx(1.0)
    assert np.median(heights) == pytest.approx(1.5)  # floor assumed camera_height below the cameras
    assert result.scale_source == "unknown" and not result.capture.metric
    assert any("known distance" in w for w in result.warnings)


def test_metric_captures_are_left_alone_unless_asked():
    rng = np.random.default_rng(3)
    poses, _, _ = room(rng)
    tilt = Similarity(random_similarity(rng).rotation, np.zeros(3), 1.0)
    capture = capture_of([tilt.apply_pose(p) for p in poses], metric=True)
    untouched = align_gravity_and_scale(capture)
    assert untouched.capture is capture and untouched.scale_source == "metric capture"

    rotated = align_gravity_and_scale(capture, align_metric=True)
    aligned = np.stack([f.pose for f in rotated.capture.frames])
    assert rotated.similarity.scale == 1.0
    assert np.allclose(mean_up_direction(aligned), [0, 0, 1], atol=1e-9)
    distances = lambda ps: np.linalg.norm(ps[:, None, :3, 3] - ps[None, :, :3, 3], axis=-1)  # noqa: E731
    assert np.allclose(distances(aligned), distances(np.stack(poses)))


def test_frames_without_pose_stay_without_pose():
    rng = np.random.default_rng(4)
    poses, points, _ = room(rng)
    capture = capture_of(poses)
    capture.frames[3].pose = None
    result = align_gravity_and_scale(capture, points=points)
    assert result.capture.frames[3].pose is None
    assert sum(f.pose is not None for f in result.capture.frames) == 11


def test_rotation_taking_handles_all_directions():
    rng = np.random.default_rng(5)
    z = np.array([0.0, 0.0, 1.0])
    for a in [*rng.standard_normal((20, 3)), [0, 0, -1.0], [0, 0, 1.0], [1e-9, 0, -1.0]]:
        a = np.asarray(a) / np.linalg.norm(a)
        R = rotation_taking(a, z)
        assert np.allclose(R @ a, z, atol=1e-9)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    # Smallest rotation: a vector 30 degrees off +Z turns by exactly 30 degrees.
    a = np.array([np.sin(np.radians(30)), 0.0, np.cos(np.radians(30))])
    assert rotation_angle_deg(rotation_taking(a, z)) == pytest.approx(30.0)


def test_bad_known_distance_names_the_frame():
    poses, points, _ = room(np.random.default_rng(6))
    with pytest.raises(PoseError, match="nope.jpg"):
        align_gravity_and_scale(capture_of(poses), known_distance=KnownDistance("000.jpg", "nope.jpg", 2.0),
                                points=points)
    with pytest.raises(PoseError, match="positive"):
        align_gravity_and_scale(capture_of(poses), camera_height=-1.0)


def test_a_walk_whose_stretches_stand_metres_apart_in_height_is_called_bent():
    names = [f"frame_{i:05d}" for i in range(60)]
    rng = np.random.default_rng(3)
    level = 1.5 + 0.03 * rng.standard_normal(60)  # a hand-held walk: a few cm up and down
    assert bent_walk_warning(level, names) is None
    crouching = level.copy()
    crouching[20:35] -= 0.6  # a stretch filmed crouching still passes
    assert bent_walk_warning(crouching, names) is None
    bent = level.copy()
    bent[30:] += np.linspace(0.0, 3.0, 30)  # the model bends at photo 30 and climbs 3 m
    message = bent_walk_warning(bent, names)
    assert message is not None and "probably bent" in message
    assert "frame_00000" in message and "frame_00045..frame_00059" in message
    assert bent_walk_warning(bent[:20], names[:20]) is None  # too few photos for two stretches


def test_the_bent_walk_check_runs_only_over_a_floor_that_was_found():
    # The same 3 m climb through the alignment: over a floor plane it is reported, without one (an
    # object photographed from all heights, scale from the camera-height guess) it is not.
    from engine.poses.gravity import _finish

    poses = []
    for i in range(60):
        pose = np.eye(4)
        pose[:3, 3] = (0.3 * i, 0.0, 1.5 + (0.1 * (i - 30) if i >= 30 else 0.0))
        poses.append(pose)
    capture = Capture(frames=[Frame(Path(f"frame_{i:05d}.jpg"), 640, 480, None, p) for i, p in enumerate(poses)],
                      root=Path("."), format="images")
    over_floor = _finish(capture, Similarity.identity(), None, "camera height", "", [], None, "plane", 1.5)
    assert any("probably bent" in w for w in over_floor.warnings)
    no_floor = _finish(capture, Similarity.identity(), None, "camera height", "", [], None, "lowest points", 1.5)
    assert not any("probably bent" in w for w in no_floor.warnings)
