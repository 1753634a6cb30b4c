"""Up from vertical lines: photos of a room's door frames and corners, drawn through known cameras that
all look down, give gravity although the cameras' mean up leans back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fixtures_capture import draw_room_lines, look_yaw_pitch as look

from engine.capture.model import Capture, Frame
from engine.geometry.cameras import mean_up_direction
from engine.poses.align import Similarity
from engine.poses.gravity import align_gravity_and_scale
from engine.capture.vertical_lines import up_from_vertical_lines

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
SIZE = (640, 480)
PITCH_DEG = -15.0  # every camera looks down: the cameras' mean up leans 15 deg back from gravity


def tilted_walk() -> list[np.ndarray]:
    """10 cameras walking along one wall, 1.5 m high, looking across the room (yaws within 40 deg of +Y)
    and all down: the way a phone is held, and the cameras' mean up leans back with them."""
    return [look([x, 1.0, 1.5], np.pi / 2 + np.radians(yaw), np.radians(PITCH_DEG))
            for x, yaw in zip(np.linspace(1.0, 5.0, 10), np.linspace(-40, 40, 10)[::-1])]


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def up_seen_error_deg(estimated: np.ndarray, true: np.ndarray) -> float:
    """Angle between +Z as the camera sees it in the estimated world and in the true one (any yaw)."""
    return angle_deg(estimated[2, :3], true[2, :3])


def test_vertical_lines_give_gravity_where_the_cameras_mean_up_leans(tmp_path):
    poses = tilted_walk()
    frames = draw_room_lines(tmp_path, poses, K, SIZE)
    prior = mean_up_direction(np.stack(poses))
    assert angle_deg(prior, [0, 0, 1]) > 10  # the prior really is off

    found = up_from_vertical_lines(frames, prior)

    assert found is not None
    assert angle_deg(found.up, [0, 0, 1]) < 0.3
    assert found.photos >= 8 and found.lines >= 30
    assert abs(found.off_prior_deg - angle_deg(prior, [0, 0, 1])) < 0.5


def test_photos_without_vertical_lines_give_no_answer(tmp_path):
    poses = tilted_walk()
    frames = draw_room_lines(tmp_path, poses, K, SIZE, vertical=False)
    assert up_from_vertical_lines(frames, mean_up_direction(np.stack(poses))) is None


def test_alignment_puts_the_lines_up_on_z_and_says_so(tmp_path):
    """An SfM-like world: the drawn room turned and scaled arbitrarily. The alignment brings the lines'
    up back onto +Z (the cameras' mean up would leave it 15 deg off) and reports where up came from."""
    poses = tilted_walk()
    frames = draw_room_lines(tmp_path, poses, K, SIZE)
    q, _ = np.linalg.qr(np.random.default_rng(3).standard_normal((3, 3)))
    to_sfm = Similarity(q * np.sign(np.linalg.det(q)), np.array([0.4, -1.0, 2.0]), 0.37)
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 6, 500), rng.uniform(0, 5, 500), np.zeros(500)])
    sfm_frames = [Frame(f.image_path, f.width, f.height, f.K, to_sfm.apply_pose(f.pose)) for f in frames]
    capture = Capture(root=tmp_path, format="images", frames=sfm_frames, metric=False)

    aligned = align_gravity_and_scale(capture, points=to_sfm.apply_points(floor))

    assert max(up_seen_error_deg(f.pose, p) for f, p in zip(aligned.capture.frames, poses)) < 0.3
    assert "vertical lines in 10 photos" in aligned.description
    assert "floor's normal agrees" in aligned.description
    assert not aligned.warnings
    assert abs(aligned.capture.frames[0].pose[2, 3] - 1.5) < 0.02  # the floor plane under the lines' up: 1.5 m


def test_a_floor_that_disagrees_with_the_lines_is_reported(tmp_path):
    poses = tilted_walk()
    frames = draw_room_lines(tmp_path, poses, K, SIZE)
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(0, 6, 500), rng.uniform(0, 5, 500)])
    ramp = np.column_stack([xy, np.tan(np.radians(6.0)) * (xy[:, 0] - 3.0)])  # a floor sloping 6 deg
    capture = Capture(root=tmp_path, format="images", frames=frames, metric=False)

    aligned = align_gravity_and_scale(capture, points=ramp)

    assert any("deg from the up the vertical lines give" in w for w in aligned.warnings)
    assert max(up_seen_error_deg(f.pose, p) for f, p in zip(aligned.capture.frames, poses)) < 0.3  # the lines' up
