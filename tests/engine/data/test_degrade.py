"""Photo degradations of "real" synthetic rooms: each one measured on an image where its effect is known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine.colour_space import linear_to_srgb, srgb_to_linear
from engine.data.degrade import (DegradationSettings, FrameDegradation, add_sensor_noise, blur, defocus_kernel,
                                 degrade_photo, encode_jpeg, motion_blur_kernel, perturb_pose, perturb_poses,
                                 plan_degradations, pose_error, smooth_random_walk, write_jpeg)
from engine.geometry.cameras import look_at

# libjpeg's standard luminance quantisation table (Annex K), in zig-zag order as a DQT segment stores it.
_ZIGZAG = [0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20, 13, 6, 7,
           14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59, 52, 45, 38, 31, 39,
           46, 53, 60, 61, 54, 47, 55, 62, 63]
_LUMA = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                  14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                  49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99])


def luminance_table(jpeg: bytes) -> np.ndarray:
    """The first (luminance) quantisation table of a baseline JPEG, in natural row order."""
    assert jpeg[:2] == b"\xff\xd8", "not a JPEG (no SOI marker)"
    i = 2
    while i < len(jpeg):
        marker, length = jpeg[i + 1], int.from_bytes(jpeg[i + 2:i + 4], "big")
        if marker == 0xDB:
            zigzag = np.frombuffer(jpeg[i + 5:i + 69], np.uint8)
            table = np.empty(64, int)
            table[_ZIGZAG] = zigzag
            return table
        i += 2 + length
    raise AssertionError("no quantisation table")


def libjpeg_table(quality: int) -> np.ndarray:
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    return np.clip((_LUMA * scale + 50) // 100, 1, 255)


def textured(h: int = 96, w: int = 128, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.resize(rng.integers(0, 256, (h // 4, w // 4, 3), dtype=np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)


def laplacian_variance(image: np.ndarray) -> float:
    return float(cv2.Laplacian(np.asarray(image, np.float32), cv2.CV_32F).var())


@pytest.mark.parametrize("level", [0.0, 0.05, 0.4])
def test_noise_on_a_flat_image_has_the_set_std(level):
    shot, read = 6e-4, 2.5e-3
    flat = np.full((200, 200), level, np.float32)
    noisy = add_sensor_noise(flat, shot, read, np.random.default_rng(1))
    expected = np.sqrt(shot * level + read ** 2)
    assert noisy.std() == pytest.approx(expected, rel=0.03)
    assert abs(noisy.mean() - level) < 3 * expected / 200


@pytest.mark.parametrize("quality", [75, 90])
def test_jpeg_file_is_a_jpeg_of_the_given_quality(tmp_path, quality):
    path = tmp_path / "000000.jpg"
    write_jpeg(path, textured(), quality)
    data = path.read_bytes()
    assert np.array_equal(luminance_table(data), libjpeg_table(quality))
    assert cv2.imread(str(path)).shape == (96, 128, 3)
    assert not list(tmp_path.glob(".*"))  # the temporary file was renamed into place
    with pytest.raises(ValueError, match="1-100"):
        encode_jpeg(textured(), 0)


def test_blur_lowers_the_laplacian_variance_and_follows_its_direction():
    image = srgb_to_linear(textured() / 255.0)
    sharp = laplacian_variance(image)
    assert laplacian_variance(blur(image, motion_blur_kernel(6, 30))) < 0.5 * sharp
    assert laplacian_variance(blur(image, defocus_kernel(2.0))) < 0.5 * sharp
    assert np.array_equal(blur(image, defocus_kernel(0.3)), image)  # under half a pixel: in focus
    # A horizontal smear leaves horizontal stripes alone and washes vertical ones out.
    stripes = np.tile((np.arange(64) // 4 % 2).astype(np.float32), (64, 1))  # varies along x
    along_x = motion_blur_kernel(8, 0)
    assert np.abs(blur(stripes.T, along_x) - stripes.T).max() < 1e-5
    assert np.abs(blur(stripes, along_x) - stripes).mean() > 0.2
    for kernel in (motion_blur_kernel(5.3, 70), defocus_kernel(2.7)):
        assert kernel.sum() == pytest.approx(1.0, abs=1e-5)


def test_exposure_and_white_balance_drift_smoothly():
    n = 200
    walk = smooth_random_walk(n, 0.08, 2.0, np.random.default_rng(3))
    steps = np.abs(np.diff(walk))
    assert abs(walk.mean()) < 1e-9
    # It wanders far over the sequence but never jumps: neighbours are much closer than the span, and
    # the largest step is below one raw step's std (an unsmoothed walk of 200 steps has ~3 std jumps).
    assert walk.max() - walk.min() > 10 * steps.max()
    assert steps.max() < 0.08
    poses = np.stack([look_at(np.array([np.cos(a), np.sin(a), 1.5]), np.zeros(3)) for a in np.linspace(0, 6, 40)])
    plan = plan_degradations(poses, 320, DegradationSettings(), np.random.default_rng(0))
    exposure = np.array([f.exposure_stops for f in plan])
    assert np.abs(np.diff(exposure)).max() < 0.15 and np.ptp(exposure) > 0.1
    assert all(f.white_balance[1] == 1.0 for f in plan)
    focus = np.array([f.defocus_radius_px for f in plan])
    assert focus.min() == 0.0 and focus.max() == pytest.approx(0.005 * 320)  # rolling focus spans sharp..soft
    assert len({f.jpeg_quality for f in plan}) == 1 and 75 <= plan[0].jpeg_quality <= 90
    assert all(0 <= f.motion_blur_px <= 0.025 * 320 for f in plan)
    # A camera orbiting about z turns about its own y axis: the image smears along x.
    assert np.all(np.minimum(np.abs([f.motion_blur_angle_deg for f in plan]) % 180,
                             180 - np.abs([f.motion_blur_angle_deg for f in plan]) % 180) < 20)


def test_degraded_photo_is_darker_with_lower_exposure_and_noisy():
    clean = np.full((64, 64, 3), 128, np.uint8)
    settings = DegradationSettings()
    metered = degrade_photo(clean, FrameDegradation(0.0, (1.0, 1.0, 1.0), 0.0, 0.0, 0.0, 90), settings,
                            np.random.default_rng(0))
    photo = degrade_photo(clean, FrameDegradation(-1.0, (1.0, 1.0, 1.0), 0.0, 0.0, 0.0, 90), settings,
                          np.random.default_rng(0))
    assert photo.dtype == np.uint8 and photo.shape == clean.shape
    # One stop of drift below what the auto-exposure chose halves the linear light.
    assert srgb_to_linear(photo / 255.0).mean() == pytest.approx(srgb_to_linear(metered / 255.0).mean() / 2, rel=0.03)
    assert photo.std() > 1.0
    warm = degrade_photo(clean, FrameDegradation(0.0, (1.2, 1.0, 0.8), 0.0, 0.0, 0.0, 90), settings,
                         np.random.default_rng(0)).reshape(-1, 3).mean(0)
    neutral = metered.reshape(-1, 3).mean(0)
    assert warm[0] > neutral[0] + 10 and warm[2] < neutral[2] - 10 and abs(warm[1] - neutral[1]) < 2


def test_auto_exposure_brings_a_dim_render_to_mid_grey_as_a_phone_does():
    """A render exposed for the room's lights can be nearly black (a dim room at -0.8 stops); a phone
    meters each photo and exposes it for mid-grey, whatever the render's exposure was."""
    rng = np.random.default_rng(1)
    scene = rng.uniform(0.02, 0.5, (48, 64, 3)).astype(np.float32)  # linear reflectances x light
    frame = FrameDegradation(0.0, (1.0, 1.0, 1.0), 0.0, 0.0, 0.0, 90)
    means = []
    for stops in (-3.0, -1.5, 0.0):
        render = np.round(linear_to_srgb(scene * 2.0 ** stops) * 255).astype(np.uint8)
        photo = degrade_photo(render, frame, DegradationSettings(), np.random.default_rng(0))
        luminance = srgb_to_linear(photo / 255.0) @ np.array([0.2126, 0.7152, 0.0722])
        means.append(luminance.mean())
    assert np.ptp(means) < 0.1 * np.mean(means)  # the photo's brightness no longer depends on the render's
    assert means[0] == pytest.approx(0.18, rel=0.15)  # mid-grey: about 118 in sRGB
    # A render darker than the phone's highest gain stays dark (a phone cannot see in the dark).
    black = np.full((48, 64, 3), 1, np.uint8)
    assert degrade_photo(black, frame, DegradationSettings(), np.random.default_rng(0)).mean() < 60


