"""The steps both jobs of the COLMAP worker share (`sfm_worker.py`): its protocol line, the downscaled
photos, SIFT features (extracted again at a lower contrast threshold on dim or plain photos) and
the database's counts.

Like the worker, it imports nothing from the engine, only pycolmap, OpenCV, numpy and the standard
library: the worker process loads it by name from this folder (see `sfm_worker.py`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

# Below this median of SIFT features per photo (dim, blurred or plain-walled rooms) the features are
# extracted again at a third of COLMAP's contrast threshold (its default is 0.02 / 3). Measured on a
# dim, plain-walled rendered room at 320x240: 244 -> 764 features per photo, 2 -> 18 of 40 photos
# registered; the bundled demo room (775 per photo) never gets here.
LOW_CONTRAST_KEYPOINTS = 500
LOW_CONTRAST_PEAK_THRESHOLD = 0.002


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


def median_keypoints(db_path: Path) -> float:
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


def extract_features(job: dict, db_path: Path, image_dir: Path, names: list[str], reader,
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
