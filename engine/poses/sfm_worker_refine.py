"""The COLMAP worker's job of `"kind": "refine"`, run by `sfm_worker.py` and written by `refine.py` and
the pose check in `quality.py`. It works from given poses instead of estimating new ones: SIFT
features, matches between the listed image pairs, one triangulation with the given poses and
intrinsics (fixed); the parent adjusts (see `run_refine`). Its fields beyond the SfM job's:
  K_per_image        [[3x3], ...] in pixels of the source images, one per image (PINHOLE)
  cam_from_world     [[3x4], ...] the given world-to-camera poses, OpenCV axes, one per image
  pairs              [[i, j], ...] image indices to match
  loose_angle_deg    the triangulation, and the filter of COLMAP's fixed-pose adjustment after it,
                     accept rays this far off (the given poses' error); 0: COLMAP's defaults (2 deg, 4 px)
  features_from      null, or a database of an earlier job on the same photos (same names, same
                     max_side) whose features and matches are reused (and photos it lacks are extracted
                     with the same SIFT settings, from its side file DATABASE_features.json)
Its result: work_dir/result.json {"images": [{"name", "num_points3D"}], "mean_reprojection_error",
"num_points3D", "scale": [sx, sy] (downscaled / source pixels), "database", "timings"} and
work_dir/points.npz as for SfM plus the tracks (obs_image, obs_point, obs_uv, obs_keypoint), every
photo's keypoints and the verified matches (see `_write_tracks`).

Like the worker, it imports nothing from the engine, only pycolmap, numpy and the standard library:
the worker process loads it by name from this folder (see `sfm_worker.py`).
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import time
from pathlib import Path

import numpy as np

if __package__:  # imported as part of the engine (the tests)
    from .sfm_worker_steps import (LOW_CONTRAST_KEYPOINTS, LOW_CONTRAST_PEAK_THRESHOLD, database_stats,
                                   downscale_images, extract_features, median_keypoints, say)
else:  # loaded by the worker process, run by file path, where this folder is sys.path[0]
    from sfm_worker_steps import (LOW_CONTRAST_KEYPOINTS, LOW_CONTRAST_PEAK_THRESHOLD, database_stats,
                                  downscale_images, extract_features, median_keypoints, say)

COLMAP_MAX_IMAGES = 2147483647  # COLMAP's pair id: image_id1 * this + image_id2
# The pose refinement is repeatable: its RANSACs (two-view verification, triangulation) seeded, and its
# images numbered by name (number_unmatched_images_by_name).
REFINE_RANDOM_SEED = 0


def number_unmatched_images_by_name(db_path: Path) -> None:
    """Renumber, in place, the database's images that no match refers to yet so that their ids follow
    their names, and give every image the frame of its own id. COLMAP's extraction threads number the
    images (and, separately, their frames) in the order they finish, and the triangulation and
    adjustment visit images by id, so without this the same photos and poses gave different tracks and
    refined poses from run to run (the 200-frame room: 17 neighbouring pairs swapped, 7,380-7,419
    points). Images already matched (a pose check's shared database) keep their ids: their pair ids and
    match columns are built on them.

    The refinement's reconstruction gives each image a trivial frame numbered as the image, in its
    camera's rig, and the triangulation checks the database's frame of that id against it. So each
    image's frame is written with the image's id and the rig it was extracted in: a phone capture's
    photos each have their own camera and rig, and a frame left behind sat in another photo's rig
    ("Check failed: existing_frame.RigId() == frame.RigId()"). A database whose frames are not one
    camera image each is left as it is."""
    with sqlite3.connect(db_path) as con:
        frame_data = list(con.execute("SELECT frame_id, data_id, sensor_id, sensor_type FROM frame_data"))
        rig_of_frame = dict(con.execute("SELECT frame_id, rig_id FROM frames"))
        camera_of = dict(con.execute("SELECT image_id, camera_id FROM images"))
        one_each = (len({f for f, *_ in frame_data}) == len(frame_data) == len(rig_of_frame)
                    and sorted(d for _, d, *_ in frame_data) == sorted(camera_of)
                    and all(camera_of[d] == sensor for _, d, sensor, _ in frame_data))
        if not camera_of or not one_each:
            return
        matched: set[int] = set()
        for table in ("matches", "two_view_geometries"):
            for (pair_id,) in con.execute(f"SELECT pair_id FROM {table}"):
                matched.update((pair_id // COLMAP_MAX_IMAGES, pair_id % COLMAP_MAX_IMAGES))
        rows = [(i, n) for i, n in con.execute("SELECT image_id, name FROM images") if i not in matched]
        ids = sorted(i for i, _ in rows)
        new_id = {old: new for (old, _), new in zip(sorted(rows, key=lambda row: row[1]), ids)}
        moved = {old: new for old, new in new_id.items() if old != new}
        # Ids pass through a free range above every id in use: each id column is unique or a key.
        shift = 1 + max(camera_of)
        for source, target in [(old, old + shift) for old in moved] + [(old + shift, new) for old, new in moved.items()]:
            for table in ("images", "keypoints", "descriptors"):
                con.execute(f"UPDATE {table} SET image_id = ? WHERE image_id = ?", (target, source))
        con.execute("DELETE FROM frame_data")
        con.execute("DELETE FROM frames")
        for frame, image, sensor, sensor_type in frame_data:
            own = moved.get(image, image)
            con.execute("INSERT INTO frames (frame_id, rig_id) VALUES (?, ?)", (own, rig_of_frame[frame]))
            con.execute("INSERT INTO frame_data VALUES (?, ?, ?, ?)", (own, own, sensor, sensor_type))


def _pinhole_params(K: list, sx: float, sy: float) -> list[float]:
    """(fx, fy, cx, cy) of a source-pixel K in the downscaled pixels (corner at 0: a plain multiply)."""
    return [K[0][0] * sx, K[1][1] * sy, K[0][2] * sx, K[1][2] * sy]


def run_refine(job: dict) -> None:
    """Triangulate matches with the given poses and intrinsics (held fixed) and write the tracks.

    The triangulation accepts rays `loose_angle_deg` off (the given poses may be off by that much);
    the parent's bundle adjustment (`adjust.py`, which keeps the given trajectory's gauge) then fits
    rotations, focal lengths and points to these tracks and drops the wrong ones. The pose check runs
    this same job and reads only the mean reprojection error of the given poses.
    """
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    pycolmap.logging.minloglevel = 0
    pycolmap.logging.logtostderr = True
    pycolmap.set_random_seed(REFINE_RANDOM_SEED)  # the triangulation's RANSAC
    work = Path(job["work_dir"])
    image_dir = work / "images"
    db_path = work / "database.db"
    if db_path.exists():
        db_path.unlink()
    peak_threshold = None
    if job.get("features_from") and Path(job["features_from"]).is_file():
        # The pose check's features (same photos, same names and size): COLMAP skips the photos the
        # database has, and the pairs it matched already; the photos it lacks are extracted alike.
        shutil.copyfile(job["features_from"], db_path)
        peak_threshold = _features_settings(Path(job["features_from"])).get("peak_threshold")
    timings: dict[str, float] = {}
    start = time.perf_counter()
    sizes, sx, sy = downscale_images(job, image_dir)
    timings["prepare"] = time.perf_counter() - start
    names = [item["name"] for item in job["images"]]
    params = [_pinhole_params(K, sx, sy) for K in job["K_per_image"]]
    shared = all(np.allclose(p, params[0]) for p in params)

    start = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = ",".join(repr(float(v)) for v in params[0])
    with pycolmap.Database.open(str(db_path)) as db:
        have = {im.name for im in db.read_all_images() if db.exists_keypoints(im.image_id)}
    missing = [name for name in names if name not in have]
    mode = (pycolmap.CameraMode.SINGLE if shared else pycolmap.CameraMode.PER_IMAGE, reader)
    low_contrast = None
    if missing:
        extract_features(job, db_path, image_dir, missing, mode, peak_threshold=peak_threshold)
        typical = median_keypoints(db_path)
        if peak_threshold is None and typical < LOW_CONTRAST_KEYPOINTS:
            # As for SfM: dim or plain-walled photos keep too few features at SIFT's default contrast
            # threshold. Measured on a realistic rendered room at 320 x 240 (room_05001, tracker poses):
            # median 222 -> 785 features per photo, 28 -> 30 of 40 frames refined.
            db_path.unlink()
            peak_threshold = LOW_CONTRAST_PEAK_THRESHOLD
            extract_features(job, db_path, image_dir, names, mode, peak_threshold=peak_threshold)
            low_contrast = {"before": typical, "after": median_keypoints(db_path)}
    number_unmatched_images_by_name(db_path)
    _features_path(db_path).write_text(json.dumps({"peak_threshold": peak_threshold}))
    timings["extract"] = time.perf_counter() - start

    start = time.perf_counter()
    pairs_path = work / "pairs.txt"
    pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in job["pairs"]))
    say("stage", "match", len(job["pairs"]))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = int(job["num_threads"])
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = pairs_path
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = REFINE_RANDOM_SEED
    pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=pairing,
                               verification_options=verification, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - start
    say("progress", "match", len(job["pairs"]), len(job["pairs"]))
    stats = database_stats(db_path)
    stats["low_contrast"] = low_contrast

    start = time.perf_counter()
    say("stage", "triangulate", 1)
    index_of = {name: i for i, name in enumerate(names)}
    reconstruction = pycolmap.Reconstruction()
    with pycolmap.Database.open(str(db_path)) as db:
        db_images = db.read_all_images()
        image_of_camera = {im.camera_id: index_of[im.name] for im in db_images}
        for camera in db.read_all_cameras():
            # One camera per image when the intrinsics differ: each gets its own.
            camera.params = params[image_of_camera[camera.camera_id]]
            reconstruction.add_camera_with_trivial_rig(camera)
        for db_image in db_images:
            keypoints = np.asarray(db.read_keypoints(db_image.image_id))[:, :2].astype(np.float64)
            image = pycolmap.Image(name=db_image.name, keypoints=keypoints, camera_id=db_image.camera_id,
                                   image_id=db_image.image_id)
            pose = np.asarray(job["cam_from_world"][index_of[db_image.name]], dtype=np.float64)
            reconstruction.add_image_with_trivial_frame(
                image, pycolmap.Rigid3d(pycolmap.Rotation3d(pose[:, :3]), pose[:, 3]))
    focal = float(np.median([0.5 * (p[0] + p[1]) for p in params]))
    reconstruction = _triangulate(reconstruction, db_path, image_dir, work / "triangulated",
                                  float(job["loose_angle_deg"]), focal, bool(job.get("loose_filter", False)))
    timings["triangulate"] = time.perf_counter() - start
    say("progress", "triangulate", 1, 1)
    _write_tracks(work, reconstruction, index_of, stats, timings, sx, sy, db_path)


def _features_path(db_path: Path) -> Path:
    """The side file saying how a refine job's database was extracted ({"peak_threshold": null | float})."""
    return db_path.with_name(db_path.stem + "_features.json")


