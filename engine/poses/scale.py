"""Metric scale of a photos-only capture from what the photos show: the floor and the ceiling.

Structure from motion gives a world in arbitrary units. The first guess (`gravity.py`) scales it so
the median camera stands `camera_height` (1.5 m) above the floor found in the sparse points. That
guess is only as good as two things: the floor plane (sparse points on a floor are few and a
kitchen counter can pass for it) and the assumption about how high people hold the camera. Here
the scale is estimated again from two cues, each measured where it is best sampled:

- the floor and the ceiling are searched in dense stereo depth of a few keyframes (a floor or a
  ceiling is a large, often weakly textured plane: thousands of depth samples where SfM has tens)
  and in the sparse points: a floor well supported by sparse points is taken from them (they are
  exact where they are), else from dense depth;
- cue 1, camera height: the median camera height above the floor, in world units, against a prior on
  how high a hand-held camera is held;
- cue 2, room height: the floor-to-ceiling distance, in world units, against a prior on ceiling
  heights in homes.

The priors are stated in metres, each a two-part Gaussian mixture: a typical core and a broad part
for the atypical (a photographer crouching or sitting, an old building or a loft). The cues are
combined by Bayes on a grid of scale factors: with both seen, the posterior is the product of the two
likelihoods; a broad part keeps one surprising cue from dragging the answer far when the other
agrees with its prior (the robust combination). The result is the posterior mean of the log scale
and its standard deviation (a relative 1-sigma). Without a floor, nothing is measured: the caller's
camera-height guess stays and the estimate says so.

Priors (the numbers below; a user who knows better sets the scale from a known distance instead):
- camera height: core N(camera_height, 0.12 m) with weight 0.85: a standing adult's eye height is
  1.45-1.75 m and a phone is held at or a little below the eyes to see its screen, so 1.3-1.7 m
  covers most hand-held photos; broad N(camera_height, 0.35 m) with weight 0.15 for a
  camera held low (crouching, sitting, photographing a counter) or high.
- room height: core N(2.5 m, 0.12 m) with weight 0.7: homes built to common codes and habits have
  2.4-2.7 m (8 ft = 2.44 m in North America, 2.4-2.6 m in most European flats); broad
  N(2.9 m, 0.4 m) with weight 0.3 for older buildings (3 m and more), lofts and sloped ceilings.

Public API: `estimate_metric_scale(capture, points, camera_height, dense=True, ...) -> ScaleEstimate`;
`ScaleEstimate.factor` multiplies the capture's current units (1 = keep them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from ..capture.model import Capture
from ..errors import Cancelled, VortxError
from ..jobs import CancelToken, ProgressCallback, check
from ..stereo.options import MATCHER_FAST, StereoOptions
from .camera_height import DEFAULT_CAMERA_HEIGHT_M
from .floor import GRAVITY_MIN_INLIERS, FloorPlane, find_floor_plane

# Priors, metres: ((weight, mean, sigma), ...). The camera height's means are offsets from the
# user's camera height setting (its default is camera_height.py's 1.5 m).
CAMERA_HEIGHT_PRIOR = ((0.85, 0.0, 0.12), (0.15, 0.0, 0.35))
ROOM_HEIGHT_PRIOR = ((0.7, 2.5, 0.12), (0.3, 2.9, 0.4))
# A ceiling must be clearly above the cameras: the ratio of the floor-to-ceiling distance to the
# camera height lies in this range (a 1.5 m camera under a 1.9-5 m ceiling), else the plane above
# the cameras is something else (a shelf, a lamp, a slanted roof).
ROOM_TO_CAMERA_RATIO = (1.25, 3.4)
# Without a floor the first guess took the lowest points (or nothing) as the floor: its 1-sigma is
# stated, not measured: a low object under the cameras or a floor below all points is 30 % off easily.
NO_FLOOR_RELATIVE_SIGMA = 0.3
# Dense depth: a few keyframes at low resolution (seconds on a CPU).
DENSE_REFERENCES = 6
DENSE_LONG_SIDE = 96
DENSE_MAX_POINTS = 40_000
# Grid of log scale factors the posterior is evaluated on: 1/4 to 4 times the current units.
LOG_FACTOR_GRID = np.linspace(np.log(0.25), np.log(4.0), 2401)

SOURCE_FLOOR_AND_CEILING = "floor and ceiling"
SOURCE_FLOOR = "camera height over the floor"
SOURCE_GUESS = "camera height guess (no floor seen)"


@dataclass(frozen=True)
class ScaleCue:
    """One measured cue: a length in the capture's current units and the prior it is held against."""

    name: str  # "camera height" | "room height"
    units: float  # measured length in the capture's current units
    evidence: str  # "dense depth" | "sparse points"


