"""Pose the photos that pose refinement's triangulation left out, from the points their neighbours see.

The refinement (`refine.py`) triangulates matches with the given poses; COLMAP's fixed-pose filter
drops observations more than 4 px off, so a photo whose given rotation is 1.5 deg off (13 px at a
500 px focal) keeps almost no track of three or more views and stays as given, although it has
hundreds of verified matches with neighbours that were refined (room_07002, 200 photos: 59 such
frames, 1.5 deg median error). Here each such photo's keypoints are tied, through those matches, to
the adjusted 3D points its neighbours observe, and its rotation is solved with its centre held (the
gauge the refinement keeps): RANSAC over two-point Wahba solutions, then a weighted Wahba fit of the
inliers with a weak prior towards the given rotation, which pins the turn about the viewing direction
when the points cluster in one part of the photo.

- `point_correspondences(tracks, inlier, obs_keypoint, matches, posed, wanted)
   -> {camera: (keypoint (M,), uv (M, 2), point (M,))}`
- `resect_rotation(K, centre, start_rotation, uv, points, options, rng) -> Resection | None`
- `resect_left_out(Ks, best, tracks, keypoint_of, matches, constrained, chosen_given, min_points,
   max_rotation_deg) -> {camera: Resection}`: the refinement's left-out cameras, posed in rounds
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .adjust import Adjusted, Tracks
from .align import rotation_angle_deg


@dataclass(frozen=True)
class ResectOptions:
    threshold_px: float = 4.0  # a correspondence is an inlier within this angle (in pixels at the focal length)
    min_inliers: int = 10  # as many as a triangulated frame needs (RefineOptions.min_points)
    iterations: int = 200  # RANSAC samples of two correspondences
    # The prior towards the given rotation weighs like one observation 1 px off when the rotation is
    # `prior_deg` away, as in the bundle adjustment (adjust.AdjustOptions.rotation_sigma_deg).
    prior_deg: float = 2.0
    # Frames posed in one round lend their points to the next: a frame that matches only frames left
    # out as well can follow them (room_05002: plain walls, chains of such frames).
    rounds: int = 3


@dataclass(frozen=True)
class Resection:
    rotation: np.ndarray  # (3, 3) world-to-camera rotation; the centre is the given one
    inliers: int  # correspondences within the threshold
    candidates: int  # correspondences tried
    inlier: np.ndarray  # (candidates,) bool: which


def point_correspondences(tracks: Tracks, inlier: np.ndarray, obs_keypoint: np.ndarray, matches: dict,
                          posed: np.ndarray, wanted: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Keypoints of each wanted camera matched to a keypoint that a posed camera observes a point with.

    tracks: the triangulated observations (O,) and their points; inlier: (O,) bool, observations the
    adjustment kept; obs_keypoint: (O,) keypoint index of each observation in its photo; matches: the
    worker's keypoints_uv (Σ, 2), keypoints_start (C + 1,), match_image (M, 2), match_keypoint (M, 2);
    posed: (C,) bool, cameras whose pose and points are trusted; wanted: (C,) bool, cameras to pose.
    Returns {camera: (keypoint (N,) indices in its photo, uv (N, 2) their positions, point (N,) rows of
    tracks.points)}, one point per keypoint (the one most of its matches agree on)."""
    start = np.asarray(matches["keypoints_start"], dtype=np.int64)
    keypoints_uv = np.asarray(matches["keypoints_uv"], dtype=np.float64).reshape(-1, 2)
    pair_image = np.asarray(matches["match_image"], dtype=np.int64).reshape(-1, 2)
    pair_keypoint = np.asarray(matches["match_keypoint"], dtype=np.int64).reshape(-1, 2)
    # A global keypoint id (start[camera] + index) for every trusted observation, sorted for lookup.
    trusted = inlier & posed[tracks.camera]
    observed_id = start[tracks.camera[trusted]] + np.asarray(obs_keypoint, dtype=np.int64)[trusted]
    observed_point = tracks.point[trusted]
    order = np.argsort(observed_id, kind="stable")
    observed_id, observed_point = observed_id[order], observed_point[order]
    target_ids, target_points = [], []
    for this, other in ((0, 1), (1, 0)):
        to_pose = wanted[pair_image[:, this]] & posed[pair_image[:, other]]
        query = start[pair_image[to_pose, other]] + pair_keypoint[to_pose, other]
        at = np.minimum(np.searchsorted(observed_id, query), max(len(observed_id) - 1, 0))
        hit = observed_id[at] == query if len(observed_id) else np.zeros(len(query), dtype=bool)
        target_ids.append(start[pair_image[to_pose, this]][hit] + pair_keypoint[to_pose, this][hit])
        target_points.append(observed_point[at[hit]])
    ids, points = np.concatenate(target_ids), np.concatenate(target_points)
    if not len(ids):
        return {}
    # One point per keypoint: the most frequent among its matches.
    pairs, counts = np.unique(np.stack([ids, points], axis=1), axis=0, return_counts=True)
    order = np.lexsort((-counts, pairs[:, 0]))
    pairs = pairs[order]
    first = np.r_[True, pairs[1:, 0] != pairs[:-1, 0]]
    ids, points = pairs[first, 0], pairs[first, 1]
    camera = np.searchsorted(start, ids, side="right") - 1
    found: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for c in np.unique(camera):
        mine = camera == c
        found[int(c)] = (ids[mine] - start[c], keypoints_uv[ids[mine]], points[mine])
    return found


