"""`engine eval-scale` (engine/eval/scale_eval.py): the scale of estimated cameras against true ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine.errors import VortxError
from engine.eval.scale_eval import fit_scale, true_camera_centres
from engine.geometry.cameras import look_at


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_a_reconstruction_twelve_percent_too_large_in_another_frame_reads_plus_twelve_percent():
    rng = np.random.default_rng(0)
    true = {f"{i:06d}": rng.uniform([0, 0, 1.2], [4, 5, 1.7]) for i in range(20)}
    R = _rotation(np.array([0.3, -1.0, 0.4]), 1.1)
    # SfM's world: rotated, moved and 1.12 times too large, with 1 cm of noise on the centres.
    estimated = {name: 1.12 * R @ c + [3.0, -2.0, 0.5] + rng.normal(0, 0.01, 3) for name, c in true.items()}
    estimated.pop("000003")  # a photo SfM did not register
    ratio, rms, matched = fit_scale(estimated, true)
    assert matched == 19
    assert ratio - 1 == pytest.approx(0.12, abs=0.005)
    assert rms == pytest.approx(0.01 * np.sqrt(3) / 1.12, rel=0.4)


def test_too_few_registered_photos_give_no_scale():
    ratio, rms, matched = fit_scale({"a": np.zeros(3)}, {"a": np.ones(3), "b": np.zeros(3)})
    assert matched == 1 and np.isnan(ratio) and np.isnan(rms)


def test_true_poses_come_from_pose_true_when_the_given_ones_were_perturbed(tmp_path: Path):
    for folder, centre in (("pose", [9.0, 9.0, 9.0]), ("pose_true", [1.0, 2.0, 1.5])):
        (tmp_path / folder).mkdir()
        np.savetxt(tmp_path / folder / "000000.txt", look_at(np.array(centre), np.array([0.0, 0.0, 1.0])))
    assert np.allclose(true_camera_centres(tmp_path)["000000"], [1.0, 2.0, 1.5])
    with pytest.raises(VortxError, match="no true poses"):
        true_camera_centres(tmp_path / "nowhere")


def test_a_few_misplaced_photos_do_not_decide_the_scale_but_show_in_the_rms():
    rng = np.random.default_rng(1)
    true = {f"{i:06d}": rng.uniform([0, 0, 1.2], [4, 5, 1.7]) for i in range(30)}
    estimated = {name: 0.9 * c for name, c in true.items()}
    for name in list(true)[:4]:  # registered on the wrong wall, 3 m away
        estimated[name] = estimated[name] + [3.0, 0.0, 0.0]
    ratio, rms, _ = fit_scale(estimated, true)
    assert ratio == pytest.approx(0.9, abs=0.02)
    assert rms > 0.3
