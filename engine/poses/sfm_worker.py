"""Structure from motion with pycolmap, run as a separate process: `python sfm_worker.py JOB.json`.

Why a script of its own: a failed glog CHECK inside COLMAP calls abort() and takes down the whole
process (platform-notes section 1), which must never be Blender. It is started by file path, not
as a module, because inside Blender the engine lives under `bl_ext.<repo>.vortx` and a fresh
interpreter cannot import that; so this file imports nothing from the engine, only pycolmap,
OpenCV, numpy, the standard library and its two siblings, which do the same: the steps both jobs
share (`sfm_worker_steps.py`: the protocol line, downscaled photos, SIFT features, the database's
counts) and the refinement's job (`sfm_worker_refine.py`). Run by path, this folder is sys.path[0],
so it imports them by name; imported by the engine (the parent, the tests), as its package's.

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

A job with `"kind": "refine"` works from given poses instead: see `sfm_worker_refine.py`.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from pathlib import Path
from typing import Optional

import numpy as np

if __package__:  # imported as part of the engine (the parent reads its constants, the tests its steps)
    from .sfm_worker_learned import drop_unlike_far_pairs, learned_database
    from .sfm_worker_refine import run_refine
    from .sfm_worker_steps import (LOW_CONTRAST_PEAK_THRESHOLD, database_stats, downscale_images, extract_features,
                                   median_keypoints, say)
else:  # run by file path in the worker process, where this folder is sys.path[0]
    from sfm_worker_learned import drop_unlike_far_pairs, learned_database
    from sfm_worker_refine import run_refine
    from sfm_worker_steps import (LOW_CONTRAST_PEAK_THRESHOLD, database_stats, downscale_images, extract_features,
                                  median_keypoints, say)

# SfM poses every photo from its features alone, so it asks for more of them than the refinement
# (which starts from given poses): below this median it also extracts at the lower threshold. Small
# photos get here: the demo room's 320 x 240 photos keep 796 features each at the default threshold,
# and its first photos (which look at far walls over few matches) came out 0.15 deg off their
# neighbours on average, moving a wall 4-6 m away by 5-12 cm; at 0.002 (1,600 features each) 0.06 deg,
# baselines 0.8 -> 0.3 % off, centre error 0.19 -> 0.17 cm median, 8 -> 15 s (three runs each).
SFM_FEW_KEYPOINTS = 1200
MAPPING_ATTEMPTS = 3
# COLMAP's mapper drops observations more than 4 px from their point: a tolerance for photos of
# 1,000 px and more. On smaller photos it is that much looser in angle, and the model keeps matches a
# sharper filter would drop. Scaled with the photos' larger side (the SfM copy's), between 1 and 4 px.
# Measured on the demo room's 36 photos at 320 x 240 (mapping one database; pose error against the
# truth after a similarity): 4 px 0.43 cm / 0.083 deg median, 2 px 0.21 / 0.058, 1.25 px 0.17 / 0.04,
# focal 250.7 -> 251.0 px (true 251.15).
MAPPER_ERROR_PX_AT_1000 = 4.0
# With learned features the mapper's global bundle adjustment runs when the model has grown by this
# factor (COLMAP's default 1.1, kept for SIFT).
LEARNED_GLOBAL_BA_RATIO = 1.4
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

    reader = (pycolmap.CameraMode.SINGLE, reader_options(job, sx, sy))
    learned = job.get("features", "sift") == "learned"
    low_contrast, pairs_matched = None, None
    if learned:
        done = learned_database(job, db_path, image_dir, names, reader, say)
        timings.update({"extract": done["extract"], "match": done["match"], "verify": done["verify"]})
        pairs_matched = done["pairs"]
    else:
        low_contrast = _sift_database(job, work, db_path, image_dir, names, reader, timings)
    far_pairs_dropped = None
    if job["matcher"] == "sequential":  # pairs beyond the sequence: loops, or look-alike places
        drop_far = drop_unlike_far_pairs if learned else drop_weak_far_pairs
        far_pairs_dropped = drop_far(db_path, int(job["overlap"]))
    say("progress", "match", len(names), len(names))
    stats = database_stats(db_path)
    stats.update({"far_pairs_dropped": far_pairs_dropped, "low_contrast": low_contrast,
                  "features": "learned" if learned else "sift", "pairs_matched": pairs_matched})
    _map(job, work, db_path, image_dir, names, sizes, sx, sy, stats, timings, seed=None)


def _sift_database(job: dict, work: Path, db_path: Path, image_dir: Path, names: list[str], reader,
                   timings: dict) -> Optional[dict]:
    """SIFT features and COLMAP's matching (sequential with loop detection, or exhaustive) into the
    database at `db_path`; returns {"before", "after"} when low-contrast photos were extracted again."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    start = time.perf_counter()
    extract_features(job, db_path, image_dir, names, reader)
    low_contrast = None
    typical = median_keypoints(db_path)
    if typical < SFM_FEW_KEYPOINTS:
        # Dim, blurred, plain-walled or small photos: SIFT's default contrast threshold keeps too few
        # features to chain the views and pose them precisely; a third of it finds two to three times
        # as many on such photos and changes nothing on well-textured large ones (they never get here).
        db_path.unlink()
        extract_features(job, db_path, image_dir, names, reader, peak_threshold=LOW_CONTRAST_PEAK_THRESHOLD)
        low_contrast = {"before": typical, "after": median_keypoints(db_path)}
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
    else:
        pairing = pycolmap.ExhaustivePairingOptions()
        # Blocks of ~1/5 of the images (COLMAP logs one line per block) give the progress bar
        # steps instead of one jump; descriptors stay cached, so this costs little.
        pairing.block_size = max(10, -(-len(names) // 5))
        pycolmap.match_exhaustive(db_path, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - start
    return low_contrast


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
    if job.get("features", "sift") == "learned":
        # Learned features give 5-10 times SIFT's observations per photo (the corridor: 2,400), and
        # the global bundle adjustments after every 10 % of growth took most of the 594 s mapping.
        options.ba_global_frames_ratio = LEARNED_GLOBAL_BA_RATIO
        options.ba_global_points_ratio = LEARNED_GLOBAL_BA_RATIO
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
