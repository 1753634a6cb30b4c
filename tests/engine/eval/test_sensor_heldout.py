"""`engine eval-sensor`: a phone export's result against its own held-out LiDAR. The comparison is
checked on a fixture 3D Scanner App export (frame i's LiDAR: a wall 1 + 0.1 i m ahead, confident on
the left half) against walls placed by hand; the photos-alone variant's input is the photos only."""

from __future__ import annotations

import numpy as np
import pytest
from fixtures_phone import walk, write_export

from engine.capture import load_capture
from engine.errors import VortxError
from engine.eval.sensor_heldout import compare_to_sensor, photo_depth_ratio, photos_alone, split_capture
from engine.mesh_io import Mesh


def wall_ahead(pose: np.ndarray, distance: float, cells: int = 20) -> Mesh:
    """A 2 x 2 m wall of 10 cm squares (a reconstruction's triangles are small) facing the camera at
    `pose` (4, 4, OpenCV camera-to-world), `distance` m along its axis: it fills the fixture's view."""
    x, y = np.meshgrid(np.linspace(-1, 1, cells + 1), np.linspace(-1, 1, cells + 1), indexing="ij")
    corners = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, distance)])
    world = corners @ pose[:3, :3].T + pose[:3, 3]
    index = np.arange(x.size).reshape(x.shape)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(world.astype(np.float32), faces.astype(np.int32))


@pytest.fixture
def export(tmp_path):
    return load_capture(write_export(tmp_path / "export", walk(6)))


def test_a_wall_where_the_lidar_saw_it_agrees_and_one_10_cm_behind_does_not(export):
    frame = export.frames[3]  # its LiDAR: 1.3 m everywhere, high confidence on the left half
    right = compare_to_sensor(wall_ahead(frame.pose, 1.3), frame, frame.pose)
    assert right["within_5cm"] == pytest.approx(1.0) and right["rendered"] == pytest.approx(1.0)
    assert right["median_error_m"] < 0.005
    assert right["pixels"] == 16 * 12 // 2  # the confident half only
    # The right half's confidence is low: a gap in the sensor's depth, which the wall fills.
    assert right["gap_share"] == pytest.approx(0.5) and right["gap_rendered"] == pytest.approx(1.0)

    behind = compare_to_sensor(wall_ahead(frame.pose, 1.4), frame, frame.pose)
    assert behind["within_5cm"] == 0.0 and behind["rendered"] == pytest.approx(1.0)
    assert behind["median_error_m"] == pytest.approx(0.1, abs=0.005)

    # A mesh that is not in front of the camera leaves every confident pixel a miss.
    away = compare_to_sensor(wall_ahead(frame.pose, -1.3), frame, frame.pose)
    assert away["within_5cm"] == 0.0 and away["rendered"] == 0.0 and away["gap_rendered"] == 0.0


def test_the_sensor_gaps_count_as_filled_only_where_the_mesh_covers_them(export):
    frame = export.frames[3]
    wall = wall_ahead(frame.pose, 1.3)
    # Keep only the wall's left half as the camera sees it (camera x < 0): the sensor's measured half.
    in_camera = (wall.vertices - frame.pose[:3, 3]) @ frame.pose[:3, :3]
    left = np.all(in_camera[wall.faces][..., 0] <= 1e-6, axis=1)
    row = compare_to_sensor(Mesh(wall.vertices, wall.faces[left]), frame, frame.pose)
    assert row["within_5cm"] == pytest.approx(1.0)
    assert row["gap_rendered"] < 0.1


def test_held_out_frames_are_every_nth_and_the_photos_alone_have_nothing_but_pixels(export):
    kept, held = split_capture(export, 2)
    assert [f.name for f in held] == ["frame_00001.jpg", "frame_00003.jpg", "frame_00005.jpg"]
    assert [f.name for f in kept.frames] == ["frame_00000.jpg", "frame_00002.jpg", "frame_00004.jpg"]
    with pytest.raises(VortxError, match="--every must be at least 2"):
        split_capture(export, 1)

    alone = photos_alone(kept)
    assert [f.image_path for f in alone.frames] == [f.image_path for f in kept.frames]
    assert all(f.pose is None and f.K is None and f.sensor_depth is None for f in alone.frames)
    assert not alone.metric and alone.pose_origin == "" and alone.format == "images" and alone.points is None
    # The export itself is untouched: its held-out truth stays.
    assert all(f.pose is not None and f.sensor_depth is not None for f in kept.frames)


