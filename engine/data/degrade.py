"""Photo degradations: what a real camera does to a clean render (pure numpy + OpenCV, seeded).

Rendered rooms are cleaner than any photo: no blur, no noise, one exposure, exact poses. A
"real" synthetic room (`python -m engine synth --realism real`) is rendered losslessly and then
passed through `degrade_photo`, in the order a camera applies it:

1. the render is linearised with the sRGB curve (the view transform is close to it: scene light
   is then multiplicative and blur is physical);
2. motion blur along the camera's rotation direction, and defocus (a disc) whose radius rolls
   slowly over the sequence, as autofocus hunts;
3. auto-exposure: each photo is metered and brought to a phone's mid-grey target (`auto_exposure_gain`;
   a render is exposed for the room's lights, which leaves dim rooms nearly black, while a phone
   exposes every photo for what it sees), then exposure and white balance drift as smooth random
   walks around it (auto-exposure hunting, auto white balance);
4. sensor noise in linear light: shot noise (variance proportional to the signal) + read noise;
5. the sRGB tone curve, 8 bits, and JPEG at the room's quality (75-90, what phones write), with the
   EXIF a phone writes about its lens (the 35 mm-equivalent focal length, whole millimetres).

The poses written with the photos get a per-frame error (`perturb_pose`), as SfM or a phone's
tracking would give; the true poses stay beside them for scoring. Every function takes its random
generator, so a room's degradations are fixed by its seed and frame index (resume-safe).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..colour_space import linear_to_srgb, srgb_to_linear


@dataclass(frozen=True)
class DegradationSettings:
    """How strongly real photos differ from a clean render. Lengths in pixels are fractions of the
    image width, so a room looks alike at 160 or 640 pixels across."""

    shot_noise: float = 6e-4  # variance per unit of linear signal: sigma^2 = shot * x + read^2
    read_noise: float = 2.5e-3  # standard deviation in linear units (1 = white)
    jpeg_quality: tuple[int, int] = (75, 90)  # one quality per room, drawn from this range
    motion_blur_mean: float = 0.006  # mean blur length / image width (about 2 px at 320)
    motion_blur_max: float = 0.025  # longest blur / image width (8 px at 320)
    defocus_max: float = 0.005  # largest defocus disc radius / image width (1.6 px at 320)
    exposure_step_stops: float = 0.08  # random-walk step of the exposure per frame (stops)
    white_balance_step: float = 0.015  # random-walk step of the red and blue log gains per frame
    walk_smoothing_frames: float = 2.0  # Gaussian smoothing of the walks (frames): no jumps
    # Auto-exposure: the centre-weighted mean linear luminance is brought to mid-grey (18 %, about
    # 118 in sRGB), within the gains a phone reaches by exposure time and ISO (1/2 to 16 x).
    auto_exposure_target: float = 0.18
    auto_exposure_gain_range: tuple[float, float] = (0.5, 16.0)
    pose_rotation_deg: tuple[float, float] = (0.5, 2.0)  # per-frame pose error: rotation angle
    pose_translation_m: tuple[float, float] = (0.01, 0.03)  # ... and camera-centre offset

    def to_json(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass(frozen=True)
class FrameDegradation:
    """What happens to one photo; planned for the whole sequence at once (`plan_degradations`)."""

    exposure_stops: float
    white_balance: tuple[float, float, float]  # linear gains, green = 1
    defocus_radius_px: float
    motion_blur_px: float
    motion_blur_angle_deg: float  # image direction of the blur, 0 = along x
    jpeg_quality: int


# ------------------------------------------------------------------------------- building blocks


def smooth_random_walk(n: int, step_std: float, smoothing_frames: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) a random walk (Gaussian steps of `step_std`) smoothed by a Gaussian of `smoothing_frames`
    and centred on 0: values drift over the sequence without jumping between neighbours."""
    walk = np.cumsum(rng.normal(0.0, step_std, n))
    if smoothing_frames > 0 and n > 1:
        radius = int(np.ceil(3 * smoothing_frames))
        taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / smoothing_frames) ** 2)
        padded = np.pad(walk, radius, mode="reflect" if n > radius else "edge")
        walk = np.convolve(padded, taps / taps.sum(), mode="valid")
    return walk - walk.mean()


def add_sensor_noise(linear: np.ndarray, shot: float, read: float, rng: np.random.Generator) -> np.ndarray:
    """Linear image (any shape, float) plus Gaussian noise of variance shot * signal + read^2 (the
    Poisson-Gaussian sensor model). Not clipped: the tone curve does that."""
    x = np.asarray(linear, np.float32)
    sigma = np.sqrt(shot * np.clip(x, 0.0, None) + read * read)
    return (x + sigma * rng.standard_normal(x.shape).astype(np.float32)).astype(np.float32)


