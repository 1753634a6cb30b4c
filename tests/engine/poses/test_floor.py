"""Automatic scale from the floor plane: synthetic sparse points with a floor, walls, a table, clutter
and outliers, moved into a tilted, scaled SfM-like world, come back with the floor at z = 0, the
camera height and the scale within 1 %; a scene whose only horizontal surface is a table under an
object says that no floor was found. Known distances between two 3D points rescale a capture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures_capture import look_at, look_yaw_pitch

from engine.capture.model import Capture, Frame
from engine.errors import PoseError
from engine.poses import (
    KnownDistance,
    Similarity,
    align_gravity_and_scale,
    find_floor_plane,
    rescale_capture,
    scale_from_known_distance,
)
from engine.poses.gravity import mean_up_direction

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
TRUE_MEDIAN_HEIGHT = 1.42


def capture_of(poses: list[np.ndarray]) -> Capture:
    frames = [Frame(Path(f"/room/{i:03d}.jpg"), 640, 480, K.copy(), p) for i, p in enumerate(poses)]
    return Capture(Path("/room"), "images", frames)


def box_points(rng: np.random.Generator, lo, hi, count: int) -> np.ndarray:
    return rng.uniform(lo, hi, size=(count, 3))


def cluttered_room(rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """A 6 x 5 x 2.8 m room walked along one long wall (half a loop), cameras pitched down.

    Looking down along half a loop tilts the cameras' mean "up" by several degrees, so gravity must
    come from the floor. Points: a noisy floor (1 cm), four walls, a table top at 0.75 m holding
    more points than any floor patch of its size, boxes, stray points in the air and below the floor.
    Returns (poses, points (N, 3), floor mask (N,)).
    """
    poses = []
    heights = TRUE_MEDIAN_HEIGHT + np.array([-0.08, 0.05, 0.0, 0.1, -0.04, 0.07, -0.1, 0.02, -0.02, 0.12, -0.06])
    for k, h in enumerate(heights):
        x = 0.8 + 4.4 * k / (len(heights) - 1)
        poses.append(look_yaw_pitch([x, 0.7, h], np.radians(60 + 60 * k / (len(heights) - 1)), np.radians(-8)))
    floor = np.column_stack([rng.uniform(0, 6, 900), rng.uniform(0, 5, 900), rng.normal(0, 0.01, 900)])
    walls = np.vstack([
        np.column_stack([rng.uniform(0, 6, 300), np.full(300, 5.0), rng.uniform(0, 2.8, 300)]),
        np.column_stack([np.zeros(200), rng.uniform(0, 5, 200), rng.uniform(0, 2.8, 200)]),
        np.column_stack([np.full(200, 6.0), rng.uniform(0, 5, 200), rng.uniform(0, 2.8, 200)]),
    ])
    table = np.column_stack([rng.uniform(2.5, 3.7, 700), rng.uniform(2.5, 3.3, 700), rng.normal(0.75, 0.004, 700)])
    boxes = np.vstack([box_points(rng, [0.5, 3.5, 0], [1.1, 4.5, 0.6], 150), box_points(rng, [4.6, 3.8, 0], [5.6, 4.8, 1.0], 150)])
    strays = np.vstack([box_points(rng, [0, 0, 0.2], [6, 5, 2.6], 60), box_points(rng, [0, 0, -1.0], [6, 5, -0.2], 15)])
    points = np.vstack([floor, walls, table, boxes, strays])
    is_floor = np.r_[np.ones(len(floor), bool), np.zeros(len(points) - len(floor), bool)]
    return poses, points, is_floor


def sfm_world(rng: np.random.Generator, scale: float) -> Similarity:
    """An arbitrary SfM frame: random rotation, translation and `scale` SfM units per metre."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return Similarity(q if np.linalg.det(q) > 0 else -q, rng.uniform(-10, 10, 3), scale)


def test_floor_plane_gives_gravity_camera_height_and_scale_within_one_percent():
    rng = np.random.default_rng(7)
    poses, points, is_floor = cluttered_room(rng)
    # The cameras alone would put "up" several degrees off: the floor has to correct it.
    camera_up_error = np.degrees(np.arccos(mean_up_direction(np.stack(poses))[2]))
    assert camera_up_error > 4.0

    world = sfm_world(rng, 0.37)
    result = align_gravity_and_scale(capture_of([world.apply_pose(p) for p in poses]), camera_height=TRUE_MEDIAN_HEIGHT,
                                     points=world.apply_points(points))
    print(result.description)

    assert result.scale_source == "camera height" and result.floor_method == "plane"
    assert result.similarity.scale == pytest.approx(1 / 0.37, rel=0.01)
    aligned = np.stack([f.pose for f in result.capture.frames])
    # Camera heights come back in metres above a floor at z = 0.
    assert np.allclose(aligned[:, 2, 3], [p[2, 3] for p in poses], atol=0.01 * TRUE_MEDIAN_HEIGHT)
    assert np.median(np.abs(result.points[is_floor, 2])) < 0.01
    # Gravity: the true vertical maps onto +Z (to a fraction of a degree, far better than the cameras' guess).
    true_up_now = result.similarity.rotation @ world.rotation @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(np.clip(true_up_now[2], -1, 1))) < 0.5
    # The report carries the numbers: inliers, their share, the measured height in SfM units, the factor.
    floor = result.floor
    assert floor is not None and floor.inliers >= 800
    assert result.camera_height_units == pytest.approx(TRUE_MEDIAN_HEIGHT * 0.37, rel=0.01)
    assert f"floor plane from {floor.inliers} points" in result.description
    assert f"{100 * floor.inlier_share:.0f} %" in result.description
    assert f"x{result.similarity.scale:.3g}" in result.description and f"{TRUE_MEDIAN_HEIGHT:g} m" in result.description
    assert not result.warnings


