"""The refine job's triangulation settings in the COLMAP worker (sfm_worker_refine.py), COLMAP not run:
poses a tracker gives (1-2 deg off) reproject tracks of three or more views 5-10 px off at a 280 px
focal, so the triangulation must tolerate that much, or the tracks that could correct the rotations are
gone before our own adjustment sees them; COLMAP's fixed-pose adjustment filter only with `loose_filter`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from engine.poses import sfm_worker_refine  # noqa: E402


def _options_of_triangulation(monkeypatch, tmp_path: Path, loose_angle_deg: float, focal: float, loose_filter: bool = False):
    seen = {}

    def fake(reconstruction, database, images, out, clear_points, options):
        seen["options"] = options
        return reconstruction

    monkeypatch.setattr(pycolmap, "triangulate_points", fake)
    sfm_worker_refine._triangulate(pycolmap.Reconstruction(), tmp_path / "db", tmp_path, tmp_path / "out", loose_angle_deg, focal,
                            loose_filter)
    return seen["options"]


def test_the_fixed_pose_adjustment_keeps_tracks_as_far_off_as_the_poses_may_be(monkeypatch, tmp_path):
    options = _options_of_triangulation(monkeypatch, tmp_path, loose_angle_deg=3.0, focal=277.0, loose_filter=True)
    pixels = 277.0 * np.tan(np.radians(3.0))  # 14.5 px: what 3 deg of rotation moves a point by
    assert options.mapper.filter_max_reproj_error == pytest.approx(pixels)
    assert options.triangulation.merge_max_reproj_error == pytest.approx(pixels)
    assert options.triangulation.complete_max_reproj_error == pytest.approx(pixels)
    assert options.triangulation.create_max_angle_error == pytest.approx(3.0)


def test_by_default_the_fixed_pose_adjustment_filters_at_colmaps_4_px(monkeypatch, tmp_path):
    """The loose filter is off by default: on the real SUN3D room its extra tracks cost F (RefineOptions)."""
    options = _options_of_triangulation(monkeypatch, tmp_path, loose_angle_deg=3.0, focal=277.0)
    assert options.mapper.filter_max_reproj_error == 4.0
    assert options.triangulation.merge_max_reproj_error == pytest.approx(277.0 * np.tan(np.radians(3.0)))


def test_a_tolerance_of_zero_is_colmaps_own(monkeypatch, tmp_path):
    options = _options_of_triangulation(monkeypatch, tmp_path, loose_angle_deg=0.0, focal=277.0)
    defaults = pycolmap.IncrementalPipelineOptions()
    assert options.mapper.filter_max_reproj_error == defaults.mapper.filter_max_reproj_error == 4.0
    assert options.triangulation.create_max_angle_error == defaults.triangulation.create_max_angle_error == 2.0


def test_a_reused_database_says_how_its_features_were_extracted(tmp_path):
    database = tmp_path / "database.db"
    assert sfm_worker_refine._features_settings(database) == {}  # an older database without the side file: defaults
    sfm_worker_refine._features_path(database).write_text(json.dumps({"peak_threshold": sfm_worker_refine.LOW_CONTRAST_PEAK_THRESHOLD}))
    assert sfm_worker_refine._features_settings(database)["peak_threshold"] == sfm_worker_refine.LOW_CONTRAST_PEAK_THRESHOLD
    assert sfm_worker_refine._features_path(database).name == "database_features.json"


@pytest.mark.parametrize("camera_per_photo", [False, True], ids=["one camera", "a camera per photo"])
def test_unmatched_images_are_numbered_by_name_and_matched_ones_keep_their_ids(tmp_path, camera_per_photo):
    database = tmp_path / "database.db"
    pycolmap.Database.open(str(database)).close()  # COLMAP's own schema
    import sqlite3
    # As extraction threads leave it: ids in the order the photos finished, not by name, and the frames
    # numbered in their own order; photos 1 and 4 (c.jpg, a.jpg) already matched, as a pose check's
    # shared database has them. A phone capture's photos each have their own intrinsics, so their own
    # camera and rig (rig ids apart from camera ids, as COLMAP may number them).
    finished = ["c.jpg", "e.jpg", "b.jpg", "a.jpg", "d.jpg"]
    frame_of_image = {1: 2, 2: 1, 3: 3, 4: 5, 5: 4}
    camera_of = {name: (k + 1 if camera_per_photo else 1) for k, name in enumerate(finished)}
    rig_of_camera = {camera: 10 + camera for camera in camera_of.values()}
    with sqlite3.connect(database) as con:
        for camera in sorted(set(camera_of.values())):
            con.execute("INSERT INTO cameras VALUES (?, 1, 320, 240, ?, 0)", (camera, np.full(4, camera, float).tobytes()))
            con.execute("INSERT INTO rigs VALUES (?, ?, 0)", (rig_of_camera[camera], camera))
        for image_id, name in enumerate(finished, start=1):
            camera = camera_of[name]
            con.execute("INSERT INTO images VALUES (?, ?, ?)", (image_id, name, camera))
            keypoints = np.full((image_id, 2), float(image_id), np.float32)  # each image's count is its first id
            con.execute("INSERT INTO keypoints VALUES (?, ?, 2, ?)", (image_id, image_id, keypoints.tobytes()))
            con.execute("INSERT INTO descriptors VALUES (?, 0, ?, 128, ?)", (image_id, image_id, bytes(128 * image_id)))
            con.execute("INSERT INTO frames VALUES (?, ?)", (frame_of_image[image_id], rig_of_camera[camera]))
            con.execute("INSERT INTO frame_data VALUES (?, ?, ?, 0)", (frame_of_image[image_id], image_id, camera))
        con.execute("INSERT INTO matches VALUES (?, 0, 2, NULL)", (1 * sfm_worker_refine.COLMAP_MAX_IMAGES + 4,))

    sfm_worker_refine.number_unmatched_images_by_name(database)

    with sqlite3.connect(database) as con:
        ids = dict(con.execute("SELECT name, image_id FROM images"))
        first_id = {ids[name]: finished.index(name) + 1 for name in finished}
        # The matched photos keep 1 and 4; the others take 2, 3 and 5 in name order.
        assert ids == {"c.jpg": 1, "a.jpg": 4, "b.jpg": 2, "d.jpg": 3, "e.jpg": 5}
        for image_id, rows in con.execute("SELECT image_id, rows FROM keypoints"):
            assert rows == first_id[image_id]  # the features moved with their photo
        for image_id, rows in con.execute("SELECT image_id, rows FROM descriptors"):
            assert rows == first_id[image_id]
        assert sorted(con.execute("SELECT frame_id, data_id FROM frame_data")) == [(i, i) for i in range(1, 6)]
        # Each photo's frame has the photo's id and sits in its own camera's rig, as the triangulation checks.
        for name, image_id in ids.items():
            assert con.execute("SELECT camera_id FROM images WHERE image_id = ?", (image_id,)).fetchone()[0] == camera_of[name]
            rig = con.execute("SELECT rig_id FROM frames WHERE frame_id = ?", (image_id,)).fetchone()[0]
            assert con.execute("SELECT ref_sensor_id FROM rigs WHERE rig_id = ?", (rig,)).fetchone()[0] == camera_of[name]
            assert con.execute("SELECT sensor_id FROM frame_data WHERE data_id = ?", (image_id,)).fetchone()[0] == camera_of[name]