def motion_blur_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """Normalised line kernel of `length_px` pixels along image direction `angle_deg` (0 = x),
    anti-aliased (points along the line splatted bilinearly). Length < 1 px gives the identity."""
    length = max(float(length_px), 0.0)
    half = int(np.ceil(length / 2)) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float64)
    t = np.linspace(-length / 2, length / 2, max(int(np.ceil(length * 4)), 1) + 1)
    angle = np.radians(angle_deg)
    xs, ys = half + t * np.cos(angle), half + t * np.sin(angle)
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(kernel, (y0 + dy, x0 + dx), w)
    return (kernel / kernel.sum()).astype(np.float32)


def defocus_kernel(radius_px: float) -> np.ndarray:
    """Normalised disc of `radius_px` (the image of an out-of-focus point), its edge anti-aliased by
    4 x 4 supersampling. Radius < 0.5 px gives the identity."""
    if radius_px < 0.5:
        return np.ones((1, 1), np.float32)
    half = int(np.ceil(radius_px))
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    offsets = np.arange(-half, half + 1)
    ys = (offsets[:, None] + sub[None, :]).ravel()
    inside = (ys[:, None] ** 2 + ys[None, :] ** 2) <= radius_px ** 2
    n = len(offsets)
    kernel = inside.reshape(n, 4, n, 4).mean(axis=(1, 3))
    return (kernel / kernel.sum()).astype(np.float32)


def blur(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Image (H, W[, C]) float convolved with `kernel`, borders mirrored."""
    if kernel.shape == (1, 1):
        return np.asarray(image, np.float32)
    return cv2.filter2D(np.asarray(image, np.float32), -1, kernel, borderType=cv2.BORDER_REFLECT)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """uint8 (H, W, 3) RGB -> JPEG bytes at `quality` (libjpeg's 1-100 scale), 4:2:0 chroma, as
    phone cameras write."""
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"JPEG quality must be 1-100, got {quality}")
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(np.asarray(rgb, np.uint8), cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OSError("OpenCV could not encode the JPEG")
    return data.tobytes()


def with_exif(jpeg: bytes, exif: bytes) -> bytes:
    """JPEG bytes with an APP1 segment holding `exif` ("Exif\\0\\0" + TIFF) right after the start of image."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG (no start-of-image marker)")
    if len(exif) + 2 > 0xFFFF:
        raise ValueError(f"EXIF block of {len(exif)} bytes does not fit one APP1 segment")
    return jpeg[:2] + b"\xff\xe1" + (len(exif) + 2).to_bytes(2, "big") + exif + jpeg[2:]


def write_jpeg(path: Path, rgb: np.ndarray, quality: int, exif: Optional[bytes] = None) -> None:
    """Atomic (tmp + rename): a frame's photo is either complete or absent. `exif`: an APP1 payload
    (e.g. `engine.capture.exif.focal_exif_block`), as a phone writes with its photos."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.jpg")
    data = encode_jpeg(rgb, quality)
    tmp.write_bytes(with_exif(data, exif) if exif is not None else data)
    os.replace(tmp, path)


def perturb_pose(cam_to_world: np.ndarray, rotation_deg: float, translation_m: float,
                 rng: np.random.Generator) -> np.ndarray:
    """The pose (4, 4) turned by `rotation_deg` about a random axis through the camera centre and
    moved `translation_m` in a random direction: a pose error of exactly that size."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rotation, _ = cv2.Rodrigues(axis * np.radians(rotation_deg))
    shift = rng.normal(size=3)
    shift *= translation_m / np.linalg.norm(shift)
    out = np.array(cam_to_world, np.float64, copy=True)
    out[:3, :3] = rotation @ out[:3, :3]
    out[:3, 3] += shift
    return out


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rotation angle in degrees, camera-centre distance in metres) between two poses (4, 4)."""
    relative = np.asarray(estimate)[:3, :3] @ np.asarray(truth)[:3, :3].T
    cos = np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(np.asarray(estimate)[:3, 3] - np.asarray(truth)[:3, 3]))


# ---------------------------------------------------------------------------------- a sequence


def plan_degradations(poses: np.ndarray, width: int, settings: DegradationSettings,
                      rng: np.random.Generator) -> list[FrameDegradation]:
    """Per-frame degradations of a sequence of camera-to-world poses (N, 4, 4): smooth exposure,
    white-balance and focus drifts, and motion blur along each camera's image motion."""
    n = len(poses)
    s = settings
    exposure = smooth_random_walk(n, s.exposure_step_stops, s.walk_smoothing_frames, rng)
    red = smooth_random_walk(n, s.white_balance_step, s.walk_smoothing_frames, rng)
    blue = smooth_random_walk(n, s.white_balance_step, s.walk_smoothing_frames, rng)
    focus = smooth_random_walk(n, 1.0, s.walk_smoothing_frames, rng)
    span = focus.max() - focus.min()
    # Rolling focus: the sharpest frame of the room is in focus, the softest at the largest disc.
    defocus = s.defocus_max * width * ((focus - focus.min()) / span if span > 0 else np.zeros(n))
    lengths = np.minimum(rng.exponential(s.motion_blur_mean * width, n), s.motion_blur_max * width)
    quality = int(rng.integers(s.jpeg_quality[0], s.jpeg_quality[1] + 1))
    angles = _image_motion_angles(poses)
    return [FrameDegradation(float(exposure[i]), (float(np.exp(red[i])), 1.0, float(np.exp(blue[i]))),
                             float(defocus[i]), float(lengths[i]), float(angles[i]), quality) for i in range(n)]


