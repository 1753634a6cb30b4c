"""Metric scale from the floor and ceiling (engine/poses/scale.py).

Rooms are built as point clouds in arbitrary units (a floor, a ceiling, four walls and a ring of
hand-held cameras), so the true metres-per-unit is known: a floor and a ceiling give the scale within
a few per cent; a camera held low (1.15 m where 1.5 m is assumed) is pulled towards the truth by the
ceiling; without a floor the camera-height guess stays and says so. One test runs the dense path on
the bundled demo photos (true poses, shrunk to arbitrary units): the floor is found in stereo depth
and the camera height comes back in metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.capture.model import Capture, Frame
from engine.mesh_io import read_ply
from engine.poses.prepare import SFM_NEVER, prepare_capture
from engine.poses.scale import SOURCE_FLOOR, SOURCE_FLOOR_AND_CEILING, SOURCE_GUESS, estimate_metric_scale
from fixtures_capture import intrinsics, look_yaw_pitch

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
UNITS_PER_METRE = 0.37  # an SfM world: 1 m is 0.37 units


def _room(rng: np.random.Generator, camera_height: float, room_height: float | None, floor: bool = True,
          size: tuple[float, float] = (4.0, 5.0)) -> tuple[Capture, np.ndarray]:
    """A capture of 12 cameras walking round a room, and its sparse points (N, 3), in units."""
    length, width = size
    parts = []
    if floor:
        parts.append(np.c_[rng.uniform(0, length, (600, 2)) * [1, width / length], np.zeros(600)])
    if room_height is not None:
        parts.append(np.c_[rng.uniform(0, length, (400, 2)) * [1, width / length], np.full(400, room_height)])
    top = room_height if room_height is not None else 2.6
    for x in (0.0, length):
        parts.append(np.c_[np.full(300, x), rng.uniform(0, width, 300), rng.uniform(0.05, top - 0.05, 300)])
    for y in (0.0, width):
        parts.append(np.c_[rng.uniform(0, length, 300), np.full(300, y), rng.uniform(0.05, top - 0.05, 300)])
    if not floor:  # nothing below the cameras but the walls' upper parts
        parts = [p[p[:, 2] > camera_height + 0.1] for p in parts]
    points = np.concatenate(parts) + rng.normal(0, 0.004, (sum(len(p) for p in parts), 3))
    K = intrinsics(200.0, 320, 240)
    frames = []
    for i, angle in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False)):
        centre = [length / 2 + 1.2 * np.cos(angle), width / 2 + 1.5 * np.sin(angle),
                  camera_height + 0.05 * np.sin(3 * angle)]
        pose = look_yaw_pitch(centre, angle + np.pi, np.radians(-10.0))
        pose[:3, 3] *= UNITS_PER_METRE
        frames.append(Frame(Path(f"/nonexistent/{i:03d}.jpg"), 320, 240, K.copy(), pose))
    capture = Capture(Path("/nonexistent"), "colmap", frames, metric=False)
    return capture, points * UNITS_PER_METRE


def _error(factor: float) -> float:
    """Relative error of a factor against the true metres per unit."""
    return factor * UNITS_PER_METRE - 1.0


def test_floor_and_ceiling_give_the_scale_of_a_room_in_arbitrary_units() -> None:
    capture, points = _room(np.random.default_rng(0), camera_height=1.5, room_height=2.5)
    both = estimate_metric_scale(capture, points, dense=False)
    assert both.source == SOURCE_FLOOR_AND_CEILING and both.evidence == "sparse points"
    assert abs(_error(both.factor)) < 0.03, both.describe()
    assert [c.name for c in both.cues] == ["camera height", "room height"]
    assert both.cues[1].units == pytest.approx(2.5 * UNITS_PER_METRE, rel=0.01)
    # Two cues that agree are surer than the floor alone.
    floor_only = estimate_metric_scale(capture, points[points[:, 2] < 2.0 * UNITS_PER_METRE], dense=False)
    assert floor_only.source == SOURCE_FLOOR and abs(_error(floor_only.factor)) < 0.03
    assert both.relative_sigma < 0.08 < floor_only.relative_sigma
    text = both.describe()
    assert "floor and ceiling (sparse points)" in text and f"+-{100 * both.relative_sigma:.0f} %" in text


def test_a_camera_held_low_is_pulled_towards_the_truth_by_the_ceiling() -> None:
    capture, points = _room(np.random.default_rng(1), camera_height=1.15, room_height=2.5)
    guess = estimate_metric_scale(capture, points[points[:, 2] < 2.0 * UNITS_PER_METRE], dense=False)
    both = estimate_metric_scale(capture, points, dense=False)
    assert _error(guess.factor) > 0.25  # the 1.5 m assumption makes this room 30 % too big
    assert abs(_error(both.factor)) < 0.75 * abs(_error(guess.factor))
    # The cues disagree: the uncertainty says so (wider than for a room where they agree).
    assert both.relative_sigma > 0.08


def test_the_user_camera_height_is_the_prior() -> None:
    capture, points = _room(np.random.default_rng(2), camera_height=1.7, room_height=None)
    assumed = estimate_metric_scale(capture, points, camera_height=1.7, dense=False)
    assert assumed.source == SOURCE_FLOOR and abs(_error(assumed.factor)) < 0.03


def test_without_a_floor_the_camera_height_guess_stays_and_says_so() -> None:
    capture, points = _room(np.random.default_rng(3), camera_height=1.5, room_height=2.5, floor=False)
    estimate = estimate_metric_scale(capture, points, dense=False)
    assert estimate.source == SOURCE_GUESS and estimate.factor == 1.0 and estimate.relative_sigma >= 0.3
    assert "no floor" in estimate.describe()


def test_a_plane_just_above_the_heads_is_not_taken_as_the_ceiling() -> None:
    capture, points = _room(np.random.default_rng(4), camera_height=1.5, room_height=1.8)
    estimate = estimate_metric_scale(capture, points, dense=False)
    assert estimate.source == SOURCE_FLOOR
    assert any("not taken as the ceiling" in n for n in estimate.notes)


def test_prepare_reports_the_scale_its_uncertainty_and_source() -> None:
    capture, points = _room(np.random.default_rng(5), camera_height=1.5, room_height=2.5)
    prepared = prepare_capture(capture.with_points(points, np.zeros((len(points), 3), np.uint8)), sfm=SFM_NEVER)
    assert prepared.scale_source == SOURCE_FLOOR_AND_CEILING
    poses = np.stack([f.pose for f in prepared.capture.frames])
    # Metres now: the ring's cameras stand 1.5 m above the floor at z = 0.
    assert np.median(poses[:, 2, 3]) == pytest.approx(1.5, rel=0.03)
    summary = prepared.summary()["scale"]
    assert summary["source"] == "floor and ceiling (sparse points)" and 0 < summary["relative_sigma"] < 0.08
    assert "scaled by the floor and ceiling, +-" in prepared.pose_status()
    assert prepared.description.startswith("metric scale x")
    # The similarity that moved the given cameras includes the new scale.
    assert prepared.similarity.scale == pytest.approx(1.0 / UNITS_PER_METRE, rel=0.03)


def _wall_points(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3) points on the demo room's walls and furniture sides (true mesh faces that are not
    horizontal): sparse points that miss the floor, as on a plain floor."""
    mesh = read_ply(SAMPLE / "truth" / "mesh_gt.ply")
    corners = mesh.vertices[mesh.faces].astype(np.float64)  # (F, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    areas = 0.5 * np.linalg.norm(normals, axis=1)
    upright = np.abs(normals[:, 2]) < 0.3 * np.maximum(2.0 * areas, 1e-12)
    chosen = rng.choice(np.flatnonzero(upright), count, p=areas[upright] / areas[upright].sum())
    a, b = rng.uniform(size=(2, count, 1))
    flip = (a + b) > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    c = corners[chosen]
    return c[:, 0] + a * (c[:, 1] - c[:, 0]) + b * (c[:, 2] - c[:, 0])