@dataclass
class ScaleEstimate:
    factor: float  # multiply the capture's current units by this to get metres
    relative_sigma: float  # 1-sigma of the factor, relative (0.08 = 8 %)
    source: str  # SOURCE_FLOOR_AND_CEILING, SOURCE_FLOOR or SOURCE_GUESS
    evidence: str  # where the planes were found: "dense depth", "sparse points", both, or "" (guess)
    cues: list[ScaleCue] = field(default_factory=list)
    floor: Optional[FloorPlane] = None  # in the capture's current world
    ceiling_z: Optional[float] = None  # height of the ceiling plane's centre, current units
    dense_points: int = 0  # dense depth samples searched (0: dense depth not used)
    notes: list[str] = field(default_factory=list)  # why dense depth was not used, ...

    @property
    def source_text(self) -> str:
        """"floor and ceiling (dense depth)": the source with where it was seen."""
        return f"{self.source} ({self.evidence})" if self.evidence else self.source

    def describe(self) -> str:
        """One line: the scale, its uncertainty, its source and the numbers behind it."""
        parts = [f"{c.name} {c.units:.3g} units ({c.evidence})" for c in self.cues]
        measured = "; ".join(parts) if parts else "no floor in the dense depth or the sparse points"
        return (f"metric scale x{self.factor:.3g} +-{100 * self.relative_sigma:.0f} % from the "
                f"{self.source_text}: {measured}")

    def summary(self) -> dict:
        """JSON-ready: the batch report's and the reconstruction sidecar's scale entry."""
        return {"factor": self.factor, "relative_sigma": self.relative_sigma, "source": self.source_text,
                "cues": {c.name: {"units": c.units, "evidence": c.evidence} for c in self.cues}}


def estimate_metric_scale(
    capture: Capture,
    points: Optional[np.ndarray],
    camera_height: float = DEFAULT_CAMERA_HEIGHT_M,
    dense: bool = True,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> ScaleEstimate:
    """The metric scale of `capture` (posed, Z up, any units) from its floor and ceiling.

    points: the sparse points (N, 3) in the capture's world, or None. dense: also compute low
    resolution stereo depth of a few keyframes and search the planes there first.
    """
    posed = [f for f in capture.frames if f.pose is not None]
    centres = np.stack([f.pose[:3, 3] for f in posed]) if posed else np.zeros((0, 3))
    notes: list[str] = []
    dense_points = np.zeros((0, 3))
    if dense and len(posed) >= 2:
        dense_points, note = _dense_points(capture, points, progress, cancel)
        if note:
            notes.append(note)
    check(cancel)
    sparse = None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 3)

    # The floor: a well-supported plane in the sparse points first (SfM points are exact where they
    # are; the low-resolution dense floor came out 2-4 % closer to the cameras on the demo room), then
    # dense depth, then a weakly supported sparse plane. The ceiling: dense depth first (SfM rarely
    # has enough points on a plain ceiling).
    floor, floor_evidence = _first_plane(centres, [(sparse, "sparse points")], up=True)
    if floor is None or floor.inliers < GRAVITY_MIN_INLIERS:
        dense_floor, dense_evidence = _first_plane(centres, [(dense_points, "dense depth")], up=True)
        if dense_floor is not None:
            floor, floor_evidence = dense_floor, dense_evidence
    if floor is None:
        return ScaleEstimate(1.0, NO_FLOOR_RELATIVE_SIGMA, SOURCE_GUESS, "", [], None, None, len(dense_points), notes)
    camera_units = float(np.median(floor.heights(centres)))
    cues = [ScaleCue("camera height", camera_units, floor_evidence)]
    ceiling, ceiling_evidence = _first_plane(centres, [(dense_points, "dense depth"), (sparse, "sparse points")], up=False)
    ceiling_z = None
    if ceiling is not None:
        # The ceiling's height above the floor, both planes measured at the cameras' centre.
        centre = np.median(centres, axis=0)
        # (the ceiling plane is in the flipped frame: n . (x, y, -z) = offset)
        ceiling_z = float(ceiling.normal[0] * centre[0] + ceiling.normal[1] * centre[1] - ceiling.offset) / ceiling.normal[2]
        floor_z = float(floor.offset - floor.normal[0] * centre[0] - floor.normal[1] * centre[1]) / floor.normal[2]
        room_units = ceiling_z - floor_z
        if ROOM_TO_CAMERA_RATIO[0] <= room_units / camera_units <= ROOM_TO_CAMERA_RATIO[1]:
            cues.append(ScaleCue("room height", room_units, ceiling_evidence))
        else:
            notes.append(f"a plane {room_units / camera_units:.2f} camera heights above the floor is not taken as "
                         "the ceiling")
            ceiling_z = None
    factor, sigma = combine_cues(cues, camera_height)
    evidence = sorted({c.evidence for c in cues})
    source = SOURCE_FLOOR_AND_CEILING if len(cues) == 2 else SOURCE_FLOOR
    return ScaleEstimate(factor, sigma, source, " and ".join(evidence), cues, floor, ceiling_z, len(dense_points), notes)