def _image_motion_angles(poses: np.ndarray) -> np.ndarray:
    """(N,) image direction (degrees) in which each frame's view moves: a camera turning about its
    y axis (yaw) smears along image x, about its x axis (pitch) along image y."""
    poses = np.asarray(poses, np.float64)
    n = len(poses)
    angles = np.zeros(n)
    for i in range(n):
        a, b = poses[max(i - 1, 0)], poses[min(i + 1, n - 1)]
        turn, _ = cv2.Rodrigues(a[:3, :3].T @ b[:3, :3])  # rotation in camera axes
        wx, wy = float(turn[0, 0]), float(turn[1, 0])
        angles[i] = np.degrees(np.arctan2(wx, wy)) if abs(wx) + abs(wy) > 1e-9 else 0.0
    return angles


def auto_exposure_gain(linear: np.ndarray, settings: DegradationSettings) -> float:
    """The gain a phone's auto-exposure applies to a linear image (H, W, 3): centre-weighted mean
    luminance (a Gaussian window of half the image's size, as phones meter) to the mid-grey target."""
    h, w = linear.shape[:2]
    luminance = linear @ np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 / sRGB primaries
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    weight = np.exp(-0.5 * (((x - (w - 1) / 2) / (0.5 * w)) ** 2 + ((y - (h - 1) / 2) / (0.5 * h)) ** 2))
    metered = float((luminance * weight).sum() / weight.sum())
    low, high = settings.auto_exposure_gain_range
    return float(np.clip(settings.auto_exposure_target / max(metered, 1e-6), low, high))


def degrade_photo(rgb: np.ndarray, frame: FrameDegradation, settings: DegradationSettings,
                  rng: np.random.Generator) -> np.ndarray:
    """A clean render uint8 (H, W, 3) sRGB -> the photo a camera would have written (uint8, before
    JPEG: write it with `write_jpeg(path, photo, frame.jpeg_quality)`)."""
    linear = srgb_to_linear(np.asarray(rgb, np.float32) / 255.0)
    linear = blur(linear, motion_blur_kernel(frame.motion_blur_px, frame.motion_blur_angle_deg))
    linear = blur(linear, defocus_kernel(frame.defocus_radius_px))
    exposure = auto_exposure_gain(linear, settings) * 2.0 ** frame.exposure_stops
    gains = np.float32(exposure) * np.asarray(frame.white_balance, np.float32)
    linear = add_sensor_noise(linear * gains, settings.shot_noise, settings.read_noise, rng)
    return np.round(linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255.0).astype(np.uint8)


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The random stream of frame `index` of room `seed`: the same noise and pose error however
    often the frame is rendered (an interrupted room resumes with identical files)."""
    return np.random.default_rng([seed, 3, index])


def perturb_poses(poses: Sequence[np.ndarray], settings: DegradationSettings, seed: int) -> np.ndarray:
    """(N, 4, 4) poses with independent per-frame errors of 0.5-2 deg and 1-3 cm (the settings' ranges)."""
    out = []
    for i, pose in enumerate(poses):
        rng = np.random.default_rng([seed, 4, i])
        out.append(perturb_pose(pose, float(rng.uniform(*settings.pose_rotation_deg)),
                                float(rng.uniform(*settings.pose_translation_m)), rng))
    return np.stack(out)

