"""Structure from motion with pycolmap, run as a separate process: `python sfm_worker.py JOB.json`.

Why a script of its own: a failed glog CHECK inside COLMAP calls abort() and takes down the whole
process (platform-notes section 1), which must never be Blender. It is started by file path, not
as a module, because inside Blender the engine lives under `bl_ext.<repo>.vortx` and a fresh
interpreter cannot import that; so this file imports nothing from the engine, only pycolmap,
OpenCV, numpy and the standard library.

Protocol (parsed by `process.py`): stdout and stderr are one stream. Lines starting with `@vortx `
are ours: `@vortx stage NAME TOTAL`, `@vortx progress NAME DONE TOTAL`, `@vortx error MESSAGE`,
`@vortx done`. Everything else is COLMAP's log, which the parent also reads for finer progress.

JOB.json (written by `sfm.py`):
  work_dir           folder for downscaled images, the database and the models
  images             [{"path": source image, "name": name for COLMAP}], in capture order
  max_side           downscale so that the larger image side is at most this (0: keep the size)
  matcher            "sequential" | "exhaustive"
  overlap            neighbours matched per image by the sequential matcher
  loop_detection     sequential matcher: also match photos of the same place far apart in the walk,
                     found with a vocabulary tree trained on the photos' own features (optional, false)
  camera_model       COLMAP model when intrinsics are not fixed ("SIMPLE_RADIAL", "SIMPLE_PINHOLE", ...)
  intrinsics         "estimate": from scratch; "prior": K (EXIF focal) is the starting guess of
                     camera_model, refined; "fixed": K is a calibration, PINHOLE held fixed in BA
  K                  null, or [[3x3]] in pixels of the source images (for "prior" and "fixed")
  max_num_features   SIFT features per image
  num_threads        -1 for all cores
  min_model_size     smallest sub-model COLMAP keeps
  remap_seed         optional: map the database an earlier job of this work_dir matched again, the mapper
                     seeded with this (the parent found that job's model bent); extraction and matching
                     are skipped

Result (work_dir/result.json and work_dir/points.npz): see `_write_result`. Its "database" entry says
whether low-contrast photos had their features extracted again ("low_contrast": {"before", "after"}
median features per photo, or null) and how many photos each mapping attempt posed ("mapping_attempts").

A job with `"kind": "refine"` (written by `refine.py` and the pose check in `quality.py`) works
from given poses instead of estimating new ones: SIFT features, matches between the listed image
pairs, one triangulation with the given poses and intrinsics (fixed); the parent adjusts (see
`run_refine`). Its extra fields:
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
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import sys
import time
import traceback
from pathlib import Path
from typing import Optional

import numpy as np

# Below this median of SIFT features per photo (dim, blurred or plain-walled rooms) the features are
# extracted again at a third of COLMAP's contrast threshold (its default is 0.02 / 3). Measured on a
# dim, plain-walled rendered room at 320x240: 244 -> 764 features per photo, 2 -> 18 of 40 photos
# registered; the bundled demo room (775 per photo) never gets here.
LOW_CONTRAST_KEYPOINTS = 500
LOW_CONTRAST_PEAK_THRESHOLD = 0.002
# SfM poses every photo from its features alone, so it asks for more of them than the refinement
# (which starts from given poses): below this median it also extracts at the lower threshold. Small
# photos get here: the demo room's 320 x 240 photos keep 796 features each at the default threshold,
# and its first photos (which look at far walls over few matches) came out 0.15 deg off their
# neighbours on average, moving a wall 4-6 m away by 5-12 cm; at 0.002 (1,600 features each) 0.06 deg,
# baselines 0.8 -> 0.3 % off, centre error 0.19 -> 0.17 cm median, 8 -> 15 s (three runs each).
SFM_FEW_KEYPOINTS = 1200
MAPPING_ATTEMPTS = 3
COLMAP_MAX_IMAGES = 2147483647  # COLMAP's pair id: image_id1 * this + image_id2
# The pose refinement is repeatable: its RANSACs (two-view verification, triangulation) seeded, and its
# images numbered by name (number_unmatched_images_by_name).
REFINE_RANDOM_SEED = 0
# COLMAP's mapper drops observations more than 4 px from their point: a tolerance for photos of
# 1,000 px and more. On smaller photos it is that much looser in angle, and the model keeps matches a
# sharper filter would drop. Scaled with the photos' larger side (the SfM copy's), between 1 and 4 px.
# Measured on the demo room's 36 photos at 320 x 240 (mapping one database; pose error against the
# truth after a similarity): 4 px 0.43 cm / 0.083 deg median, 2 px 0.21 / 0.058, 1.25 px 0.17 / 0.04,
# focal 250.7 -> 251.0 px (true 251.15).
MAPPER_ERROR_PX_AT_1000 = 4.0
MIN_MAPPER_ERROR_PX = 1.0


# Loop detection for sequential matching: COLMAP finds photos of the same place far apart in the walk
# through a vocabulary tree, which it would download (offline, it aborts). The tree is trained here on
# the capture's own SIFT descriptors instead, as COLMAP's vocab_tree_builder trains one: LOOP_TREE_WORDS
# visual words (at most, with LOOP_TREE_SAMPLES_PER_WORD descriptors each to train on), then every
# LOOP_PERIOD-th photo is matched with the LOOP_IMAGES photos most like it beyond its neighbours.
# Training time grows with words x samples: on the corridor's 174k descriptors (2 threads) 1024 words
# from 16k samples took 5 s, 2048 from 82k 105 s, 4096 from 164k 467 s; a walk of a few hundred photos
# needs only the coarse words to find its loops.
LOOP_TREE_WORDS = 1024
LOOP_TREE_SAMPLES_PER_WORD = 16
LOOP_PERIOD = 2
LOOP_IMAGES = 20
# A pair of photos far apart in the walk (beyond the sequential overlap: a loop, or COLMAP's quadratic
# gaps of 16, 32, ...) needs this many verified matches to count. Long corridors look alike: on the
# 3D Scanner App corridor, 63 of 353 such pairs joined the U's two legs, cameras 17-28 m apart looking
# opposite ways, with up to 46 inliers, and bent the model (85 deg mean rotation error); the true ones
# along one leg reach 60-80. Neighbours keep COLMAP's 15.
FAR_PAIR_MIN_INLIERS = 50


def own_vocabulary_tree(db_path: Path, tree_path: Path, num_threads: int) -> Optional[Path]:
    """Train a vocabulary tree on the SIFT descriptors in the database at `db_path` and write it to
    `tree_path` (returned); None when there are too few descriptors for a useful one."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    with pycolmap.Database.open(str(db_path)) as db:
        blocks = [np.asarray(db.read_descriptors(image.image_id).to_float().data, np.float32)
                  for image in db.read_all_images()]
    descriptors = np.concatenate([b for b in blocks if len(b)]) if any(len(b) for b in blocks) else np.zeros((0, 128), np.float32)
    words = min(LOOP_TREE_WORDS, len(descriptors) // LOOP_TREE_SAMPLES_PER_WORD)
    if words < 64:
        return None
    rng = np.random.default_rng(0)
    sample = descriptors[rng.choice(len(descriptors), min(len(descriptors), words * LOOP_TREE_SAMPLES_PER_WORD), replace=False)]
    index = pycolmap.VisualIndex.create(descriptors.shape[1], 64)
    build = pycolmap.VisualIndex.BuildOptions()
    build.num_visual_words = int(words)
    build.num_threads = int(num_threads)
    index.build(build, pycolmap.FeatureDescriptorsFloat(pycolmap.FeatureExtractorType.SIFT, np.ascontiguousarray(sample)))
    index.write(str(tree_path))
    return tree_path


def drop_weak_far_pairs(db_path: Path, overlap: int) -> int:
    """Forget the verified pairs of photos more than `overlap` apart in capture order that have fewer
    than FAR_PAIR_MIN_INLIERS inliers (COLMAP names are the capture indices); returns how many."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    dropped = 0
    with pycolmap.Database.open(str(db_path)) as db:
        index = {image.image_id: int(Path(image.name).stem) for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        for pair_id, count in zip(pair_ids, inliers):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            if 0 < count < FAR_PAIR_MIN_INLIERS and abs(index[a] - index[b]) > overlap:
                db.delete_inlier_matches(a, b)
                dropped += 1
    return dropped


def mapper_max_error_px(larger_side: int) -> float:
    """The mapper's reprojection-error filter (pixels) for photos whose larger side is `larger_side` px."""
    return float(np.clip(MAPPER_ERROR_PX_AT_1000 * larger_side / 1000.0, MIN_MAPPER_ERROR_PX, MAPPER_ERROR_PX_AT_1000))


def say(*parts: object) -> None:
    print("@vortx", *parts, flush=True)


def downscale_images(job: dict, image_dir: Path) -> tuple[list[dict], float, float]:
    """Write a copy of each image with its larger side at most max_side.

    Returns per image {"name", "width", "height"} of the *source* image (after EXIF orientation,
    which cv2.imread applies, as the engine's K contract assumes) and the per-axis scale factors
    (scaled / source). Mixed resolutions are refused: one shared camera needs one image size.
    """
    import cv2  # defers cv2 (OpenCV) off the light paths

    image_dir.mkdir(parents=True, exist_ok=True)
    images = job["images"]
    max_side = int(job["max_side"])
    sizes: list[dict] = []
    scale_xy: tuple[float, float] | None = None
    say("stage", "prepare", len(images))
    for i, item in enumerate(images):
        # imdecode on the bytes, not imread: imread cannot open non-ASCII paths on Windows.
        # IMREAD_COLOR applies the EXIF orientation, as the engine's load_image does.
        data = np.fromfile(item["path"], dtype=np.uint8) if Path(item["path"]).is_file() else None
        image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data is not None and data.size else None
        if image is None:
            raise RuntimeError(f"cannot read image {item['path']} (missing, or not an image OpenCV can decode)")
        height, width = image.shape[:2]
        if sizes and (width, height) != (sizes[0]["width"], sizes[0]["height"]):
            raise RuntimeError(
                f"image {item['path']} is {width}x{height} but {images[0]['path']} is "
                f"{sizes[0]['width']}x{sizes[0]['height']}; all photos of a capture need the same size"
            )
        sizes.append({"name": item["name"], "width": width, "height": height})
        factor = min(1.0, max_side / max(width, height)) if max_side > 0 else 1.0
        new_w, new_h = max(1, round(width * factor)), max(1, round(height * factor))
        if (new_w, new_h) != (width, height):
            image = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA)
        ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        if not ok:
            raise RuntimeError(f"cannot encode the downscaled copy of {item['path']}")
        encoded.tofile(str(image_dir / item["name"]))
        scale_xy = (new_w / width, new_h / height)
        say("progress", "prepare", i + 1, len(images))
    assert scale_xy is not None
    return sizes, scale_xy[0], scale_xy[1]


