"""`python -m engine eval-scale ROOM [ROOM ...]`: metric scale from the photos alone, against the truth.

Each room (ScanNet layout: a rendered room of `engine synth`, or a real capture with metric poses)
is treated as a user's photos-only capture: its photos (`color/`) are loaded without poses or
intrinsics and prepared as `engine poses` and `engine reconstruct` prepare them (structure from
motion, gravity, the floor- and ceiling-based metric scale of `engine/poses/scale.py`). The
estimated cameras are then fitted to the room's true cameras (`pose_true/` where the given poses were
perturbed, else `pose/`) by a similarity on the camera centres; its scale says how far the estimate
is from metres:

- `scale_error`: estimated length / true length - 1 (+0.10: the reconstruction comes out 10 % too large);
- `sigma`: the estimate's own 1-sigma (relative), to judge whether the error is within what it claims;
- `registered`: photos that structure from motion posed, of all photos;
- `centre_rms_m`: RMS distance of the camera centres from the true ones after a least-squares
  similarity (metres): a large value means the poses themselves are wrong, not just their scale.

The error is the median over camera pairs of estimated / true distance, so a few misplaced photos
do not decide it (`fit_scale`).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture import load_capture
from ..capture.model import Capture
from ..data import scannet_layout as layout
from ..errors import VortxError
from ..poses.align import umeyama
from ..poses.prepare import SFM_ALWAYS, prepare_capture

MIN_MATCHED = 3  # camera centres a similarity needs
MIN_PAIR_DISTANCE_M = 0.5  # camera pairs closer than this say little about the scale


@dataclass(frozen=True)
class ScaleResult:
    room: str
    registered: int
    photos: int
    scale_error: float  # estimated / true - 1
    sigma: float  # the estimate's own relative 1-sigma (nan when it gave none)
    source: str  # what the scale came from
    centre_rms_m: float

    def row(self) -> str:
        return (f"{self.room:<22} {self.registered:>3}/{self.photos:<3} {100 * self.scale_error:>+7.1f} % "
                f"{100 * self.sigma:>6.0f} % {self.centre_rms_m:>8.3f}  {self.source}")


HEADER = f"{'room':<22} {'posed':>7} {'error':>9} {'+-1s':>8} {'rms (m)':>8}  scale source"


def true_camera_centres(room: Path) -> dict[str, np.ndarray]:
    """Photo stem -> true camera centre (3,) in metres, from `pose_true/` (else `pose/`)."""
    folder = room / layout.TRUE_POSE_DIR
    if not folder.is_dir():
        folder = room / layout.POSE_DIR
    centres = {}
    for path in sorted(folder.glob("*.txt")):
        pose = np.loadtxt(path)
        if pose.shape == (4, 4) and np.all(np.isfinite(pose)):
            centres[path.stem] = pose[:3, 3]
    if not centres:
        raise VortxError(f"{room} has no true poses (pose_true/*.txt or pose/*.txt)")
    return centres


def photos_only(room: Path) -> Capture:
    """The room's photos as a user without poses or intrinsics would give them."""
    photos = room / "color"
    if not photos.is_dir():
        raise VortxError(f"{room} has no color/ folder of photos")
    return load_capture(photos)


def fit_scale(estimated: dict[str, np.ndarray], true: dict[str, np.ndarray]) -> tuple[float, float, int]:
    """(estimated / true length ratio, RMS of the fitted centres in metres, matched count).

    The ratio is the median over camera pairs at least MIN_PAIR_DISTANCE_M apart of their estimated
    over their true distance: the scale of the cameras SfM placed right, even when it misplaced a few
    (a repeated wall pattern can register a handful of photos on the wrong wall; a least-squares
    similarity would let them drag the scale). The RMS is that of a least-squares similarity: it
    shows whether the poses themselves are right."""
    names = sorted(set(estimated) & set(true))
    if len(names) < MIN_MATCHED:
        return float("nan"), float("nan"), len(names)
    source = np.stack([estimated[n] for n in names])
    target = np.stack([true[n] for n in names])
    i, j = np.triu_indices(len(names), k=1)
    true_distance = np.linalg.norm(target[i] - target[j], axis=1)
    far = true_distance >= MIN_PAIR_DISTANCE_M
    if not far.any():
        return float("nan"), float("nan"), len(names)
    ratio = float(np.median(np.linalg.norm(source[i] - source[j], axis=1)[far] / true_distance[far]))
    similarity = umeyama(source, target, with_scale=True)  # target = s R source + t
    residual = similarity.apply_points(source) - target
    return ratio, float(np.sqrt((residual ** 2).sum(1).mean())), len(names)


def evaluate_room(room: Path, camera_height: Optional[float] = None) -> ScaleResult:
    capture = photos_only(room)
    kwargs = {} if camera_height is None else {"camera_height": camera_height}
    prepared = prepare_capture(capture, sfm=SFM_ALWAYS, **kwargs)
    estimated = {f.image_path.stem: np.asarray(f.pose, np.float64)[:3, 3] for f in prepared.capture.frames if f.pose is not None}
    ratio, rms, _ = fit_scale(estimated, true_camera_centres(room))
    sigma = prepared.scale.relative_sigma if prepared.scale is not None else float("nan")
    return ScaleResult(room.name, len(estimated), len(capture.frames), ratio - 1.0, sigma, prepared.scale_source, rms)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("rooms", nargs="+", type=Path, help="room folders (ScanNet layout with true poses)")
    parser.add_argument("--camera-height", type=float, help="the camera-height prior in metres (default 1.5)")
    parser.add_argument("--json", type=Path, help="also write the rows here")


def run(args: argparse.Namespace) -> int:
    results = []
    print(HEADER, flush=True)
    for room in args.rooms:
        result = evaluate_room(room, args.camera_height)
        results.append(result)
        print(result.row(), flush=True)
    errors = np.array([abs(r.scale_error) for r in results if np.isfinite(r.scale_error)])
    if len(errors):
        print(f"mean |error| {100 * errors.mean():.1f} %, worst {100 * errors.max():.1f} %, "
              f"within 10 %: {int((errors <= 0.10).sum())} of {len(results)}")
    if args.json:
        args.json.write_text(json.dumps([vars(r) for r in results], indent=1))
    return 0

