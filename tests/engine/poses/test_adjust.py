"""Bundle adjustment with the given camera centres as the gauge (engine/poses/adjust.py), on synthetic
rooms whose truth is known: rotations a tracker got 1-2 deg wrong come back, the centres stay where
they were given (so no stretch of a trajectory can change scale), wrong matches are dropped, and the
solver agrees with scipy's least squares on a small problem."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from engine.poses.adjust import AdjustOptions, Tracks, adjust, reprojection_errors, rodrigues
from engine.poses.align import umeyama
from fixtures_tracks import F, H, K, W, angles_deg, cam_from_world, centres_of, look, observe, ring_room, wall_points

def test_tracker_rotations_come_back_and_the_given_centres_stay():
    rng = np.random.default_rng(0)
    rotations, centres, points = ring_room(rng)
    tracks, wrong = observe(rotations, centres, points, rng, outliers=0.03)
    given = rodrigues(rng.normal(0.0, np.radians(1.0), (len(centres), 3))) @ rotations
    assert np.median(angles_deg(given, rotations)) > 1.0
    start = Tracks(tracks.camera, tracks.point, tracks.uv, points + rng.normal(0.0, 0.03, points.shape))

    result = adjust(np.repeat(K[None], len(centres), 0), np.zeros(len(centres), int), cam_from_world(given, centres), start)

    assert angles_deg(result.cam_from_world[:, :, :3], rotations).max() < 0.1
    assert np.abs(centres_of(result.cam_from_world) - centres).max() < 1e-9  # the gauge: centres as given
    assert result.error_adjusted_px < 0.5 < 3.0 < result.error_given_px
    # The wrong matches (15-40 px off) are the observations dropped; almost nothing else is.
    assert (~result.inlier[wrong]).mean() > 0.95 and (~result.inlier[~wrong]).mean() < 0.01
    errors = reprojection_errors(K[None].repeat(len(centres), 0), result.focal_scale, np.zeros(len(centres), int),
                                 result.cam_from_world, result.points, tracks)
    assert np.mean(errors[result.inlier]) == pytest.approx(result.error_adjusted_px, rel=1e-6)


def test_a_straight_stretch_keeps_its_roll():
    """Cameras on a straight line with their centres held can all turn about that line without moving a
    centre: the photos do not see it. The rotation prior keeps that turn where the given poses had it."""
    rng = np.random.default_rng(3)
    x = np.linspace(-1.5, 1.5, 25)
    centres = np.stack([x, np.zeros_like(x), np.full_like(x, 1.4)], 1)
    rotations = np.stack([look(c, c + [0.2 * np.sin(3 * c[0]), 1.0, -0.05]) for c in centres])
    points = wall_points(rng, 4000)
    tracks, _ = observe(rotations, centres, points, rng)
    given = rodrigues(rng.normal(0.0, np.radians(0.7), (len(centres), 3))) @ rotations
    result = adjust(np.repeat(K[None], len(centres), 0), np.zeros(len(centres), int), cam_from_world(given, centres),
                    tracks)
    turned = angles_deg(result.cam_from_world[:, :, :3], rotations)
    assert turned.max() < 0.35, turned  # the truth's common roll is the given poses' mean, well under their 0.7 deg
    relative = angles_deg(np.einsum("cij,ckj->cik", result.cam_from_world[1:, :, :3], result.cam_from_world[:-1, :, :3]),
                          np.einsum("cij,ckj->cik", rotations[1:], rotations[:-1]))
    assert relative.max() < 0.05  # what stereo needs: neighbours' relative rotations


def test_position_priors_keep_a_weakly_linked_stretch_at_its_scale():
    """Two stretches of a trajectory that share few points (the SUN3D room's two fragments); centres free
    within 1 cm priors around given centres that are 1 cm off: every stretch keeps its scale within 1 %."""
    rng = np.random.default_rng(5)
    rotations, centres, points = ring_room(rng, cameras=48)
    first = np.arange(24)
    second = np.arange(24, 48)
    tracks, _ = observe(rotations, centres, points, rng)
    # Cut the link: points seen from both stretches keep only the first stretch's views, except 15.
    both = np.intersect1d(tracks.point[np.isin(tracks.camera, first)], tracks.point[np.isin(tracks.camera, second)])
    drop = np.isin(tracks.point, both[15:]) & np.isin(tracks.camera, second)
    tracks = Tracks(tracks.camera[~drop], tracks.point[~drop], tracks.uv[~drop], points)
    given_centres = centres + rng.normal(0.0, 0.01, centres.shape)
    given = rodrigues(rng.normal(0.0, np.radians(1.0), (len(centres), 3))) @ rotations
    result = adjust(np.repeat(K[None], len(centres), 0), np.zeros(len(centres), int),
                    cam_from_world(given, given_centres), tracks, AdjustOptions(position_sigma=0.01))
    refined = centres_of(result.cam_from_world)
    for part in (first, second):
        assert umeyama(refined[part], given_centres[part]).scale == pytest.approx(1.0, abs=0.01)
    assert angles_deg(result.cam_from_world[:, :, :3], rotations).max() < 0.5  # the given centres' 1 cm noise turns the world a little
    assert np.abs(refined - given_centres).max() < 0.04


def eight_neighbours(seed: int):
    """Eight neighbouring cameras of the ring room (most points seen more than once), their tracks with
    0.5 px noise, and given rotations 1 deg off: (rng, rotations, centres, tracks, given rotations)."""
    rng = np.random.default_rng(seed)
    rotations, centres, points = ring_room(rng, cameras=60)
    rotations, centres = rotations[:8], centres[:8]
    points = points[rng.choice(len(points), 600, replace=False)]
    tracks, _ = observe(rotations, centres, points, rng, noise_px=0.5)
    used = np.unique(tracks.point)
    remap = -np.ones(len(points), int)
    remap[used] = np.arange(len(used))
    tracks = Tracks(tracks.camera, remap[tracks.point], tracks.uv, points[used])
    given = rodrigues(rng.normal(0.0, np.radians(1.0), (8, 3))) @ rotations
    return rng, rotations, centres, tracks, given


def test_agrees_with_scipy_least_squares_on_a_small_problem():
    """The same objective (pixel residuals + rotation prior, centres held, plain least squares) solved by
    scipy's trust-region solver with numerical derivatives: the same rotations and points."""
    rng, rotations, centres, tracks, given = eight_neighbours(11)
    options = AdjustOptions(loss_scale_px=1e6, outlier_px=1e9, max_iterations=100, tolerance=1e-14, refine_focal=False)
    ours = adjust(np.repeat(K[None], 8, 0), np.zeros(8, int), cam_from_world(given, centres), tracks, options)

    sigma = np.radians(options.rotation_sigma_deg)

    def residuals(x: np.ndarray) -> np.ndarray:
        w, X = x[:24].reshape(8, 3), x[24:].reshape(-1, 3)
        R = rodrigues(w) @ given
        y = np.einsum("oij,oj->oi", R[tracks.camera], X[tracks.point] - centres[tracks.camera])
        uv = F * y[:, :2] / y[:, 2:3] + [W / 2, H / 2]
        return np.concatenate([(uv - tracks.uv).ravel(), w.ravel() / sigma])

    reference = least_squares(residuals, np.concatenate([np.zeros(24), tracks.points.ravel()]), method="trf",
                              x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    R_reference = rodrigues(reference.x[:24].reshape(8, 3)) @ given
    assert angles_deg(ours.cam_from_world[:, :, :3], R_reference).max() < 1e-3
    assert np.abs(ours.points - reference.x[24:].reshape(-1, 3)).max() < 1e-4


def test_per_camera_priors_agree_with_scipy_least_squares():
    """Centres free within priors of their own, and rotation priors of their own (a tiny pair holds a
    camera, as the refinement holds a stretch that freeing would rescale): the same objective solved by
    scipy's trust-region solver gives the same cameras, and the held camera stays where it started."""
    rng, rotations, centres, tracks, given = eight_neighbours(12)
    given_centres = centres + rng.normal(0.0, 0.02, centres.shape)
    position_sigma = np.array([1e-5, 0.05, 0.05, 0.02, 0.05, 0.1, 0.05, 0.05])
    rotation_sigma_deg = np.array([4e-4, 2.0, 2.0, 2.0, 1.0, 2.0, 3.0, 2.0])
    options = AdjustOptions(position_sigma=position_sigma, rotation_sigma_deg=rotation_sigma_deg, loss_scale_px=1e6,
                            outlier_px=1e9, max_iterations=100, tolerance=1e-14, refine_focal=False)
    ours = adjust(np.repeat(K[None], 8, 0), np.zeros(8, int), cam_from_world(given, given_centres), tracks, options)

    def residuals(x: np.ndarray) -> np.ndarray:
        w, c, X = x[:24].reshape(8, 3), x[24:48].reshape(8, 3), x[48:].reshape(-1, 3)
        R = rodrigues(w) @ given
        y = np.einsum("oij,oj->oi", R[tracks.camera], X[tracks.point] - c[tracks.camera])
        uv = F * y[:, :2] / y[:, 2:3] + [W / 2, H / 2]
        return np.concatenate([(uv - tracks.uv).ravel(), (w / np.radians(rotation_sigma_deg)[:, None]).ravel(),
                               ((c - given_centres) / position_sigma[:, None]).ravel()])

    start = np.concatenate([np.zeros(24), given_centres.ravel(), tracks.points.ravel()])
    reference = least_squares(residuals, start, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    R_reference = rodrigues(reference.x[:24].reshape(8, 3)) @ given
    assert angles_deg(ours.cam_from_world[:, :, :3], R_reference).max() < 1e-3
    assert np.abs(centres_of(ours.cam_from_world) - reference.x[24:48].reshape(8, 3)).max() < 1e-5
    # The held camera: where it started, to a hundredth of a millimetre and a thousandth of a degree;
    # the others moved towards the truth by millimetres to centimetres.
    assert np.abs(centres_of(ours.cam_from_world)[0] - given_centres[0]).max() < 1e-5
    assert angles_deg(ours.cam_from_world[:1, :, :3], given[:1]).max() < 1e-3
    assert np.abs(centres_of(ours.cam_from_world)[1:] - given_centres[1:]).max() > 5e-3


def test_rotations_and_their_logarithm_match_opencv():
    import cv2

    from engine.poses.adjust import log_rotations

    rng = np.random.default_rng(2)
    w = rng.normal(size=(40, 3))
    w *= (np.linspace(1e-8, 3.1, 40) / np.linalg.norm(w, axis=1))[:, None]  # from a hair to nearly 180 deg
    opencv = np.stack([cv2.Rodrigues(v)[0] for v in w])
    np.testing.assert_allclose(rodrigues(w), opencv, atol=1e-12)
    np.testing.assert_allclose(log_rotations(opencv), w, atol=1e-9)
