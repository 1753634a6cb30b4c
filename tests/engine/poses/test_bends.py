"""A bent SfM model: photos of a room's door frames and corners drawn through the true cameras, then
given poses of which a stretch leans (as SfM's poses lean where a walk along plain walls bends). Each
photo's own vertical lines find the stretch, and the walk is cut there."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from fixtures_capture import draw_room_lines, look_yaw_pitch as look

from engine.poses.bends import BEND_TILT_DEG, find_bend, photo_tilts
from engine.poses.sfm import _leave_out, lone_photos

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
SIZE = (640, 480)


def walk(count: int) -> list[np.ndarray]:
    """`count` cameras walking along one wall of the 6 x 5 m room, 1.5 m high, looking across it and
    10 deg down, turning slowly as a hand-held phone does."""
    return [look([x, 1.0, 1.5], np.pi / 2 + np.radians(yaw), np.radians(-10.0))
            for x, yaw in zip(np.linspace(0.8, 5.2, count), np.linspace(-35, 35, count)[::-1])]


def leaning(pose: np.ndarray, degrees: float) -> np.ndarray:
    """`pose` turned by `degrees` about the world's x axis through the camera: its up leans that far."""
    a = np.radians(degrees)
    turn = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    out = pose.copy()
    out[:3, :3] = turn @ pose[:3, :3]
    return out


def test_a_straight_walk_has_no_bend(tmp_path):
    frames = draw_room_lines(tmp_path, walk(20), K, SIZE)

    sampled, _, tilts = photo_tilts(frames)

    assert len(sampled) == 20
    assert np.nanmax(tilts) < 0.5  # every photo's own lines agree with the capture's up
    assert np.isfinite(tilts).sum() >= 15
    assert find_bend(frames) is None


def test_a_leaning_stretch_is_found_and_the_longer_straight_walk_kept(tmp_path):
    frames = draw_room_lines(tmp_path, walk(24), K, SIZE)
    # Photos 15-23 were posed leaning 8 deg (the photos themselves show the true room).
    bent = [replace(f, pose=leaning(f.pose, 8.0)) if i >= 15 else f for i, f in enumerate(frames)]

    _, _, tilts = photo_tilts(bent)
    found = find_bend(bent)

    assert np.nanmin(tilts[15:]) > BEND_TILT_DEG and np.nanmax(tilts[:15]) < 1.0
    assert found is not None
    assert found.kept == list(range(15))
    assert found.cut == list(range(15, 24))
    assert abs(np.median(found.tilts_deg) - 8.0) < 0.5
    message = found.describe([f.name for f in bent])
    assert "015.png..023.png lean 8 deg" in message and "only the 15 photos 000.png..014.png are used" in message


def test_one_leaning_photo_is_not_a_bend(tmp_path):
    frames = draw_room_lines(tmp_path, walk(20), K, SIZE)
    bent = [replace(f, pose=leaning(f.pose, 8.0)) if i == 10 else f for i, f in enumerate(frames)]

    assert find_bend(bent) is None


def test_the_cut_leaves_the_bent_photos_unposed_and_drops_their_points(tmp_path):
    frames = draw_room_lines(tmp_path, walk(24), K, SIZE)
    bent = [replace(f, pose=leaning(f.pose, 8.0)) if i >= 15 else f for i, f in enumerate(frames)]
    found = find_bend(bent)
    # Three points: seen by straight photos only, by bent photos only, and by two straight and one bent.
    tracks = {"obs_point": np.array([0, 0, 1, 1, 2, 2, 2]), "obs_image": np.array([1, 2, 20, 21, 3, 4, 22])}
    xyz = np.arange(9.0).reshape(3, 3)
    rgb = np.zeros((3, 3), np.uint8)

    leave = np.zeros(len(bent), bool)
    leave[found.cut] = True

    cut_frames, kept_xyz, _ = _leave_out(bent, leave, tracks, xyz, rgb)

    assert [f.pose is not None for f in cut_frames] == [True] * 15 + [False] * 9
    np.testing.assert_array_equal(kept_xyz, xyz[[0, 2]])


def test_a_walk_photo_posed_without_its_neighbours_is_lone():
    # Photos 0-40 and 70-90 posed in one model, and photo 55 too, placed through a loop match only.
    posed = list(range(0, 41)) + [55] + list(range(70, 91))
    assert lone_photos(posed, overlap=10) == [55]
    assert lone_photos(list(range(0, 41)) + [50] + list(range(70, 91)), overlap=10) == []  # 40 is a neighbour
    assert lone_photos(list(range(20)), overlap=10) == []
    assert lone_photos([3], overlap=10) == []
