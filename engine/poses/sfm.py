"""Camera poses for a capture without them: pycolmap SfM in a subprocess, then gravity and scale.

Choices (measured in platform-notes section 1 and on the fox photos):
- SIFT on the CPU and one shared camera (`CameraMode.SINGLE`): a capture is one phone or one video.
- Photos are downscaled (larger side `max_side`, default 1024) before SfM: at 800 px the fox set
  registers fully with sub-degree rotation error, and features/matching get ~4x cheaper than at
  full size. K is scaled back to the full-size photos afterwards.
- Matching: exhaustive for small unordered photo sets (robust, O(n^2) pairs); sequential with
  `sequential_overlap` neighbours for video frames and sets larger than `sequential_above`
  (O(n) pairs), plus loop detection: photos of the same place far apart in the walk are matched
  too, found with a vocabulary tree trained on the capture's own features (COLMAP would download
  one, and offline it aborts; `sfm_worker.own_vocabulary_tree`). A pair far apart in the walk counts
  only with `sfm_worker.FAR_PAIR_MIN_INLIERS` verified matches: look-alike corridors match falsely.
- Intrinsics: when every frame has the same calibrated K (COLMAP, transforms.json, ScanNet
  captures), PINHOLE held fixed in bundle adjustment. Otherwise SIMPLE_RADIAL is estimated
  (COLMAP's default: modelling the lens's mild barrel distortion keeps bundle adjustment from
  bending the trajectory to absorb it), starting from the EXIF focal length when the photo folder
  loader found one. The reconstruction needs a pinhole camera: it gets (f, f, cx, cy), and the
  radial term is either negligible (it moves the image corners by less than 0.5 % of the image
  size: dropped) or the photos are undistorted into the capture's cache (`undistort=True`).
- A model that bends (a stretch of photos whose own vertical lines lean from the rest: `bends.py`)
  is cut there: the longest straight stretch of the walk is kept, the rest left unposed, and the
  report says which photos and why. A walk's photo posed with none of its neighbours (a loop match
  to a look-alike place) is left out too.
- The whole SfM runs in a child process (`sfm_worker.py`): a COLMAP CHECK failure aborts the
  process it runs in, and that must not be Blender.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture.model import Capture, Frame
from ..capture.naming import name_list
from ..capture.undistort import undistort_images
from ..errors import PoseError
from ..jobs import CancelToken, ProgressCallback, check
from .adjust import cam_to_world_of
from .bends import Bend, find_bend
from .camera_height import DEFAULT_CAMERA_HEIGHT_M
from .gravity import Alignment, KnownDistance, align_gravity_and_scale
from .process import run_pose_job
from .sfm_worker_learned import missing_packages as learned_missing_packages
from .quality import distinct_groups, min_group_size, quality_warnings, radial_corner_shift, significant_distortion

MATCHERS = ("auto", "sequential", "exhaustive")
# The features structure from motion matches: COLMAP's SIFT, or XFeat's learned keypoints and
# descriptors with learned matching and pairs by retrieval (`sfm_worker_learned.py`).
FEATURES = ("sift", "learned")
FEATURE_NAMES = {"sift": "SIFT features", "learned": "learned features (XFeat)"}  # as reports name them
FEATURES_HELP = ("features structure from motion matches: 'sift' (COLMAP's SIFT) or 'learned' (XFeat keypoints, "
                 "learned matching, pairs by retrieval: more matches on blurred, fast-turning or plain photos)")


def add_features_argument(parser: argparse.ArgumentParser) -> None:
    """--features, for every command that estimates poses (`engine poses`, `engine reconstruct`, the batch)."""
    parser.add_argument("--features", choices=FEATURES, default=SfmOptions.features,
                        help=f"{FEATURES_HELP} (default %(default)s)")


def missing_learned_packages() -> list[str]:
    """The packages the learned features need that are not installed (pip names; empty when all are)."""
    return learned_missing_packages()


def check_features(features: str) -> None:
    """Refuse an unknown Features setting, or learned features without their packages (with what to do)."""
    if features not in FEATURES:
        raise PoseError(f"unknown features {features!r}; use one of {', '.join(FEATURES)}")
    missing = missing_learned_packages() if features == "learned" else []
    if missing:
        raise PoseError(
            f"learned features need the Python packages {', '.join(missing)}, which are not installed: run `make venv` "
            f"(or pip install -r requirements.txt -c constraints.txt), or in Blender Preferences > Add-ons > VoRTX "
            f"Install Missing Packages; or estimate poses with SIFT (--features sift, Features: SIFT in Blender)")
INTRINSICS = ("auto", "fixed", "prior", "estimate")
# Formats whose K comes from a calibration or an earlier SfM; a photo folder's or video's K is an
# EXIF guess (or absent) and only a starting point.
CALIBRATED_FORMATS = ("colmap", "transforms", "scannet")
# COLMAP models whose parameters start with a pinhole part we can hand to the reconstruction.
CAMERA_MODELS = ("SIMPLE_RADIAL", "RADIAL", "SIMPLE_PINHOLE", "PINHOLE")
# How often a bent model is mapped again before the best of them is cut. On one database of the 3D
# Scanner App corridor 2 of 11 mapper runs came out straight (4 of 6 fresh SfM runs did); each run
# there takes 25-50 s.
BENT_REMAPS = 2


@dataclass
class SfmOptions:
    matcher: str = "auto"  # "auto" | "sequential" | "exhaustive"
    max_side: int = 1024  # downscale photos so their larger side is at most this for SfM; 0 = full size
    sequential_overlap: int = 10  # neighbours each frame is matched with by the sequential matcher
    sequential_above: int = 60  # "auto" matches sequentially when there are more frames than this
    loop_detection: bool = True  # sequential matching also matches far-apart photos of one place
    intrinsics: str = "auto"  # "fixed" | "prior" (refine the given K) | "estimate" (ignore it) | "auto"
    camera_model: str = "SIMPLE_RADIAL"  # model estimated when intrinsics are not fixed
    undistort: bool = True  # undistort the photos (into the cache) when the lens distortion is significant
    cache_dir: Optional[Path] = None  # where undistorted photos go (default: see engine.capture.cache)
    max_num_features: int = 8192  # SIFT features per photo
    features: str = "sift"  # one of FEATURES
    learned_matcher: str = "mnn"  # learned features: "mnn" (mutual nearest neighbours) | "lighterglue"
    num_threads: int = -1  # -1: all cores
    align: bool = True  # gravity (+Z up), floor at z = 0 and metric scale after SfM
    camera_height: float = DEFAULT_CAMERA_HEIGHT_M  # metres above the floor, for the scale when no known distance is given
    known_distance: Optional[KnownDistance] = None
    work_dir: Optional[Path] = None  # keep the worker's files (database, models, log) here; default: temp, deleted


@dataclass
class PoseResult:
    capture: Capture  # all frames in their order; registered ones posed, all with K of the full-size photos
    registered: list[str]  # frame names
    unregistered: list[str]
    model_sizes: list[int]  # registered photos per model, largest (the one used) first
    matcher: str
    camera_model: str  # as estimated ("PINHOLE" when K was fixed)
    K: np.ndarray  # (3, 3) pinhole intrinsics in pixels of the full-size photos
    radial_distortion: list[float]  # COLMAP k1[, k2] in the downscaled photos' normalised coordinates
    mean_reprojection_error: float  # pixels of the downscaled photos
    points: np.ndarray  # (N, 3) float64 sparse points in the (aligned) world
    point_colors: np.ndarray  # (N, 3) uint8 RGB
    scaled_size: tuple[int, int]  # (width, height) of the photos SfM ran on
    alignment: Optional[Alignment]  # None when options.align is False
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what was done that is no problem (undistortion)
    features: str = "sift"  # one of FEATURES

    @property
    def report(self) -> str:
        """A few human-readable lines: what registered, how well, which world frame."""
        total = len(self.registered) + len(self.unregistered)
        f = 0.5 * (self.K[0, 0] + self.K[1, 1])
        lines = [
            f"Camera poses: pycolmap SfM, {FEATURE_NAMES[self.features]}, {self.matcher} matching, {self.camera_model} camera, "
            f"photos at {self.scaled_size[0]}x{self.scaled_size[1]}",
            f"  registered {len(self.registered)} of {total} photos"
            + (f"; not placed: {name_list(self.unregistered)}" if self.unregistered else ""),
            f"  models: {len(self.model_sizes)} ({', '.join(map(str, self.model_sizes))} photos)"
            + ("; kept the largest" if len(self.model_sizes) > 1 else ""),
            f"  focal length {f:.1f} px, principal point ({self.K[0, 2]:.1f}, {self.K[1, 2]:.1f}) "
            f"in the full-size photos"
            + (f", radial k {', '.join(f'{k:.4f}' for k in self.radial_distortion)}" if self.radial_distortion else ""),
            f"  mean reprojection error {self.mean_reprojection_error:.2f} px, {len(self.points)} 3D points",
        ]
        if self.alignment is not None:
            lines.append(f"  world: {self.alignment.description}")
        if self.timings:
            lines.append("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in self.timings.items()))
        lines += [f"  note: {n}" for n in self.notes]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def choose_matcher(capture: Capture, options: SfmOptions) -> str:
    """Sequential for video and large sets (neighbours in time overlap), else exhaustive."""
    if options.matcher not in MATCHERS:
        raise PoseError(f"unknown matcher {options.matcher!r}; use one of {', '.join(MATCHERS)}")
    if options.matcher != "auto":
        return options.matcher
    if capture.format == "video" or len(capture.frames) > options.sequential_above:
        return "sequential"
    return "exhaustive"


def intrinsics_mode(capture: Capture, options: SfmOptions) -> tuple[str, Optional[np.ndarray]]:
    """("fixed" | "prior" | "estimate", the shared K (3, 3) or None) for this capture.

    "auto" holds a calibrated K fixed, refines an EXIF guess, and estimates from scratch when the
    frames lack K or disagree (one shared camera cannot honour different K).
    """
    if options.intrinsics not in INTRINSICS:
        raise PoseError(f"unknown intrinsics mode {options.intrinsics!r}; use one of {', '.join(INTRINSICS)}")
    if options.intrinsics == "estimate":
        return "estimate", None
    Ks = [f.K for f in capture.frames]
    same = all(K is not None for K in Ks) and all(np.allclose(K, Ks[0], rtol=1e-6, atol=1e-6) for K in Ks)
    if not same:
        if options.intrinsics != "auto":
            raise PoseError(
                f"intrinsics={options.intrinsics!r} needs one K shared by every frame of {capture.root}, "
                "but some frames have none or they differ; use intrinsics='estimate'"
            )
        return "estimate", None
    mode = options.intrinsics
    if mode == "auto":
        mode = "fixed" if capture.format in CALIBRATED_FORMATS else "prior"
    return mode, np.asarray(Ks[0], dtype=np.float64)


def estimate_poses(
    capture: Capture,
    options: Optional[SfmOptions] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> PoseResult:
    """Estimate a camera pose for every frame of `capture` from its photos.

    All frames take part; poses the capture already had are replaced (an SfM model has its own
    world and cannot be mixed with them). Frames SfM could not place keep `pose=None`.
    Raises PoseError when no model is found, Cancelled when `cancel` fires.
    """
    options = options or SfmOptions()
    if not capture.frames:
        raise PoseError(f"no photos in {capture.root}: nothing to estimate poses from")
    if options.camera_model not in CAMERA_MODELS:
        raise PoseError(f"unsupported camera model {options.camera_model!r}; use one of {', '.join(CAMERA_MODELS)}")
    check_features(options.features)
    matcher = choose_matcher(capture, options)
    intrinsics, given_K = intrinsics_mode(capture, options)
    check(cancel)

    work = Path(options.work_dir) if options.work_dir else Path(tempfile.mkdtemp(prefix="vortx-sfm-"))
    work.mkdir(parents=True, exist_ok=True)
    # COLMAP names: the frame index, so duplicate file names in sub-folders cannot collide.
    names = [f"{i:06d}.jpg" for i in range(len(capture.frames))]
    job = {
        "work_dir": str(work),
        "images": [{"path": str(f.image_path), "name": n} for f, n in zip(capture.frames, names)],
        "max_side": int(options.max_side),
        "matcher": matcher,
        "overlap": int(options.sequential_overlap),
        "loop_detection": bool(options.loop_detection),
        "camera_model": options.camera_model,
        "intrinsics": intrinsics,
        "K": None if given_K is None else given_K.tolist(),
        "max_num_features": int(options.max_num_features),
        "features": options.features,
        "learned_matcher": options.learned_matcher,
        "num_threads": int(options.num_threads),
        "min_model_size": min_group_size(len(names)),
    }
    try:
        result, xyz, rgb = run_pose_job(job, work, keep_work=True, task="structure from motion", progress=progress,
                                        cancel=cancel)
        if not result["model_sizes"]:
            db = result["database"]
            raise PoseError(
                f"no camera poses could be estimated for the {len(names)} photos in {capture.root}: "
                f"{db['mean_keypoints']:.0f} features per photo on average and {db['verified_pairs']} "
                "photo pairs with enough matches. Take photos with more overlap (each spot in 3 or more "
                "photos) of textured surfaces; blank walls, mirrors and blurry photos cannot be matched."
            )
        walk = _walk_check(result, work, matcher, options)
        timings = dict(result["timings"])
        remaps = 0
        # A bent model is mapped again (the mapper seeded otherwise; the matches are kept): the same
        # database gives a straight model in some runs and a bent one in others.
        while walk.bend is not None and remaps < BENT_REMAPS:
            remaps += 1
            try:
                again = run_pose_job({**job, "remap_seed": remaps}, work, keep_work=True,
                                     task="structure from motion (mapping again: the poses bent)", progress=progress,
                                     cancel=cancel)
            except PoseError:  # the first model stands, cut where it bends
                break
            timings["map again"] = timings.get("map again", 0.0) + again[0]["timings"]["map"]
            again_walk = _walk_check(again[0], work, matcher, options) if again[0]["model_sizes"] else None
            if again_walk is not None and again_walk.kept > walk.kept:
                (result, xyz, rgb), walk = again, again_walk
        walk.remaps = remaps
        result["timings"] = timings
    finally:
        if options.work_dir is None:
            shutil.rmtree(work, ignore_errors=True)
    return _pose_result(capture, options, matcher, intrinsics, given_K, result, xyz, rgb, names, walk, progress, cancel)


@dataclass
class WalkCheck:
    """What `_walk_check` found in one SfM result: photos to leave out (capture indices) and why."""

    lone: list[int]  # posed only through photos far along the walk
    bend: Optional[Bend]  # indexes `order`
    order: list[int]  # capture indices of the posed photos the bend was looked for in, in capture order
    kept: int  # photos posed after leaving these out
    remaps: int = 0  # how often the mapper ran again because the model bent


def _walk_check(result: dict, work: Path, matcher: str, options: SfmOptions) -> WalkCheck:
    """Lone photos (sequential matching only) and a bend (`bends.find_bend`) in the worker's `result`,
    looked for in its downscaled photos (work/images) with its camera (the lens's radial term ignored:
    it bends the lines of the corridor's photos by a pixel or two at their edges)."""
    camera = result["camera"]
    K_scaled, _ = _pinhole(camera["model"], camera["params"])
    posed = sorted((int(Path(im["name"]).stem), im) for im in result["images"])
    lone = lone_photos([i for i, _ in posed], options.sequential_overlap) if matcher == "sequential" else []
    walk = [(i, im) for i, im in posed if i not in lone]
    frames = [Frame(work / "images" / im["name"], camera["width"], camera["height"], K_scaled,
                    cam_to_world_of(np.asarray(im["cam_from_world"], dtype=np.float64))) for _, im in walk]
    bend = find_bend(frames)
    return WalkCheck(lone, bend, [i for i, _ in walk], len(walk) if bend is None else len(bend.kept))


def _pinhole(model: str, params: list[float]) -> tuple[np.ndarray, list[float]]:
    """COLMAP camera params -> (K (3, 3), radial terms) in the same pixels."""
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        f, cx, cy = params[:3]
        fx = fy = f
        radial = list(params[3:])
    elif model == "PINHOLE":
        fx, fy, cx, cy = params[:4]
        radial = []
    else:
        raise PoseError(f"COLMAP returned an unsupported camera model {model}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), radial


def _pose_result(
    capture: Capture,
    options: SfmOptions,
    matcher: str,
    intrinsics: str,
    given_K: Optional[np.ndarray],
    result: dict,
    xyz: np.ndarray,
    rgb: np.ndarray,
    names: list[str],
    walk: WalkCheck,
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
) -> PoseResult:
    """Turn the worker's result into posed frames (full-size K), checks, the photos `walk` leaves out,
    undistortion and alignment."""
    camera = result["camera"]
    sx, sy = result["scale_xy"]
    K_scaled, radial = _pinhole(camera["model"], camera["params"])
    if intrinsics == "fixed" and given_K is not None:
        K = given_K
    else:
        # COLMAP's pixel grid has the image corner at 0, so rescaling is a plain per-axis divide.
        K = np.diag([1.0 / sx, 1.0 / sy, 1.0]) @ K_scaled

    index_of = {name: i for i, name in enumerate(names)}
    poses = {index_of[im["name"]]: cam_to_world_of(np.asarray(im["cam_from_world"], dtype=np.float64))
             for im in result["images"]}
    frames: list[Frame] = [replace(f, pose=poses.get(i), K=K.copy()) for i, f in enumerate(capture.frames)]
    registered = [f.name for i, f in enumerate(capture.frames) if i in poses]
    unregistered = [f.name for i, f in enumerate(capture.frames) if i not in poses]
    groups = distinct_groups([[index_of[name] for name in model] for model in result.get("model_images", [])],
                             min_group_size(len(names)))
    model_sizes = [len(group) for group in groups] if groups else list(result["model_sizes"])
    links = [(index_of[a], index_of[b], int(n)) for a, b, n in result.get("group_links", [])]
    warnings = quality_warnings(
        num_images=len(frames),
        unregistered=unregistered,
        model_sizes=model_sizes,
        reprojection_error_px=result["mean_reprojection_error"],
        num_points=len(xyz),
        groups=groups,
        links=links,
        frame_names=[f.name for f in capture.frames],
    )

    notes: list[str] = []
    low_contrast = result["database"].get("low_contrast")
    if low_contrast:
        notes.append(f"few features ({low_contrast['before']:.0f} per photo, low contrast or small photos): found again "
                     f"at a lower contrast threshold ({low_contrast['after']:.0f} per photo)")
    attempts = result["database"].get("mapping_attempts") or []
    if len(attempts) > 1:
        notes.append(f"mapping ran {len(attempts)} times (few photos posed: {', '.join(map(str, attempts))} of "
                     f"{len(names)}); kept the run that posed the most")
    size = tuple(result["source_size"])
    # The radial terms live in normalised coordinates, which downscaling does not change.
    shift_px = radial_corner_shift(K_scaled, radial, camera["width"], camera["height"]) / sx if radial else 0.0
    if significant_distortion(shift_px, size):
        if options.undistort:
            frames, K = _undistorted(capture, frames, K, radial, size, options, progress, cancel)
            notes.append(f"lens distortion (corners moved {shift_px:.1f} px) removed: photos undistorted "
                         f"into {frames[0].image_path.parent}")
        else:
            warnings.append(f"the lens distorts the image corners by about {shift_px:.1f} px and undistort is "
                            "off: the reconstruction treats the photos as pinhole, so walls near the image "
                            "edges will bend")
    leave_out = np.zeros(len(frames), bool)
    if walk.lone:
        leave_out[walk.lone] = True
        warnings.append(f"{', '.join(frames[i].name for i in walk.lone)}: placed only through photos far along the "
                        f"walk, none of the {options.sequential_overlap} before or after it, so probably at a "
                        "look-alike place; left out")
    if walk.bend is not None:
        leave_out[[walk.order[k] for k in walk.bend.cut]] = True
        warnings.append(walk.bend.describe([frames[i].name for i in walk.order])
                        + (f" (the mapper ran {walk.remaps + 1} times, bent every time)" if walk.remaps else ""))
    elif walk.remaps:
        notes.append(f"the first model bent (a stretch of photos leaning from the rest); mapping ran again "
                     f"{walk.remaps} time(s), and this model is straight")
    if leave_out.any():
        frames, xyz, rgb = _leave_out(frames, leave_out, result["tracks"], xyz, rgb)
        registered = [f.name for f in frames if f.pose is not None]
        unregistered = [f.name for f in frames if f.pose is None]
    posed = capture.with_frames(frames, metric=False)

    alignment = None
    points = xyz
    if options.align:
        alignment = align_gravity_and_scale(
            posed, camera_height=options.camera_height, known_distance=options.known_distance, points=xyz
        )
        posed, points = alignment.capture, alignment.points
        warnings += alignment.warnings
    return PoseResult(
        capture=posed,
        registered=registered,
        unregistered=unregistered,
        model_sizes=model_sizes,
        matcher=matcher,
        camera_model=camera["model"] + (" (fixed)" if intrinsics == "fixed" else ""),
        K=K,
        radial_distortion=radial,
        mean_reprojection_error=float(result["mean_reprojection_error"]),
        points=points if points is not None else np.zeros((0, 3)),
        point_colors=rgb,
        scaled_size=(camera["width"], camera["height"]),
        alignment=alignment,
        timings={k: float(v) for k, v in result["timings"].items()},
        warnings=warnings,
        notes=notes,
        features=options.features,
    )


def lone_photos(posed: list[int], overlap: int) -> list[int]:
    """Of the posed photos (capture indices, ascending) of a walk matched sequentially, those with no
    other posed photo within `overlap` of them in capture order: they were placed only through a loop
    match, which in a look-alike corridor is another place (the 3D Scanner App corridor: a photo of
    one leg posed 17 m away in the other)."""
    index = np.asarray(posed)
    gaps = np.diff(index)
    before = np.r_[np.inf, gaps]
    after = np.r_[gaps, np.inf]
    return index[(before > overlap) & (after > overlap)].tolist() if len(index) > 1 else []


def _leave_out(frames: list[Frame], leave: np.ndarray, tracks: dict, xyz: np.ndarray,
               rgb: np.ndarray) -> tuple[list[Frame], np.ndarray, np.ndarray]:
    """`frames` with those where `leave` (len(frames),) bool unposed, and the points (N, 3) and colours
    (N, 3) without those at least half of whose observations (`tracks`: obs_image frame index,
    obs_point row) are in the photos left out: those photos' poses placed them."""
    seen_left = np.bincount(tracks["obs_point"], weights=leave[tracks["obs_image"]], minlength=len(xyz))
    seen = np.bincount(tracks["obs_point"], minlength=len(xyz))
    keep = seen_left * 2 < np.maximum(seen, 1)
    return [replace(f, pose=None) if leave[i] else f for i, f in enumerate(frames)], xyz[keep], rgb[keep]


def _undistorted(
    capture: Capture,
    frames: list[Frame],
    K: np.ndarray,
    radial: list[float],
    size: tuple[int, int],
    options: SfmOptions,
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
) -> tuple[list[Frame], np.ndarray]:
    """Frames pointing at undistorted copies of their photos, with the new pinhole K (3, 3).

    Undistortion only changes intrinsics, so the poses stay valid. COLMAP's RADIAL model equals
    OpenCV's (k1, k2, p1=0, p2=0).
    """
    dist = np.array([radial[0], radial[1] if len(radial) > 1 else 0.0, 0.0, 0.0])
    folder = capture.root if capture.root.is_dir() else capture.root.parent
    paths, new_K = undistort_images([f.image_path for f in frames], K, dist, size, folder,
                                    options.cache_dir, progress, cancel)
    return [replace(f, image_path=p, K=new_K.copy()) for f, p in zip(frames, paths)], new_K