def test_pose_error_has_the_requested_size():
    truth = look_at(np.array([1.0, 2.0, 1.5]), np.array([3.0, 2.0, 1.0]))
    rot, trans = pose_error(perturb_pose(truth, 1.3, 0.02, np.random.default_rng(0)), truth)
    assert rot == pytest.approx(1.3, abs=1e-6) and trans == pytest.approx(0.02, abs=1e-9)
    poses = np.repeat(truth[None], 50, 0)
    moved = perturb_poses(poses, DegradationSettings(), seed=5)
    errors = np.array([pose_error(m, truth) for m in moved])
    assert np.all((errors[:, 0] >= 0.5 - 1e-6) & (errors[:, 0] <= 2.0 + 1e-6))
    assert np.all((errors[:, 1] >= 0.01 - 1e-9) & (errors[:, 1] <= 0.03 + 1e-9))
    assert np.allclose(moved[:, :3, :3] @ moved[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.array_equal(moved, perturb_poses(poses, DegradationSettings(), seed=5))  # seeded


def test_photos_carry_the_lens_exif_a_phone_writes(tmp_path):
    """The 35 mm-equivalent focal length, rounded as phones round it, read back by the photo loader."""
    from engine.capture import load_capture
    from engine.capture.exif import focal_exif_block

    focal = 0.5 * 64 / np.tan(np.radians(30.0))  # 60 degrees across 64 px
    for i in range(2):
        image = np.random.default_rng(i).integers(0, 255, (48, 64, 3), dtype=np.uint8)
        write_jpeg(tmp_path / f"{i:06d}.jpg", image, 85, focal_exif_block(focal, 64, 48))
    frames = load_capture(tmp_path).frames
    assert cv2.imread(str(tmp_path / "000000.jpg")).shape == (48, 64, 3)  # still a JPEG any reader opens
    assert frames[0].K is not None and frames[0].K[0, 0] == pytest.approx(focal, rel=0.02)