def test_all_photos_refuses_to_score_the_sensor_depth_against_itself(tmp_path, capsys):
    from engine.__main__ import main

    folder = write_export(tmp_path / "export", walk(6))
    assert main(["eval-sensor", str(folder), "--all-photos", "--variant", "sensor", "--quiet"]) != 0
    assert "--all-photos: the sensor depth would be scored against itself" in capsys.readouterr().err


def test_a_variants_report_keeps_the_finishings_planes_and_the_gap_coverage(export):
    from engine.eval.sensor_heldout import evaluate_variant
    from engine.recon.settings import ReconSettings

    kept, held = split_capture(export, 2)
    result = evaluate_variant(kept, held, ReconSettings(), keep_poses=True)
    assert result["sensor_depth"] and result["held_out"] == len(held)
    assert result["finish"]["mode"] == ReconSettings().finish and "planes" in result["finish"]
    assert 0.0 <= result["mean"]["gap_rendered"] <= 1.0 and result["mean"]["gap_share"] == pytest.approx(0.5)


def test_normals_agree_for_a_wall_facing_as_the_lidar_saw_it_not_for_one_turned_45_deg(export):
    frame = export.frames[3]  # its LiDAR: a wall 1.3 m ahead, facing the camera
    facing = compare_to_sensor(wall_ahead(frame.pose, 1.3), frame, frame.pose)
    assert facing["normals_30deg"] == pytest.approx(1.0)
    # The same wall turned 45 deg about the camera's vertical axis through the point 1.3 m ahead.
    wall = wall_ahead(frame.pose, 1.3)
    in_camera = (wall.vertices - frame.pose[:3, 3]) @ frame.pose[:3, :3]
    in_camera[:, 2] = 1.3 + in_camera[:, 0]
    turned = Mesh((in_camera @ frame.pose[:3, :3].T + frame.pose[:3, 3]).astype(np.float32), wall.faces)
    row = compare_to_sensor(turned, frame, frame.pose)
    assert row["rendered"] > 0.9 and row["normals_30deg"] == 0.0


def test_the_photos_geometry_against_the_lidar_is_the_median_depth_ratio_on_the_same_surface(export):
    """Points 1 % nearer than the LiDAR's wall where it is confident give 0.99; points where it is not
    confident, or on another surface (twice as far: behind the wall), do not count."""
    from engine.capture.sensor_depth import read_sensor_depth
    from engine.geometry.cameras import scale_intrinsics

    frame = export.frames[3]
    truth, _ = read_sensor_depth(frame.sensor_depth)  # 1.3 m, confident on the left half
    h, w = truth.shape
    K = scale_intrinsics(frame.K, (frame.width, frame.height), (w, h))
    v, u = np.mgrid[0:h, 0:w] + 0.5
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1).reshape(-1, 3)
    left = (u < w / 2).reshape(-1)
    depth = np.where(left, 0.99 * 1.3, 0.5 * 1.3)  # the right half's LiDAR is not confident
    in_camera = np.concatenate([rays * depth[:, None], rays[left][::4] * 2.6])  # and some behind the wall
    world = in_camera @ frame.pose[:3, :3].T + frame.pose[:3, 3]
    assert photo_depth_ratio(world, [(frame, frame.pose)]) == pytest.approx(0.99, abs=1e-6)
    assert photo_depth_ratio(world[:20], [(frame, frame.pose)]) is None  # too few points to say


