"""Posing a photo the refinement's triangulation left out, from the points its neighbours see: the
rotation comes back from correspondences with wrong matches among them, a cluster of points in one
corner of the photo does not let it spin about the viewing direction, too few agreeing points give
nothing, and the correspondences follow the verified matches to the right points."""

from __future__ import annotations

import numpy as np

from engine.poses import rotation_angle_deg
from engine.poses.adjust import Tracks
from engine.poses.resect import point_correspondences, resect_rotation
from fixtures_capture import rotation_about
from fixtures_tracks import F, H, K, W, look, wall_points


def _view(rotation: np.ndarray, centre: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(uv (N, 2), indices) of the points the camera sees inside its photo."""
    y = (points - centre) @ rotation.T
    uv = F * y[:, :2] / np.maximum(y[:, 2:3], 1e-9) + [W / 2, H / 2]
    seen = np.flatnonzero((y[:, 2] > 0.3) & (uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H))
    return uv[seen], seen


def test_the_rotation_comes_back_from_noisy_correspondences_with_wrong_matches():
    rng = np.random.default_rng(3)
    centre = np.array([0.3, -0.2, 1.5])
    truth = look(centre, np.array([3.0, 1.0, 1.2]))
    uv, seen = _view(truth, centre, wall_points(rng, 4000))
    uv = uv + rng.normal(0.0, 0.3, uv.shape)
    points = wall_points(np.random.default_rng(3), 4000)[seen]
    wrong = rng.random(len(uv)) < 0.3
    uv[wrong] = rng.uniform([0, 0], [W, H], (wrong.sum(), 2))
    given = truth @ rotation_about([0.3, 1.0, 0.2], 1.8)  # a tracker's error, as the triangulation misses it

    solved = resect_rotation(K, centre, given, uv, points)

    assert solved is not None
    assert rotation_angle_deg(solved.rotation @ truth.T) < 0.05
    assert solved.inliers >= 0.9 * (~wrong).sum() and solved.inliers <= (~wrong).sum() + 0.05 * wrong.sum()


def test_points_in_one_corner_do_not_spin_the_camera_about_its_viewing_direction():
    # Twelve points within a few pixels of each other: they fix where the camera looks, not its roll.
    rng = np.random.default_rng(5)
    centre = np.zeros(3)
    truth = look(centre, np.array([3.0, 0.0, 0.0]))
    uv = np.array([W / 2, H / 2]) + rng.uniform(-3, 3, (12, 2))
    depth = rng.uniform(2.5, 3.5, 12)
    rays = np.linalg.solve(K, np.c_[uv, np.ones(12)].T).T
    points = centre + (rays * depth[:, None]) @ truth  # camera -> world: R^T y
    # Given: rolled 2 deg about the viewing direction (world x) and turned 1 deg sideways (about world z).
    given = truth @ rotation_about([1.0, 0.0, 0.0], 2.0) @ rotation_about([0.0, 0.0, 1.0], 1.0)

    solved = resect_rotation(K, centre, given, uv + rng.normal(0.0, 0.3, uv.shape), points)

    assert solved is not None
    # Where it looks is corrected; the roll, which the points leave free, stays as given (2 deg).
    axis_after = solved.rotation.T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(np.clip(axis_after @ (truth.T @ [0.0, 0.0, 1.0]), -1, 1))) < 0.2
    assert rotation_angle_deg(solved.rotation @ given.T) < 1.2
    assert 1.8 < rotation_angle_deg(solved.rotation @ truth.T) < 2.2


def test_too_few_agreeing_points_give_no_rotation():
    rng = np.random.default_rng(7)
    centre = np.zeros(3)
    truth = look(centre, np.array([3.0, 0.5, 1.0]))
    uv, seen = _view(truth, centre, wall_points(rng, 3000))
    points = wall_points(np.random.default_rng(7), 3000)[seen]
    uv = uv.copy()
    uv[8:] = rng.uniform([0, 0], [W, H], (len(uv) - 8, 2))  # 8 right, the rest scattered

    assert resect_rotation(K, centre, truth, uv, points) is None


def test_correspondences_follow_the_verified_matches_to_the_points_the_posed_cameras_observe():
    # Camera 0 (posed) observes points 5 and 6 at its keypoints 0 and 1; camera 2 (posed) observes
    # point 7 at keypoint 0. Camera 1 (to pose): its keypoint 3 matches cam 0 kp 0 (point 5); its
    # keypoint 4 matches cam 0 kp 1 twice (point 6) and cam 2 kp 0 once (point 7): the majority wins;
    # its keypoint 2 matches cam 0 kp 1 (point 6).
    keypoints = [np.array([[10.0, 10.0], [20.0, 20.0]]), np.arange(10.0).reshape(5, 2), np.array([[30.0, 30.0]])]
    tracks = Tracks(camera=[0, 0, 2], point=[5, 6, 7], uv=[[10, 10], [20, 20], [30, 30]], points=np.zeros((8, 3)))
    matches = {
        "keypoints_uv": np.concatenate(keypoints),
        "keypoints_start": np.array([0, 2, 7, 8]),
        "match_image": np.array([[0, 1], [1, 0], [1, 2], [0, 1], [1, 0]]),
        "match_keypoint": np.array([[0, 3], [4, 1], [4, 0], [1, 4], [2, 1]]),
    }
    posed = np.array([True, False, True])

    found = point_correspondences(tracks, np.ones(3, bool), np.array([0, 1, 0]), matches, posed, ~posed)

    assert set(found) == {1}
    keypoint, uv, point = found[1]
    assert {k: p for k, p in zip(keypoint, point)} == {3: 5, 4: 6, 2: 6}
    np.testing.assert_array_equal(uv, keypoints[1][keypoint])
    # An observation the adjustment dropped is no correspondence.
    found = point_correspondences(tracks, np.array([False, True, True]), np.array([0, 1, 0]), matches, posed, ~posed)
    assert {k: p for k, p, in zip(found[1][0], found[1][2])} == {4: 6, 2: 6}