def _features_settings(db_path: Path) -> dict:
    try:
        return json.loads(_features_path(db_path).read_text())
    except (OSError, ValueError):
        return {}


def _triangulate(reconstruction, db_path: Path, image_dir: Path, out: Path, loose_angle_deg: float, focal: float,
                 loose_filter: bool = False):
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    options = pycolmap.IncrementalPipelineOptions()
    triangulation = options.triangulation
    triangulation.create_max_angle_error = max(2.0, loose_angle_deg)
    triangulation.continue_max_angle_error = max(2.0, loose_angle_deg)
    pixels = max(4.0, focal * float(np.tan(np.radians(loose_angle_deg))))
    triangulation.merge_max_reproj_error = pixels
    triangulation.complete_max_reproj_error = pixels
    # The fixed-pose bundle adjustment inside triangulate_points drops observations beyond the mapper's
    # filter (4 px by default) after each round. Poses 1.5 deg off at a 280 px focal reproject a track
    # of three or more views 5-10 px off, so at 4 px most such tracks are dropped before our own
    # adjustment can turn the cameras (room_05001 at 320 x 240: 10 of 40 frames refined; with the
    # filter at the same tolerance, 28). `loose_filter` (RefineOptions) does that; it is off because
    # on the real SUN3D room the extra tracks made the result worse.
    if loose_filter:
        options.mapper.filter_max_reproj_error = pixels
    out.mkdir(parents=True, exist_ok=True)
    return pycolmap.triangulate_points(reconstruction, db_path, image_dir, out, clear_points=True, options=options)