def test_a_table_under_an_object_is_not_taken_for_the_floor():
    """Cameras circling an object on a table (fox-like): the table top is the only horizontal plane
    below them, and they stand outside it, so no floor plane is found, and the report says so."""
    rng = np.random.default_rng(8)
    angles = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    poses = [look_at([1.0 * np.cos(a), 1.0 * np.sin(a), 1.3], [0, 0, 0.85]) for a in angles]
    radius = np.sqrt(rng.uniform(0, 0.4**2, 800))
    theta = rng.uniform(0, 2 * np.pi, 800)
    table = np.column_stack([radius * np.cos(theta), radius * np.sin(theta), rng.normal(0.75, 0.003, 800)])
    thing = rng.normal([0, 0, 0.9], [0.08, 0.05, 0.1], size=(600, 3))
    far_walls = np.column_stack([rng.uniform(-4, 4, 300), np.full(300, 4.0), rng.uniform(0.3, 2.5, 300)])
    points = np.vstack([table, thing, far_walls])

    search = find_floor_plane(points, np.array([p[:3, 3] for p in poses]))
    assert search.plane is None and "table" in search.reason

    result = align_gravity_and_scale(capture_of(poses), camera_height=1.5, points=points)
    assert result.floor_method == "lowest points"
    assert result.description.startswith("no floor plane found in the sparse points")
    assert any("no floor plane found" in w and "known distance" in w for w in result.warnings)


def test_the_floor_of_a_corridor_walked_round_a_block_is_a_floor():
    """A U-shaped walk (the 3D Scanner App corridor: 20 x 32 m round a block of offices, 2 m wide): the
    corridor's floor covers a quarter of the area the cameras ring, with its middle inside the ring,
    as a table under a circled object does; but here the cameras stand over the floor they see."""
    rng = np.random.default_rng(10)
    legs = [((0, 0), (0, 32)), ((0, 32), (20, 32)), ((20, 32), (20, 0))]  # corridor centre lines, metres
    path = np.vstack([np.linspace(a, b, 50, endpoint=False) for a, b in legs])
    heading = np.arctan2(*np.gradient(path, axis=0)[:, ::-1].T)
    poses = [look_yaw_pitch([x, y, 1.45 + rng.normal(0, 0.05)], yaw, np.radians(-15)) for (x, y), yaw in zip(path, heading)]
    # Floor points where the cameras looked, 1-4 m ahead, across the 2 m corridor.
    ahead = rng.integers(0, len(path), 3000)
    distance = rng.uniform(1.0, 4.0, 3000)
    side = rng.uniform(-1.0, 1.0, 3000)
    direction = np.column_stack([np.cos(heading[ahead]), np.sin(heading[ahead])])
    across = direction[:, ::-1] * [1, -1]
    floor_xy = path[ahead] + distance[:, None] * direction + side[:, None] * across
    floor = np.column_stack([floor_xy, rng.normal(0, 0.01, 3000)])
    walls = np.column_stack([path[ahead] + 1.0 * across, rng.uniform(0.0, 2.6, 3000)])
    points = np.vstack([floor, walls])
    centres = np.array([p[:3, 3] for p in poses])

    search = find_floor_plane(points, centres)
    assert search.plane is not None, search.reason
    assert abs(search.plane.offset) < 0.02 and not search.plane.orbited
    # Its footprint is small and ringed by the cameras: standing over it is what tells it from a table.
    ring = 20 * 32
    assert search.plane.area < 0.3 * ring


def test_no_points_below_the_cameras_leaves_the_scale_unknown_and_says_so():
    poses = [look_at([2 * np.cos(a), 2 * np.sin(a), 1.5], [0, 0, 1.5]) for a in np.linspace(0, 6, 8)]
    ceiling = np.random.default_rng(9).uniform([-3, -3, 2.5], [3, 3, 2.6], size=(300, 3))
    result = align_gravity_and_scale(capture_of(poses), points=ceiling)
    assert result.scale_source == "unknown" and result.floor_method == "assumed"
    assert "no floor found in the sparse points" in result.description
    assert any("scale is unknown" in w for w in result.warnings)