def combine_cues(cues: Sequence[ScaleCue], camera_height: float = DEFAULT_CAMERA_HEIGHT_M) -> tuple[float, float]:
    """(factor, relative 1-sigma): the posterior mean and standard deviation of the log scale.

    Each cue measures a length L_u in units; with factor x its metric length is x L_u, whose prior
    is the cue's mixture. p(L_u | x) = p_prior(x L_u) * x (the change of variables), and the log
    factor has a flat prior over the grid.
    """
    if not cues:
        raise ValueError("combine_cues needs at least one cue")
    log_x = LOG_FACTOR_GRID
    x = np.exp(log_x)
    log_posterior = np.zeros_like(log_x)
    for cue in cues:
        if cue.name == "camera height":
            prior = tuple((w, camera_height + offset, s) for w, offset, s in CAMERA_HEIGHT_PRIOR)
        elif cue.name == "room height":
            prior = ROOM_HEIGHT_PRIOR
        else:
            raise ValueError(f"unknown scale cue {cue.name!r}")
        log_posterior += np.log(_mixture_pdf(x * cue.units, prior) * x + 1e-300)
    weights = np.exp(log_posterior - log_posterior.max())
    weights /= weights.sum()
    mean = float((weights * log_x).sum())
    sigma = float(np.sqrt((weights * (log_x - mean) ** 2).sum()))
    return float(np.exp(mean)), sigma


def _mixture_pdf(values: np.ndarray, prior: Sequence[tuple[float, float, float]]) -> np.ndarray:
    total = np.zeros_like(values)
    for weight, mean, sigma in prior:
        total += weight * np.exp(-0.5 * ((values - mean) / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi))
    return total


def _first_plane(
    centres: np.ndarray, sources: Sequence[tuple[Optional[np.ndarray], str]], up: bool
) -> tuple[Optional[FloorPlane], str]:
    """The floor (up=True) or the ceiling (up=False) in the first source where it is found.

    The ceiling is the floor of the world turned upside down (z -> -z), so one plane search with
    its heuristics (horizontal, well supported, nothing much beyond it) serves both; the returned
    ceiling plane is in the flipped frame (normal pointing down in the real one, offset negated).
    """
    flip = np.array([1.0, 1.0, 1.0 if up else -1.0])
    for points, evidence in sources:
        if points is None or len(points) == 0:
            continue
        search = find_floor_plane(points * flip, centres * flip, reject_orbited=up)
        if search.plane is not None:
            return search.plane, evidence
    return None, ""


def _dense_points(
    capture: Capture, points: Optional[np.ndarray], progress: Optional[ProgressCallback], cancel: Optional[CancelToken]
) -> tuple[np.ndarray, str]:
    """(P, 3) world points from low-resolution stereo depth of a few keyframes, and a note when there are none."""
    # defers torch and cv2 (depth_maps loads them): Blender imports this module before they are installed
    from ..stereo.depth_maps import estimate_depth_maps, stereo_references

    posed = [f for f in capture.frames if f.pose is not None]
    poses = np.stack([f.pose for f in posed])
    sizes = {(f.width, f.height) for f in posed}
    if len(sizes) > 1:
        return np.zeros((0, 3)), "dense depth skipped: the photos have different sizes"
    # The world is already roughly metric (the camera-height guess), so the depth limits in metres
    # hold with a wide margin; the sparse points narrow each view's range.
    options = StereoOptions(matcher=MATCHER_FAST, long_side=DENSE_LONG_SIDE, planes=32, refine_planes=4, min_depth=0.05, max_depth=40.0,
                            max_references=DENSE_REFERENCES, consistency_views=1)
    references = stereo_references(len(posed), DENSE_REFERENCES).tolist()
    try:
        maps = estimate_depth_maps(posed, poses, references, options, points=points, progress=progress, cancel=cancel)
    except Cancelled:
        raise
    except (OSError, VortxError) as error:  # a photo that cannot be read: the sparse points still serve
        return np.zeros((0, 3)), f"dense depth skipped: {error}"
    world: list[np.ndarray] = []
    for depth_map in maps:
        v, u = np.nonzero(depth_map.depth > 0)
        if len(u) == 0:
            continue
        depth = depth_map.depth[v, u].astype(np.float64)
        rays = np.linalg.inv(depth_map.K) @ np.stack([u + 0.5, v + 0.5, np.ones_like(u, dtype=np.float64)])
        camera = rays * depth
        world.append((depth_map.pose[:3, :3] @ camera).T + depth_map.pose[:3, 3])
    if not world:
        return np.zeros((0, 3)), "dense depth found no confident depth"
    dense = np.concatenate(world)
    if len(dense) > DENSE_MAX_POINTS:
        dense = dense[np.random.default_rng(0).choice(len(dense), DENSE_MAX_POINTS, replace=False)]
    return dense, ""