def room_surface(lo: np.ndarray, hi: np.ndarray, cell: float = 0.1) -> Mesh:
    """The six sides of the box [lo, hi] as `cell`-sized squares (rendered depth needs small triangles)."""
    vertices, faces = [], []
    for axis in range(3):
        u_axis, v_axis = [a for a in range(3) if a != axis]
        us = np.linspace(lo[u_axis], hi[u_axis], int(round((hi[u_axis] - lo[u_axis]) / cell)) + 1)
        vs = np.linspace(lo[v_axis], hi[v_axis], int(round((hi[v_axis] - lo[v_axis]) / cell)) + 1)
        u, v = np.meshgrid(us, vs, indexing="ij")
        for side in (lo[axis], hi[axis]):
            grid = np.zeros(u.shape + (3,))
            grid[..., axis], grid[..., u_axis], grid[..., v_axis] = side, u, v
            index = np.arange(u.size).reshape(u.shape) + sum(len(p) for p in vertices)
            a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
            vertices.append(grid.reshape(-1, 3))
            faces += [np.column_stack([a, b, c]), np.column_stack([a, c, d])]
    return Mesh(np.concatenate(vertices).astype(np.float32), np.concatenate(faces).astype(np.int32))


def test_against_the_lidar_surface_a_room_3_cm_off_is_whole_and_10_cm_off_loses_exactly_the_walls_it_left():
    from engine.eval.sensor_heldout import lidar_surface, surface_scores
    from engine.geometry.depth_render import render_depth

    lo, hi = np.array([-2.0, -1.5, 0.0]), np.array([2.0, 1.5, 2.5])
    room = room_surface(lo, hi)
    K = np.array([[110.0, 0, 128], [0, 110.0, 96], [0, 0, 1]])
    views = []
    for yaw in (0, 90, 180, 270):  # from the middle of the room at 1.25 m, looking at each wall
        forward = np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw)), 0.0])
        right = np.cross(forward, [0, 0, 1.0])
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([right, [0, 0, -1.0], forward])  # OpenCV: x right, y down, z ahead
        pose[:3, 3] = [0.0, 0.0, 1.25]
        depth = render_depth(room.vertices, room.faces, K, pose, (256, 192))
        views.append((np.where(np.isfinite(depth), depth, 0.0).astype(np.float32), K, pose))
    truth = lidar_surface(views)

    near = surface_scores(Mesh(room.vertices + np.float32([0.03, 0, 0]), room.faces), truth)
    assert near["fscore"] > 0.97 and near["normal_agreement"] > 0.93  # the 4 cm truth bevels its corners

    # 10 cm along x: the two end walls leave the truth; floor, ceiling and side walls slide within theirs.
    # Independently: the share of the LiDAR's points that lie on the end walls.
    points = np.concatenate([
        (np.stack([(u + 0.5 - K[0, 2]) / K[0, 0] * d, (v + 0.5 - K[1, 2]) / K[1, 1] * d, d], 1) @ pose[:3, :3].T) + pose[:3, 3]
        for depth, _, pose in views for v, u in [np.nonzero(depth > 0)] for d in [depth[v, u]]])
    end_walls = float(np.mean(np.abs(np.abs(points[:, 0]) - 2.0) < 0.02))
    assert 0.2 < end_walls < 0.5
    far = surface_scores(Mesh(room.vertices + np.float32([0.10, 0, 0]), room.faces), truth)
    assert far["recall"] == pytest.approx(1 - end_walls, abs=0.05)
    assert far["prec"] < 1 - 0.5 * end_walls
    assert far["normal_agreement"] > 0.93  # what is near the truth still faces as it does


def test_the_held_out_frames_lidar_is_no_input_of_the_reconstruction(export):
    # The capture's point cloud is its LiDAR (it bounds and seeds stereo): a frame's depth is a plane at
    # 1 + 0.1 i m before it, so each point's depth along its frame's axis says which frame gave it.
    from engine.eval.sensor_heldout import without_held_out_points

    assert export.points is not None
    kept, held = split_capture(export, 2)
    scored = without_held_out_points(export, held)  # --all-photos: every photo in, every second one the truth

    def frames_of(points: np.ndarray) -> set[int]:
        found = set()
        for i, frame in enumerate(export.frames):
            depth = (points - frame.pose[:3, 3]) @ frame.pose[:3, 2]
            if np.isclose(depth, 1.0 + 0.1 * i, atol=1e-3).any():
                found.add(i)
        return found

    held_positions = {export.frames.index(f) for f in held}
    assert held_positions <= frames_of(export.points), "the fixture's cloud holds every frame's depth"
    assert not frames_of(scored.points) & held_positions
    assert frames_of(scored.points) == set(range(len(export.frames))) - held_positions