def reader_options(job: dict, sx: float, sy: float):
    """Camera model and (for "prior"/"fixed") its starting parameters in the downscaled pixels."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    options = pycolmap.ImageReaderOptions()
    mode, model = job["intrinsics"], job["camera_model"]
    if mode == "estimate":
        options.camera_model = model
        return options
    K = job["K"]
    # COLMAP's pixel convention has the image corner at 0, so scaling is a plain multiply.
    fx, fy, cx, cy = K[0][0] * sx, K[1][1] * sy, K[0][2] * sx, K[1][2] * sy
    if mode == "fixed" or model == "PINHOLE":
        options.camera_model = "PINHOLE"
        params = [fx, fy, cx, cy]
    else:
        # One-focal models; COLMAP marks the focal as a prior and bundle adjustment refines it.
        options.camera_model = model
        extra = {"SIMPLE_PINHOLE": 0, "SIMPLE_RADIAL": 1, "RADIAL": 2}[model]
        params = [0.5 * (fx + fy), cx, cy] + [0.0] * extra
    options.camera_params = ",".join(repr(float(v)) for v in params)
    return options


def _median_keypoints(db_path: Path) -> float:
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    with pycolmap.Database.open(str(db_path)) as db:
        counts = [db.num_keypoints_for_image(im.image_id) for im in db.read_all_images()]
    return float(np.median(counts)) if counts else 0.0


def database_stats(db_path: Path) -> dict:
    """Keypoints per image and verified pairs: what the user needs to hear when nothing registers."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    with pycolmap.Database.open(str(db_path)) as db:
        num_images = db.num_images()
        keypoints = [db.num_keypoints_for_image(im.image_id) for im in db.read_all_images()]
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
    return {
        "num_images": int(num_images),
        "mean_keypoints": float(sum(keypoints) / len(keypoints)) if keypoints else 0.0,
        # 15 inliers is COLMAP's own threshold for a geometrically verified pair.
        "verified_pairs": int(sum(1 for n in inliers if n >= 15)),
    }