def _write_tracks(work: Path, reconstruction, index_of: dict[str, int], stats: dict, timings: dict,
                  sx: float, sy: float, db_path: Path) -> None:
    """points.npz: xyz, rgb, error per point, and the observations (obs_image: job image index,
    obs_point: row in xyz, obs_uv: COLMAP's keypoint position in the downscaled photo, the frame of
    the scaled K COLMAP triangulated with, obs_keypoint: its keypoint's index in that photo); every
    photo's keypoints (keypoints_uv, photo i's rows keypoints_start[i]:keypoints_start[i + 1]) and the
    geometrically verified matches (match_image (M, 2) job image indices, match_keypoint (M, 2)), which
    let the parent pose a photo the triangulation left out from the points its neighbours see;
    result.json: counts, the given poses' mean error, timings."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    images = []
    for image_id in sorted(reconstruction.reg_image_ids()):
        image = reconstruction.images[image_id]
        images.append({"name": image.name, "num_points3D": int(image.num_points3D)})
    point_ids = sorted(reconstruction.points3D)
    row_of = {pid: row for row, pid in enumerate(point_ids)}
    xyz = np.array([reconstruction.points3D[p].xyz for p in point_ids], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([reconstruction.points3D[p].color for p in point_ids], dtype=np.uint8).reshape(-1, 3)
    error = np.array([reconstruction.points3D[p].error for p in point_ids], dtype=np.float64)
    obs_image, obs_point, obs_uv, obs_keypoint = [], [], [], []
    for pid in point_ids:
        for element in reconstruction.points3D[pid].track.elements:
            image = reconstruction.images[element.image_id]
            obs_image.append(index_of[image.name])
            obs_point.append(row_of[pid])
            obs_uv.append(image.points2D[element.point2D_idx].xy)
            obs_keypoint.append(element.point2D_idx)
    keypoints = [np.zeros((0, 2))] * len(index_of)
    match_image, match_keypoint = [np.zeros((0, 2), dtype=np.int64)], [np.zeros((0, 2), dtype=np.int64)]
    with pycolmap.Database.open(str(db_path)) as db:
        job_index = {im.image_id: index_of[im.name] for im in db.read_all_images() if im.name in index_of}
        for image_id, i in job_index.items():
            keypoints[i] = np.asarray(db.read_keypoints(image_id))[:, :2].astype(np.float64).reshape(-1, 2)
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries):
            first, second = pycolmap.pair_id_to_image_pair(pair_id)
            inliers = np.asarray(geometry.inlier_matches, dtype=np.int64).reshape(-1, 2)
            if first in job_index and second in job_index and len(inliers):
                match_image.append(np.tile([job_index[first], job_index[second]], (len(inliers), 1)))
                match_keypoint.append(inliers)
    np.savez(work / "points.npz", xyz=xyz, rgb=rgb, error=error,
             obs_image=np.asarray(obs_image, dtype=np.int64),
             obs_point=np.asarray(obs_point, dtype=np.int64),
             obs_uv=np.asarray(obs_uv, dtype=np.float64).reshape(-1, 2),
             obs_keypoint=np.asarray(obs_keypoint, dtype=np.int64),
             keypoints_uv=np.concatenate(keypoints).reshape(-1, 2),
             keypoints_start=np.cumsum([0] + [len(k) for k in keypoints]).astype(np.int64),
             match_image=np.concatenate(match_image), match_keypoint=np.concatenate(match_keypoint))
    result = {
        "images": images,
        "mean_reprojection_error": float(reconstruction.compute_mean_reprojection_error()) if point_ids else None,
        "num_points3D": len(point_ids),
        "scale": [sx, sy],
        "database": stats,
        "timings": timings,
    }
    (work / "result.json").write_text(json.dumps(result))