def test_known_distance_between_two_points_rescales_capture_and_points():
    rng = np.random.default_rng(10)
    poses, points, _ = cluttered_room(rng)
    world = sfm_world(rng, 0.37)
    capture = capture_of([world.apply_pose(p) for p in poses])
    sfm_points = world.apply_points(points)
    # A door 2.0 m high: its foot and its top, as two points picked in the SfM world.
    foot, top = np.array([3.0, 5.0, 0.0]), np.array([3.0, 5.0, 2.0])
    a, b = world.apply_points(np.stack([foot, top]))
    factor = scale_from_known_distance(a, b, 2.0)
    assert factor == pytest.approx(1 / 0.37)

    rescaled = rescale_capture(capture, factor, sfm_points)
    assert rescaled.capture.metric and rescaled.factor == factor
    moved = np.stack([f.pose for f in rescaled.capture.frames])
    original = np.stack([f.pose for f in capture.frames])
    assert np.allclose(moved[:, :3, :3], original[:, :3, :3])  # rotations untouched
    assert np.allclose(moved[:, :3, 3], factor * original[:, :3, 3])  # about the origin
    assert np.allclose(rescaled.points, factor * sfm_points)
    # Distances between cameras are now true metres.
    assert np.linalg.norm(moved[0, :3, 3] - moved[-1, :3, 3]) == pytest.approx(np.linalg.norm(poses[0][:3, 3] - poses[-1][:3, 3]))

    # The same two points through the alignment: the door measures 2.0 m there too, Z up.
    result = align_gravity_and_scale(capture, known_distance=KnownDistance(a, b, 2.0), points=sfm_points)
    assert result.scale_source == "known distance"
    door = result.similarity.apply_points(np.stack([a, b]))
    assert np.linalg.norm(door[1] - door[0]) == pytest.approx(2.0)
    assert door[1, 2] - door[0, 2] == pytest.approx(2.0, abs=0.02)  # vertical: the floor found gravity
    assert door[0, 2] == pytest.approx(0.0, abs=0.02)  # and its foot is on the floor


def test_bad_known_distances_are_refused_with_reasons():
    with pytest.raises(PoseError, match="positive"):
        scale_from_known_distance(np.zeros(3), np.ones(3), 0.0)
    with pytest.raises(PoseError, match="same spot"):
        scale_from_known_distance(np.ones(3), np.ones(3), 1.0)
    with pytest.raises(PoseError, match="positive"):
        rescale_capture(capture_of([np.eye(4)]), -2.0)
    poses, points, _ = cluttered_room(np.random.default_rng(11))
    with pytest.raises(PoseError, match="neither a frame name nor a 3D point"):
        align_gravity_and_scale(capture_of(poses), known_distance=KnownDistance([1.0, 2.0], "000.jpg", 1.0), points=points)



def test_demo_sample_scale_from_the_floor_plane_within_one_percent():
    """The bundled demo room, photos only, through structure from motion (~20 s): with the camera
    height set to the renderer's true median camera height, the room comes out at its true size."""
    from engine.capture import load_capture
    from engine.poses import SfmOptions, estimate_poses, pose_errors

    sample = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
    if not (sample / "truth" / "pose").is_dir():
        pytest.skip(f"the demo sample is missing: {sample}")
    truth = {p.stem: np.loadtxt(p).reshape(4, 4) for p in (sample / "truth" / "pose").glob("*.txt")}
    true_height = float(np.median([pose[2, 3] for pose in truth.values()]))

    result = estimate_poses(load_capture(sample / "images"), SfmOptions(camera_height=true_height))
    print(result.report)
    alignment = result.alignment
    assert alignment is not None and alignment.floor_method == "plane" and alignment.scale_source == "camera height"
    assert "floor plane from" in alignment.description and f"world: {alignment.description}" in result.report
    posed = [f for f in result.capture.frames if f.pose is not None]
    errors = pose_errors([f.pose for f in posed], [truth[f.image_path.stem] for f in posed])
    # Once in about 30 SfM runs (2026-12-04) the scale came out 0.816 with a report like the good ones;
    # the message keeps what would tell why (a distorted model, or a floor found too high).
    heights = {f.image_path.stem: round(float(f.pose[2, 3] - truth[f.image_path.stem][2, 3]), 3) for f in posed}
    assert errors["scale"] == pytest.approx(1.0, abs=0.01), f"{errors}\nheight errors (m): {heights}"  # truth m per estimated m
    # Z up, floor at z = 0, metres: each camera's height above the floor is its true height.
    assert np.median(np.abs([f.pose[2, 3] - truth[f.image_path.stem][2, 3] for f in posed])) < 0.02