def run_sfm(job: dict) -> None:
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    # INFO lines carry the per-image progress the parent parses; they go to this process's stderr.
    pycolmap.logging.minloglevel = 0
    pycolmap.logging.logtostderr = True

    work = Path(job["work_dir"])
    image_dir = work / "images"
    db_path = work / "database.db"
    sparse_dir = work / "sparse"
    sparse_dir.mkdir(parents=True, exist_ok=True)
    names = [item["name"] for item in job["images"]]
    if job.get("remap_seed") is not None:
        # The parent found the model bent: map the same matches again, the mapper seeded otherwise.
        previous = json.loads((work / "result.json").read_text())
        width, height = previous["source_size"]
        _map(job, work, db_path, image_dir, names, [{"width": width, "height": height}], *previous["scale_xy"],
             previous["database"], {}, seed=int(job["remap_seed"]))
        return
    if db_path.exists():
        db_path.unlink()
    timings: dict[str, float] = {}

    start = time.perf_counter()
    sizes, sx, sy = downscale_images(job, image_dir)
    timings["prepare"] = time.perf_counter() - start

    start = time.perf_counter()
    reader = (pycolmap.CameraMode.SINGLE, reader_options(job, sx, sy))
    _extract(job, db_path, image_dir, names, reader)
    low_contrast = None
    typical = _median_keypoints(db_path)
    if typical < SFM_FEW_KEYPOINTS:
        # Dim, blurred, plain-walled or small photos: SIFT's default contrast threshold keeps too few
        # features to chain the views and pose them precisely; a third of it finds two to three times
        # as many on such photos and changes nothing on well-textured large ones (they never get here).
        db_path.unlink()
        _extract(job, db_path, image_dir, names, reader, peak_threshold=LOW_CONTRAST_PEAK_THRESHOLD)
        low_contrast = {"before": typical, "after": _median_keypoints(db_path)}
    timings["extract"] = time.perf_counter() - start

    start = time.perf_counter()
    say("stage", "match", len(names))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = int(job["num_threads"])
    if job["matcher"] == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = int(job["overlap"])
        tree = own_vocabulary_tree(db_path, work / "vocabulary_tree.bin", int(job["num_threads"])) if job.get("loop_detection") else None
        pairing.loop_detection = tree is not None
        if tree is not None:
            pairing.vocab_tree_path = str(tree)
            pairing.loop_detection_period = LOOP_PERIOD
            pairing.loop_detection_num_images = LOOP_IMAGES
        timings["vocabulary_tree"] = time.perf_counter() - start
        pycolmap.match_sequential(db_path, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
        far_pairs_dropped = drop_weak_far_pairs(db_path, int(job["overlap"]))
    else:
        pairing = pycolmap.ExhaustivePairingOptions()
        # Blocks of ~1/5 of the images (COLMAP logs one line per block) give the progress bar
        # steps instead of one jump; descriptors stay cached, so this costs little.
        pairing.block_size = max(10, -(-len(names) // 5))
        pycolmap.match_exhaustive(db_path, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - start
    say("progress", "match", len(names), len(names))
    stats = database_stats(db_path)
    if job["matcher"] == "sequential":
        stats["far_pairs_dropped"] = far_pairs_dropped
    stats["low_contrast"] = low_contrast
    _map(job, work, db_path, image_dir, names, sizes, sx, sy, stats, timings, seed=None)


def _map(job: dict, work: Path, db_path: Path, image_dir: Path, names: list[str], sizes: list[dict], sx: float,
         sy: float, stats: dict, timings: dict, seed: Optional[int]) -> None:
    """COLMAP's incremental mapper on the matched database (`seed`: the mapper's random seed, None for
    COLMAP's own), then `_write_result`."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    sparse_dir = work / "sparse"
    start = time.perf_counter()
    say("stage", "map", len(names))
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = int(job["num_threads"])
    options.min_model_size = int(job["min_model_size"])
    scaled_side = round(max(sizes[0]["width"] * sx, sizes[0]["height"] * sy))
    options.mapper.filter_max_reproj_error = mapper_max_error_px(scaled_side)
    stats["mapper_max_error_px"] = options.mapper.filter_max_reproj_error
    if job["intrinsics"] == "fixed":
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
    # The mapper is randomised (RANSAC): on weakly matched photos one run poses 3 of 40, the next 11.
    # While fewer than half are posed it runs again, up to MAPPING_ATTEMPTS times; the run that posed
    # the most photos is kept.
    attempts: list[int] = []
    models: dict = {}
    while len(attempts) < MAPPING_ATTEMPTS:
        attempt_dir = sparse_dir / f"attempt_{len(attempts)}" if seed is None else sparse_dir / f"seed_{seed}_{len(attempts)}"
        attempt_dir.mkdir(parents=True, exist_ok=True)
        if seed is not None:
            options.random_seed = seed * MAPPING_ATTEMPTS + len(attempts)
        found = pycolmap.incremental_mapping(db_path, image_dir, attempt_dir, options=options)
        attempts.append(max((r.num_reg_images() for r in found.values()), default=0))
        if attempts[-1] >= max((r.num_reg_images() for r in models.values()), default=0) and found:
            models = found
        if max(attempts) * 2 >= len(names):
            break
    timings["map"] = time.perf_counter() - start
    registered = max(attempts)
    say("progress", "map", registered, len(names))

    stats["mapping_attempts"] = attempts
    _write_result(work, models, sizes, sx, sy, stats, timings, {name: i for i, name in enumerate(names)}, db_path)


def _group_links(db_path: Path, ordered: list) -> list[list]:
    """[[name a, name b, inliers], ...]: the verified photo pairs whose photos are in different models
    (`ordered`, largest first), strongest first: what held the groups together, as little as it was."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    model_of = {r.images[i].name: m for m, r in enumerate(ordered) for i in r.reg_image_ids()}
    links = []
    with pycolmap.Database.open(str(db_path)) as db:
        name = {image.image_id: image.name for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        for pair_id, count in zip(pair_ids, inliers):
            a, b = (name[i] for i in pycolmap.pair_id_to_image_pair(pair_id))
            if count > 0 and a in model_of and b in model_of and model_of[a] != model_of[b]:
                links.append([a, b, int(count)])
    return sorted(links, key=lambda link: -link[2])


def _write_result(work: Path, models: dict, sizes: list[dict], sx: float, sy: float, stats: dict, timings: dict,
                  index_of: dict[str, int], db_path: Optional[Path] = None) -> None:
    """result.json: {"source_size": [w, h], "scaled_size": [w, h], "model_sizes": [...] (largest first),
    "camera": {"model", "params", "width", "height"} | null, "images": [{"name", "cam_from_world" 3x4}],
    "mean_reprojection_error", "num_points3D", "database": stats, "timings"};
    points.npz: xyz (N, 3) float64, rgb (N, 3) uint8, error (N,) float64 of the largest model, and its
    observations (obs_image: job image index (`index_of` a COLMAP name), obs_point: row in xyz, obs_uv:
    the keypoint in the downscaled photo), so the parent can drop the points of photos it leaves out.
    With more than one model (and `db_path`): "model_images", each model's photo names (largest first),
    and "group_links" (`_group_links`), so the report can say where the photos split and what linked them."""
    ordered = sorted(models.values(), key=lambda r: r.num_reg_images(), reverse=True)
    result: dict = {
        "source_size": [sizes[0]["width"], sizes[0]["height"]],
        "scale_xy": [sx, sy],
        "model_sizes": [int(r.num_reg_images()) for r in ordered],
        "camera": None,
        "images": [],
        "mean_reprojection_error": None,
        "num_points3D": 0,
        "database": stats,
        "timings": timings,
    }
    if len(ordered) > 1 and db_path is not None:
        result["model_images"] = [sorted(r.images[i].name for i in r.reg_image_ids()) for r in ordered]
        result["group_links"] = _group_links(db_path, ordered)
    xyz = np.zeros((0, 3))
    rgb = np.zeros((0, 3), dtype=np.uint8)
    error = np.zeros((0,))
    obs_image, obs_point, obs_uv = [], [], []
    if ordered:
        best = ordered[0]
        camera_ids = {best.images[i].camera_id for i in best.reg_image_ids()}
        camera = best.cameras[sorted(camera_ids)[0]]
        result["camera"] = {
            "model": camera.model_name,
            "params": [float(v) for v in camera.params],
            "width": int(camera.width),
            "height": int(camera.height),
        }
        for image_id in sorted(best.reg_image_ids()):
            image = best.images[image_id]
            result["images"].append(
                {"name": image.name, "cam_from_world": np.asarray(image.cam_from_world().matrix()).tolist()}
            )
        result["mean_reprojection_error"] = float(best.compute_mean_reprojection_error())
        result["num_points3D"] = int(best.num_points3D())
        points = list(best.points3D.values())
        if points:
            xyz = np.array([p.xyz for p in points], dtype=np.float64)
            rgb = np.array([p.color for p in points], dtype=np.uint8)
            error = np.array([p.error for p in points], dtype=np.float64)
        for row, point in enumerate(points):
            for element in point.track.elements:
                image = best.images[element.image_id]
                obs_image.append(index_of[image.name])
                obs_point.append(row)
                obs_uv.append(image.points2D[element.point2D_idx].xy)
    np.savez(work / "points.npz", xyz=xyz, rgb=rgb, error=error, obs_image=np.asarray(obs_image, dtype=np.int64),
             obs_point=np.asarray(obs_point, dtype=np.int64), obs_uv=np.asarray(obs_uv, dtype=np.float64).reshape(-1, 2))
    (work / "result.json").write_text(json.dumps(result))


def _extract(job: dict, db_path: Path, image_dir: Path, names: list[str], reader,
             peak_threshold: Optional[float] = None) -> None:
    """SIFT features of `names` into the database; `peak_threshold` replaces COLMAP's contrast threshold."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = int(job["num_threads"])
    extraction.sift.max_num_features = int(job["max_num_features"])
    if peak_threshold is not None:
        extraction.sift.peak_threshold = float(peak_threshold)
    say("stage", "extract", len(names))
    pycolmap.extract_features(
        db_path,
        image_dir,
        image_names=names,
        camera_mode=reader[0],
        reader_options=reader[1],
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    say("progress", "extract", len(names), len(names))


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
        _extract(job, db_path, image_dir, missing, mode, peak_threshold=peak_threshold)
        typical = _median_keypoints(db_path)
        if peak_threshold is None and typical < LOW_CONTRAST_KEYPOINTS:
            # As for SfM: dim or plain-walled photos keep too few features at SIFT's default contrast
            # threshold. Measured on a realistic rendered room at 320 x 240 (room_05001, tracker poses):
            # median 222 -> 785 features per photo, 28 -> 30 of 40 frames refined.
            db_path.unlink()
            peak_threshold = LOW_CONTRAST_PEAK_THRESHOLD
            _extract(job, db_path, image_dir, names, mode, peak_threshold=peak_threshold)
            low_contrast = {"before": typical, "after": _median_keypoints(db_path)}
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


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: sfm_worker.py JOB.json", file=sys.stderr)
        return 2
    try:
        job = json.loads(Path(argv[1]).read_text())
        if job.get("kind", "sfm") == "refine":
            run_refine(job)
        else:
            run_sfm(job)
    except Exception as error:  # reported to the parent, which turns it into a PoseError
        traceback.print_exc()
        say("error", " ".join(str(error).split()) or type(error).__name__)
        return 1
    say("done")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
