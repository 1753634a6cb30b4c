"""Acceptance: SfM on 50 real phone photos (instant-ngp's fox) against their published COLMAP poses.

Only the photos are used (loaded as a plain photo folder: no EXIF, so the focal length is
estimated); transforms.json is the truth, compared up to a similarity (Umeyama on the camera
centres). It lists 67 frames, of which only 50 photos still exist, and uses OpenGL camera axes.

The photos were taken walking around the fox, so their file order is the capture order and the
sequential matcher (10 neighbours) suffices, at half the CPU of the exhaustive matcher that
`auto` picks for 50 photos (which registers them equally well: 50/50, rotation error max 0.74 deg).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from conftest import shared_dataset

from engine.capture import load_capture
from engine.poses import SfmOptions, estimate_poses, pose_errors

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def test_fox_photos_register_with_accurate_rotations():
    root = shared_dataset("fox")
    meta = json.loads((root / "transforms.json").read_text())
    truth = {
        frame["file_path"].split("/")[-1]: np.array(frame["transform_matrix"], dtype=np.float64) @ OPENGL_TO_OPENCV
        for frame in meta["frames"]
    }
    capture = load_capture(root / "images")  # the photos only, as a user's photo folder
    assert capture.format == "images" and len(capture.frames) == 50 and not capture.posed_frames

    start = time.perf_counter()
    result = estimate_poses(capture, SfmOptions(max_side=800, matcher="sequential"))
    elapsed = time.perf_counter() - start
    print(f"\n{result.report}\nwall time {elapsed:.1f} s")

    assert len(result.registered) >= 45, result.report
    posed = [f for f in result.capture.frames if f.pose is not None]
    errors = pose_errors([f.pose for f in posed], [truth[f.name] for f in posed])
    print(f"errors against transforms.json: {errors}")
    assert errors["rotation_deg_max"] < 2.0
    # K back at full size (1080 x 1920): the truth's focal length is 1375 px.
    assert result.K[0, 0] == pytest.approx(meta["fl_x"], rel=0.03)
    assert result.K[0, 2] == pytest.approx(540.0) and result.K[1, 2] == pytest.approx(960.0)

    # The automatic scale says where it came from. The fox sits on a table the cameras circle, with
    # little floor in view: either a floor plane is reported with its numbers, or the report says
    # plainly that no floor was found (and warns that the size is a guess).
    alignment = result.alignment
    assert alignment is not None and f"world: {alignment.description}" in result.report
    if alignment.floor_method == "plane":
        assert alignment.description.startswith("floor plane from") and "RANSAC inliers" in alignment.description
        assert alignment.scale_source == "camera height" and "scaled x" in alignment.description
    else:
        assert alignment.description.startswith("no floor")
        assert any(w.startswith("no floor") for w in result.warnings)
