"""Refining given poses: the bundled demo room's true poses, perturbed on purpose (0.5-2 deg, a few
cm, as a tracker would be off), come back within 0.2 deg of the truth; a frame given a wildly wrong
pose keeps it and is reported. The acceptance rules (refuse frames that move too far, refuse the
whole refinement when many do) are checked on constructed worker results, without COLMAP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.capture.model import Capture, Frame
from engine.errors import PoseError
from engine.poses import RefineOptions, fit_pose_similarity, refine_poses, rotation_angle_deg
from engine.poses.align import Similarity
from engine.poses.refine import _accepted, _cam_from_world, neighbour_pairs
from fixtures_capture import perturbed_poses as perturbed, rotation_about

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "demo_room"
WILD = 7  # the frame given a pose 30 degrees off


@pytest.fixture(scope="module")
def demo_refinement():
    """20 demo photos at 320x240 with perturbed true poses and one wild pose, refined once (~25 s)."""
    if not (SAMPLE / "truth" / "pose").is_dir():
        pytest.skip(f"the demo sample is missing: {SAMPLE}")
    names = sorted(p.name for p in (SAMPLE / "images").glob("*.jpg"))[:20]
    K = np.loadtxt(SAMPLE / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    truth = [np.loadtxt(SAMPLE / "truth" / "pose" / f"{Path(n).stem}.txt").reshape(4, 4) for n in names]
    given = perturbed(truth, np.random.default_rng(1))
    given[WILD][:3, :3] = given[WILD][:3, :3] @ rotation_about([0.0, 1.0, 0.0], 30.0)
    frames = [Frame(SAMPLE / "images" / n, 320, 240, K.copy(), g) for n, g in zip(names, given)]
    capture = Capture(SAMPLE / "images", "scannet", frames, metric=True)
    result = refine_poses(capture, RefineOptions())
    print(result.report)
    return truth, given, result


def test_refinement_brings_perturbed_poses_back_within_a_fifth_of_a_degree(demo_refinement):
    truth, given, result = demo_refinement
    good = [k for k in range(len(truth)) if k != WILD]
    refined = np.stack([result.capture.frames[k].pose for k in good])
    true = np.stack([truth[k] for k in good])
    # The given poses are off by 0.5-2 deg each.
    before = [rotation_angle_deg(t[:3, :3].T @ given[k][:3, :3]) for k, t in zip(good, true)]
    assert min(before) > 0.5 and max(before) > 1.5

    # Frame to frame (what stereo and fusion need), the refined poses agree with the truth to 0.2 deg:
    # compared after the one similarity that best maps them onto the truth.
    fit = fit_pose_similarity(refined, true)
    errors = [rotation_angle_deg(t[:3, :3].T @ fit.apply_pose(r)[:3, :3]) for r, t in zip(refined, true)]
    assert max(errors) < 0.2, errors
    assert fit.scale == pytest.approx(1.0, abs=0.02)  # the given metric scale is kept
    assert max(np.linalg.norm(fit.apply_pose(r)[:3, 3] - t[:3, 3]) for r, t in zip(refined, true)) < 0.01
    # Without any fit, only the given poses' average error remains (the world is theirs): well under 2 deg.
    absolute = [rotation_angle_deg(t[:3, :3].T @ r[:3, :3]) for r, t in zip(refined, true)]
    assert np.median(absolute) < 0.5 and max(absolute) < 0.6

    # The report's per-frame change is the perturbation undone: close to each given pose's true error.
    change = {c.name: c for c in result.changes}
    for k, b in zip(good, before):
        assert change[result.capture.frames[k].name].rotation_deg == pytest.approx(b, abs=0.6)
    assert result.rotation_deg_max == pytest.approx(max(c.rotation_deg for c in result.changes if c.status == "refined"))
    assert result.units == "m" and "deg median" in result.report and "cm max" in result.report
    assert len(result.points) > 500 and result.mean_reprojection_error < 1.0


def test_a_wildly_wrong_pose_keeps_its_given_pose_and_is_reported(demo_refinement):
    truth, given, result = demo_refinement
    wild = result.capture.frames[WILD]
    assert np.array_equal(wild.pose, given[WILD])
    assert wild.name in result.refused + result.not_refined
    assert len(result.refined) == len(truth) - 1
    assert any(wild.name in w for w in result.warnings)
    assert f"{wild.name} (" in result.report and "keeps its given pose" in result.report


# --- acceptance rules on constructed worker results (no COLMAP) ----------------------------------


def ring(count: int = 12) -> list[np.ndarray]:
    from fixtures_capture import look_at

    angles = np.linspace(0, 2 * np.pi, count, endpoint=False)
    return [look_at([2 * np.cos(a), 2 * np.sin(a), 1.5], [0, 0, 1.0]) for a in angles]


def worker_result(adjusted: list[np.ndarray], points: int = 200) -> dict:
    images = [{"name": f"{k:06d}.jpg", "cam_from_world": _cam_from_world(p).tolist(), "num_points3D": points}
              for k, p in enumerate(adjusted)]
    return {"images": images, "mean_reprojection_error": 0.3, "num_points3D": 1000, "rounds": 3,
            "database": {"verified_pairs": 40}, "timings": {"adjust": 1.0}}


def accept(given: list[np.ndarray], adjusted: list[np.ndarray], metric: bool = True, points: int = 200):
    frames = [Frame(Path(f"/c/{k:03d}.jpg"), 640, 480, np.eye(3), g) for k, g in enumerate(given)]
    capture = Capture(Path("/c"), "transforms", frames, metric=metric)
    names = [f"{k:06d}.jpg" for k in range(len(given))]
    return _accepted(capture, list(range(len(given))), np.stack(given), names, worker_result(adjusted, points),
                     np.zeros((0, 3)), np.zeros((0, 3), np.uint8), RefineOptions())


def test_adjusted_world_is_brought_back_and_a_runaway_frame_is_refused():
    given = ring()
    gauge = Similarity(rotation_about([1, 2, 3], 40.0), np.array([5.0, -2.0, 1.0]), 0.3)  # BA's arbitrary world
    adjusted = [gauge.apply_pose(p) for p in given]
    adjusted[4] = gauge.apply_pose(given[4] @ np.block([[rotation_about([0, 0, 1], 25.0), np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
    result = accept(given, adjusted)
    assert result.refused == ["004.jpg"] and len(result.refined) == 11
    assert result.rotation_deg_max < 1e-6 and result.translation_max < 1e-9
    assert np.array_equal(result.capture.frames[4].pose, given[4])
    refused = next(c for c in result.changes if c.status == "refused")
    assert refused.rotation_deg == pytest.approx(25.0, abs=0.01) and "25.0 deg" in refused.reason


def test_a_refinement_that_moves_many_frames_by_metres_is_refused_with_the_numbers():
    given = ring()
    adjusted = [p.copy() for p in given]
    for k in range(0, 12, 2):  # half the frames thrown a metre or more away
        adjusted[k][:3, 3] += [1.5, 0.0, 0.0] if k % 4 else [0.0, -2.0, 0.5]
    with pytest.raises(PoseError, match=r"refused: \d+ of 12 frames.*position change median.*engine poses"):
        accept(given, adjusted)


def test_frames_without_enough_points_keep_their_pose_and_too_few_left_is_an_error():
    given = ring()
    with pytest.raises(PoseError, match="only 0 of 12 frames"):
        accept(given, given, points=3)


def test_pairs_join_sequential_and_nearby_frames_looking_the_same_way():
    poses = np.stack(ring(12))
    pairs = neighbour_pairs(poses, neighbours=2, sequential=1)
    assert all(i < j for i, j in pairs)
    assert {(k, k + 1) for k in range(11)} <= set(pairs)
    forward = poses[:, :3, 2]
    assert all(np.degrees(np.arccos(np.clip(forward[i] @ forward[j], -1, 1))) <= 75 for i, j in pairs if j - i > 1)
    assert (0, 11) in pairs  # the loop closes by pose, not by order


def test_pose_similarity_fit_recovers_a_straight_trajectory():
    """Umeyama on centres leaves the roll about a straight line free; the orientation-based fit does not."""
    line = [np.block([[rotation_about([0, 0, 1], 5.0 * k), np.array([[0.3 * k], [0.0], [1.5]])], [np.zeros((1, 3)), 1]])
            for k in range(6)]
    known = Similarity(rotation_about([1, -1, 2], 70.0), np.array([1.0, 2.0, 3.0]), 2.5)
    fit = fit_pose_similarity(np.stack(line), np.stack([known.apply_pose(p) for p in line]))
    assert np.allclose(fit.rotation, known.rotation, atol=1e-9)
    assert fit.scale == pytest.approx(2.5) and np.allclose(fit.translation, known.translation, atol=1e-9)
