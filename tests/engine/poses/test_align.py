"""Similarity tools: Umeyama fit, applying a Sim(3) to poses, pose errors against truth."""

from __future__ import annotations

import numpy as np
import pytest

from engine.poses.align import Similarity, pose_errors, rotation_angle_deg, umeyama


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def random_pose(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = random_rotation(rng)
    pose[:3, 3] = rng.uniform(-3, 3, 3)
    return pose


def axis_angle(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(degrees)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(1)
    truth = Similarity(random_rotation(rng), rng.uniform(-5, 5, 3), 0.37)
    source = rng.uniform(-2, 2, (30, 3))
    fitted = umeyama(source, truth.apply_points(source))
    assert np.allclose(fitted.rotation, truth.rotation, atol=1e-10)
    assert np.allclose(fitted.translation, truth.translation, atol=1e-10)
    assert fitted.scale == pytest.approx(0.37, rel=1e-10)


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(2)
    source = rng.uniform(-1, 1, (20, 3))
    mirrored = source * [1, 1, -1]  # the best orthogonal fit is a reflection; a rotation must come back
    fitted = umeyama(source, mirrored)
    assert np.linalg.det(fitted.rotation) == pytest.approx(1.0)


def test_apply_pose_keeps_projections():
    """A point and a camera moved by the same similarity project to the same pixel."""
    rng = np.random.default_rng(3)
    sim = Similarity(random_rotation(rng), rng.uniform(-5, 5, 3), 2.5)
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    pose = random_pose(rng)
    point = pose[:3, 3] + pose[:3, :3] @ [0.3, -0.2, 2.0]  # in front of the camera

    def project(c2w: np.ndarray, p: np.ndarray) -> np.ndarray:
        x = K @ (c2w[:3, :3].T @ (p - c2w[:3, 3]))
        return x[:2] / x[2]

    moved = sim.apply_pose(pose)
    assert np.allclose(moved[:3, :3] @ moved[:3, :3].T, np.eye(3), atol=1e-12)  # still rigid
    assert np.allclose(project(moved, sim.apply_points(point[None])[0]), project(pose, point), atol=1e-9)


def test_then_composes_in_order():
    rng = np.random.default_rng(4)
    a = Similarity(random_rotation(rng), rng.uniform(-1, 1, 3), 0.5)
    b = Similarity(random_rotation(rng), rng.uniform(-1, 1, 3), 3.0)
    points = rng.uniform(-1, 1, (5, 3))
    assert np.allclose(a.then(b).apply_points(points), b.apply_points(a.apply_points(points)))
    assert np.allclose(a.then(b).matrix(), b.matrix() @ a.matrix())


def test_pose_errors_are_zero_up_to_a_similarity_and_see_a_rotated_camera():
    rng = np.random.default_rng(5)
    truth = [random_pose(rng) for _ in range(10)]
    sim = Similarity(random_rotation(rng), rng.uniform(-5, 5, 3), 0.2)
    estimated = [sim.apply_pose(p) for p in truth]
    clean = pose_errors(estimated, truth)
    assert clean["rotation_deg_max"] < 1e-6 and clean["position_max"] < 1e-9
    assert clean["scale"] == pytest.approx(5.0)

    # Turn one camera by 3 degrees about its own axis: its centre (and so the fit) stays put.
    estimated[4] = estimated[4].copy()
    estimated[4][:3, :3] = estimated[4][:3, :3] @ axis_angle([0.2, 1.0, 0.1], 3.0)
    errors = pose_errors(estimated, truth)
    assert errors["rotation_deg_max"] == pytest.approx(3.0, abs=1e-6)
    assert errors["rotation_deg_mean"] == pytest.approx(0.3, abs=1e-6)


def test_rotation_angle():
    assert rotation_angle_deg(axis_angle([1, 2, 3], 37.0)) == pytest.approx(37.0)
    assert rotation_angle_deg(np.eye(3)) == 0.0


def test_pose_errors_rejects_mismatched_lists():
    with pytest.raises(ValueError):
        pose_errors([np.eye(4)] * 3, [np.eye(4)] * 4)