def resect_rotation(K: np.ndarray, centre: np.ndarray, start_rotation: np.ndarray, uv: np.ndarray,
                    points: np.ndarray, options: Optional[ResectOptions] = None,
                    rng: Optional[np.random.Generator] = None) -> Optional[Resection]:
    """The world-to-camera rotation that points (N, 3) at uv (N, 2) with the camera centre (3,) held.

    K: (3, 3) intrinsics of the pixels uv; start_rotation: (3, 3) the given world-to-camera rotation
    (the prior). None when fewer than `min_inliers` correspondences agree on one rotation."""
    options = options or ResectOptions()
    rng = rng if rng is not None else np.random.default_rng(0)
    count = len(uv)
    if count < max(2, options.min_inliers):
        return None
    bearing = np.linalg.solve(K, np.c_[uv, np.ones(count)].T).T
    bearing /= np.linalg.norm(bearing, axis=1, keepdims=True)
    direction = np.asarray(points, dtype=np.float64) - np.asarray(centre, dtype=np.float64)
    distance = np.linalg.norm(direction, axis=1, keepdims=True)
    usable = distance[:, 0] > 1e-9
    direction = direction / np.maximum(distance, 1e-12)
    focal = 0.5 * (K[0, 0] + K[1, 1])
    threshold = options.threshold_px / focal

    def within(rotation: np.ndarray) -> np.ndarray:
        return usable & (np.linalg.norm(bearing - direction @ rotation.T, axis=1) < threshold)

    best = within(start_rotation)
    for _ in range(options.iterations):
        sample = rng.choice(count, 2, replace=False)
        if not usable[sample].all():
            continue
        candidate = within(_wahba(bearing[sample], direction[sample]))
        if candidate.sum() > best.sum():
            best = candidate
    if best.sum() < options.min_inliers:
        return None
    # The prior: the given camera axes as three extra correspondences, each weighing like an observation
    # 1 px off when the rotation is prior_deg away.
    prior_weight = (1.0 / (focal * np.radians(options.prior_deg))) ** 2
    given = np.asarray(start_rotation, dtype=np.float64)  # row k: camera axis k in the world
    rotation = given
    for _ in range(3):
        rotation = _wahba(np.r_[bearing[best], np.eye(3)], np.r_[direction[best], given],
                          np.r_[np.ones(int(best.sum())), np.full(3, prior_weight)])
        best = within(rotation)
        if best.sum() < options.min_inliers:
            return None
    return Resection(rotation=rotation, inliers=int(best.sum()), candidates=count, inlier=best)


def _wahba(bearing: np.ndarray, direction: np.ndarray, weight: Optional[np.ndarray] = None) -> np.ndarray:
    """The rotation R minimising Σ w |bearing - R direction|² (Wahba's problem, by SVD); (N, 3) each."""
    w = np.ones(len(bearing)) if weight is None else weight
    u, _, vt = np.linalg.svd((bearing * w[:, None]).T @ direction)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def resect_left_out(Ks: np.ndarray, best: Adjusted, tracks: Tracks, keypoint_of: np.ndarray, matches: Optional[dict],
                    constrained: np.ndarray, chosen_given: np.ndarray, min_points: int,
                    max_rotation_deg: float) -> dict[int, Resection]:
    """{camera: Resection} for the unconstrained cameras (K,) that `resect_rotation` can pose from the
    points their posed neighbours observe (`min_points` inliers at least), within `max_rotation_deg` of
    the given rotation; in rounds, each round's frames lending their agreeing observations to the next.

    best: the adjustment of `tracks` (whose observations' keypoint indices are keypoint_of, -1 unknown);
    chosen_given: (K, 4, 4) the given camera-to-world poses of the adjusted frames."""
    if matches is None or constrained.all() or (keypoint_of < 0).any():
        return {}
    resect_options = ResectOptions(min_inliers=min_points)
    posed = constrained.copy()
    camera, point, uv, keypoint, inlier = tracks.camera, tracks.point, tracks.uv, keypoint_of, best.inlier
    resected: dict[int, Resection] = {}
    for _ in range(resect_options.rounds):
        found = point_correspondences(Tracks(camera, point, uv, best.points), inlier, keypoint, matches, posed, ~posed)
        added = 0
        for k, (keypoints, positions, points) in sorted(found.items()):
            given_rotation = chosen_given[k, :3, :3].T
            solved = resect_rotation(Ks[k], chosen_given[k, :3, 3], given_rotation, positions, best.points[points],
                                     resect_options, np.random.default_rng(k))
            if solved is None or rotation_angle_deg(solved.rotation @ given_rotation.T) > max_rotation_deg:
                continue
            resected[k], posed[k] = solved, True
            agree = solved.inlier
            camera = np.r_[camera, np.full(int(agree.sum()), k)]
            point, uv = np.r_[point, points[agree]], np.r_[uv, positions[agree]]
            keypoint, inlier = np.r_[keypoint, keypoints[agree]], np.r_[inlier, np.ones(int(agree.sum()), bool)]
            added += 1
        if not added:
            break
    return resected