def test_dense_depth_finds_the_floor_that_the_sparse_points_miss() -> None:
    """The demo photos with their true poses shrunk to 0.37 units per metre and sparse points on the
    walls only: the floor comes from low-resolution stereo depth of a few keyframes."""
    if not (SAMPLE / "truth" / "pose").is_dir():
        pytest.skip(f"the demo sample is missing: {SAMPLE}")
    names = sorted(p.name for p in (SAMPLE / "images").glob("*.jpg"))[:18]
    K = np.loadtxt(SAMPLE / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    frames = []
    for name in names:
        pose = np.loadtxt(SAMPLE / "truth" / "pose" / f"{Path(name).stem}.txt").reshape(4, 4)
        pose[:3, 3] *= UNITS_PER_METRE
        frames.append(Frame(SAMPLE / "images" / name, 320, 240, K.copy(), pose))
    true_height = float(np.median([f.pose[2, 3] for f in frames])) / UNITS_PER_METRE
    capture = Capture(SAMPLE / "images", "colmap", frames, metric=False)
    walls = _wall_points(np.random.default_rng(0), 3000) * UNITS_PER_METRE
    assert estimate_metric_scale(capture, walls, dense=False).source == SOURCE_GUESS  # no floor in them
    estimate = estimate_metric_scale(capture, walls)
    assert estimate.dense_points > 1000 and estimate.cues and estimate.cues[0].evidence == "dense depth"
    assert estimate.cues[0].units / UNITS_PER_METRE == pytest.approx(true_height, rel=0.03)
    assert abs(_error(estimate.factor)) < 0.1, estimate.describe()
