"""Scoring a reconstruction from photos alone against the truth (engine/eval/against_truth.py): the
Sim(3) between the estimated and the true world, the pose errors after it, the F-score table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.eval.against_truth import compare_poses, fscore_table, score_mesh, true_poses
from engine.mesh_io import read_ply
from engine.poses import Similarity
from engine.recon.output_frame import moved_mesh
from engine.tsdf.volume import TsdfVolume
from conftest import REPO
from fixtures_capture import ring_poses, rotation_about

SAMPLE_TRUTH = REPO / "samples" / "demo_room" / "truth"


def test_poses_known_only_up_to_a_similarity_compare_exactly(tmp_path: Path) -> None:
    truths = {f"{i:06d}": pose for i, pose in enumerate(ring_poses(6, radius=1.5))}
    (tmp_path / "pose").mkdir()
    for stem, pose in truths.items():
        np.savetxt(tmp_path / "pose" / f"{stem}.txt", pose)
    assert set(true_poses(tmp_path, [*truths, "000099"])) == set(truths)  # a photo without a true pose is left out
    # What SfM might find: the same walk turned, moved and at a third of the size.
    truth_to_estimate = Similarity(rotation_about([0, 0, 1], 40.0), np.array([2.0, -1.0, 0.5]), 1 / 3)
    estimated = {s: truth_to_estimate.apply_pose(p) for s, p in true_poses(tmp_path, list(truths)).items()}
    estimated["000099"] = np.eye(4)  # registered, but with no truth to compare with
    poses = compare_poses(estimated, truths)
    assert poses.stems == sorted(truths) and poses.to_truth.scale == pytest.approx(3.0)
    assert poses.errors["rotation_deg_max"] < 1e-4 and poses.errors["position_max"] < 1e-6
    assert poses.summary(7).startswith("poses vs truth (6 of 7 photos registered; after the Sim(3) fit of the camera "
                                       "centres, scale 3.000): rotation error mean 0.00 deg")


def test_a_mesh_moved_back_into_the_truth_frame_scores_as_the_truth() -> None:
    truth, volume = read_ply(SAMPLE_TRUTH / "mesh_gt.ply"), TsdfVolume.load(SAMPLE_TRUTH / "tsdf_gt.npz")
    to_truth = Similarity(rotation_about([0, 0, 1], 30.0), np.array([0.5, 0.0, 0.0]), 2.0)
    estimated = moved_mesh(truth, to_truth.inverse())  # the truth as it sits in an estimated frame
    rows = [score_mesh("same room", moved_mesh(estimated, to_truth), truth, volume),
            score_mesh("left where it was", estimated, truth, volume)]
    assert rows[0].mesh.fscore > 0.99 and rows[1].mesh.fscore < 0.5
    lines = fscore_table(rows)
    assert lines[0].split() == ["method", "F", "prec", "recall", "acc", "cm", "comp", "cm"]
    assert lines[1].startswith("same room ") and lines[1].split()[2] == f"{rows[0].mesh.fscore:.3f}"
