"""ACMP's planar prior (engine/stereo/planar_prior.py) against exact geometry: the support points and
triangle planes against a brute-force computation, a floor with a textureless patch rendered by ray
casting (no engine code) where plain PatchMatch leaves the patch wrong and the prior fills it, and the
depth filter's rule for the prior's depths."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial import Delaunay

from engine.geometry.cameras import look_at
from engine.stereo.depth_maps import DepthMap, keep_confirmed, prior_candidates
from engine.stereo.patchmatch import PlaneState
from engine.stereo.patchmatch_views import PatchMatchSchedule, PlaneMap, photometric_planes
from engine.stereo.planar_prior import SUPPORT_AGREEMENT, SUPPORT_COST, planar_prior, support_points
from engine.stereo.plane_cost import MIN_SOURCE_VARIANCE, ReferenceWindows

SIZE = (96, 72)  # (w, h)
FOCAL = 80.0
K = np.array([[FOCAL, 0, SIZE[0] / 2], [0, FOCAL, SIZE[1] / 2], [0, 0, 1]])
FLAT = (-0.45, 0.45, 1.3, 2.3)  # world x0, x1, y0, y1 of the textureless patch on the floor


def _pixel_rays(K: np.ndarray) -> np.ndarray:
    """(h * w, 3) rays through the pixel centres, z = 1."""
    w, h = SIZE
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return (np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])).T


def test_support_points_are_each_cells_lowest_cost_below_the_bar() -> None:
    rng = np.random.default_rng(0)
    h, w, cell = 23, 31, 5
    cost = rng.uniform(0.0, 0.4, (h, w)).astype(np.float32)
    found = set(support_points(torch.as_tensor(cost.reshape(-1)), h, w, cell, 0.1).tolist())
    expected = set()
    for r in range(0, h, cell):  # ACMP's loop (GetSupportPoints), cells cut at the image's edge
        for c in range(0, w, cell):
            block = cost[r:r + cell, c:c + cell]
            i = int(np.argmin(block))
            if block.flat[i] < 0.1:
                expected.add((r + i // block.shape[1]) * w + c + i % block.shape[1])
    assert found == expected and len(found) > 5


def _two_plane_state() -> tuple[PlaneState, ReferenceWindows, np.ndarray, np.ndarray]:
    """A reference seeing two walls meeting in a corner 74 deg wide down the middle of the image (the
    left half one wall, the right half the other), with their exact depths and normals, confident (cost
    0.01) at scattered pixels and unsure (1.0) elsewhere. Returns the state, its windows, the true depth
    (HW,) and which pixels are the left wall (HW,)."""
    rays = _pixel_rays(K)
    wall_n, wall_rho = np.array([0.6, 0.0, -0.8]), -2.0  # n . X = rho, facing the camera
    floor_n, floor_rho = np.array([-0.6, 0.0, -0.8]), -2.0  # they meet at x = 0
    u = (np.arange(rays.shape[0]) % SIZE[0])
    wall = u < SIZE[0] // 2
    normal = np.where(wall[:, None], wall_n, floor_n)
    depth = np.where(wall, wall_rho, floor_rho) / np.sum(normal * rays, axis=1)
    rng = np.random.default_rng(2)
    cost = np.where(rng.random(rays.shape[0]) < 0.3, 0.01, 1.0)
    f = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    windows = ReferenceWindows(f(rng.random((SIZE[1], SIZE[0]))), f(K), 9)
    state = PlaneState(f(depth), f(normal), torch.zeros((1, rays.shape[0])), f(cost), torch.ones((1, rays.shape[0])))
    state._rays = windows.rays
    return state, windows, depth, wall


def test_the_prior_planes_match_an_independent_plane_fit_and_no_triangle_bridges_the_two_planes() -> None:
    state, windows, depth, wall = _two_plane_state()
    prior = planar_prior(state, windows, (0.3, 8.0))
    assert prior is not None
    got = prior.depth.numpy()
    # Independently: the same supports, scipy's Delaunay, and each triangle's plane as the null space of
    # [X 1] (ACMP's GetPriorPlaneParams), intersected with the pixel's ray; the pixel must lie in (or
    # within a pixel of: a pixel on a shared edge may take either) a triangle whose plane gives its depth.
    textured = torch.where(windows.variance > MIN_SOURCE_VARIANCE, state.cost, torch.full_like(state.cost, np.inf))
    supports = support_points(textured, SIZE[1], SIZE[0], margin=4).numpy()  # half the 9 px window
    rays = _pixel_rays(K)
    uv = np.stack([supports % SIZE[0], supports // SIZE[0]], axis=1).astype(np.float64)
    simplices = Delaunay(uv).simplices  # (T, 3)
    points = depth[supports][:, None] * rays[supports]
    planes = np.stack([np.linalg.svd(np.hstack([points[t], np.ones((3, 1))]))[2][-1] for t in simplices])  # (T, 4)
    corners = uv[simplices]  # (T, 3, 2)
    edges = np.roll(corners, -1, axis=1) - corners
    orientation = np.sign(np.cross(edges[:, 0], edges[:, 1]))  # (T,)
    covered = got > 0
    pixel_uv = np.stack([np.arange(got.size) % SIZE[0], np.arange(got.size) // SIZE[0]], axis=1)[covered].astype(np.float64)
    # Signed distance of each pixel to each edge, positive inside: (P, T, 3).
    offset = pixel_uv[:, None, None, :] - corners[None]
    distance = orientation[None, :, None] * np.cross(edges[None], offset) / np.linalg.norm(edges, axis=-1)[None]
    near = (distance >= -1.0).all(-1)  # (P, T)
    plane_depths = -planes[None, :, 3] / (rays[covered] @ planes[:, :3].T)  # (P, T)
    match = near & (np.abs(plane_depths - got[covered][:, None]) < 1e-4 * got[covered][:, None])
    assert match.any(1).all(), "every prior depth is the plane of a triangle the pixel lies in"
    hull = Delaunay(uv).find_simplex(np.stack([np.arange(got.size) % SIZE[0], np.arange(got.size) // SIZE[0]], 1)) >= 0
    assert covered.sum() > 0.7 * hull.sum(), "most of the supports' hull has a prior"
    # The kept triangles lie on one of the two planes, or, across the crease, within SUPPORT_AGREEMENT
    # of the truth where confident pixels are: a triangle they contradict is dropped.
    error = np.abs(got[covered] - depth[covered]) / depth[covered]
    assert np.mean(error < 1e-4) > 0.9 and np.mean(error < SUPPORT_AGREEMENT) > 0.99, (np.mean(error < 1e-4), np.mean(error < SUPPORT_AGREEMENT))
    assert prior.depth_sigma == pytest.approx((8.0 - 0.3) / 64)


def floor_with_a_flat_patch(count: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Cameras 1.2 m above a floor (z = 0) with a random texture except for a uniform grey patch
    (FLAT), looking 40 deg down along +y, side by side: images (count, h, w), poses (count, 4, 4)."""
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.random((512, 512)).astype(np.float32), (0, 0), 3.0)
    texture = (texture - texture.min()) / (texture.max() - texture.min())
    to_texture = lambda x, y: ((x + 3.0) / 6.0 * 511, (y + 0.5) / 6.0 * 511)  # noqa: E731
    (c0, r0), (c1, r1) = to_texture(FLAT[0], FLAT[2]), to_texture(FLAT[1], FLAT[3])
    texture[int(r0):int(r1) + 1, int(c0):int(c1) + 1] = 0.5
    w, h = SIZE
    images, poses = [], []
    for i in range(count):
        eye = np.array([0.1 * (i - count // 2), 0.03 * i, 1.2])
        pose = look_at(eye, eye + np.array([0.0, 1.0, -np.tan(np.radians(40))]))
        rays = pose[:3, :3] @ _pixel_rays(K).T
        world = eye[:, None] + rays * (-eye[2] / rays[2])
        tx, ty = to_texture(world[0], world[1])
        images.append(cv2.remap(texture, tx.astype(np.float32).reshape(h, w), ty.astype(np.float32).reshape(h, w),
                                cv2.INTER_LINEAR))
        poses.append(pose)
    return np.stack(images), np.stack(poses)


def _floor_truth(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) planar depth of the floor in the view, and (h, w) bool: pixels well inside the flat patch
    (its every 9 x 9 window flat at the finest scale)."""
    w, h = SIZE
    rays = pose[:3, :3] @ _pixel_rays(K).T
    depth = -pose[2, 3] / rays[2]
    world = pose[:3, 3:4] + rays * depth
    x0, x1, y0, y1 = FLAT
    on_patch = ((world[0] > x0) & (world[0] < x1) & (world[1] > y0) & (world[1] < y1)).reshape(h, w)
    inner = cv2.erode(on_patch.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0  # a 9 x 9 window and a pixel to spare
    return depth.reshape(h, w), inner


def test_the_prior_fills_a_textureless_patch_that_plain_patchmatch_leaves_wrong() -> None:
    images, poses = floor_with_a_flat_patch()
    ref, srcs = 2, [0, 1, 3, 4]
    depth, flat = _floor_truth(poses[ref])
    assert flat.sum() > 150, "the patch covers a few hundred pixels"

    def run(prior: bool) -> PlaneState:
        state, _ = photometric_planes(
            torch.as_tensor(images[ref]), K, poses[ref], [torch.as_tensor(images[s]) for s in srcs], [K] * len(srcs),
            [poses[s] for s in srcs], (0.5, 6.0), PatchMatchSchedule(planar_prior=prior), torch.device("cpu"))
        return state

    plain, with_prior = run(False), run(True)
    # Within 2 %: the patch's planes are interpolated from supports around it, each right to about 1 % at
    # this size (96 px) and 2-3 m.
    good = lambda s: (np.abs(s.depth.reshape(depth.shape).numpy() - depth) / depth < 0.02)  # noqa: E731
    assert plain.prior_depth is None
    assert good(plain)[flat].mean() < 0.5, "no window on the patch tells one plane from another"
    assert good(with_prior)[flat].mean() > 0.9, "the patch takes the plane of the floor around it"
    prior = with_prior.prior_depth.reshape(depth.shape).numpy()
    assert np.mean(prior[flat] > 0) > 0.9, "the prior covers the patch"
    has = flat & (prior > 0)
    assert np.mean(np.abs(prior[has] - depth[has]) < 0.02 * depth[has]) > 0.95, "the prior itself is the floor's plane"
    # The textured floor keeps its own planes.
    textured = ~flat & (images[ref] != 0.5)
    textured[:8], textured[-8:], textured[:, :8], textured[:, -8:] = False, False, False, False
    assert good(with_prior)[textured].mean() >= good(plain)[textured].mean() - 0.02
    # The patch's own cost stays high: the depth filter, not the cost, must decide to keep it.
    assert float(with_prior.cost.reshape(depth.shape)[torch.as_tensor(flat)].median()) > SUPPORT_COST


def test_the_filter_keeps_prior_depths_on_their_plane_that_two_views_confirm() -> None:
    images, poses = floor_with_a_flat_patch()
    maps, candidates = [], []
    for i, pose in enumerate(poses):
        depth, _ = _floor_truth(pose)
        up = pose[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        normals = np.broadcast_to(up, (*depth.shape, 3)).astype(np.float32).copy()
        cost = np.full(depth.shape, 0.1, np.float32)
        cost[20:50, 30:70] = 1.0  # the photometric filter (cost <= 0.5) drops this block
        prior = np.zeros(depth.shape, np.float32)
        prior[20:50, 30:70] = depth[20:50, 30:70]
        found = depth.astype(np.float32).copy()
        if i == 2:
            found[20:30, 30:40] *= 1.05  # off its prior plane: not a prior depth
            found[40:50, 60:70] *= 1.015  # on its prior plane, but 1.5 % from what the others see
            prior[40:50, 60:70] *= 1.015
        plane = PlaneMap(found, normals, cost, prior)
        photometric = cost <= 0.5
        candidate = prior_candidates(plane, photometric)
        assert not candidate[photometric].any()
        candidates.append(candidate)
        kept = photometric | candidate
        maps.append(DepthMap(i, np.where(kept, found, 0).astype(np.float32), kept.astype(np.float32), K, pose,
                             np.zeros(0, np.int64), (0.5, 6.0), normal=normals))
    no_prior = PlaneMap(maps[0].depth, maps[0].normal, np.ones_like(maps[0].depth))
    assert not prior_candidates(no_prior, np.zeros(maps[0].depth.shape, bool)).any()
    middle = maps[2]
    assert np.all(middle.depth[20:30, 30:40] == 0), "a depth off its prior plane is not kept"
    keep_confirmed(maps, candidates, 2)
    assert np.all(middle.depth[40:50, 60:70] == 0), "a prior depth no other view confirms is dropped"
    assert np.mean(middle.depth[30:40, 40:60] > 0) > 0.9, "the rest of the block, seen alike by its neighbours, is kept"
    assert np.all(middle.depth[:10] > 0), "photometric depths are not judged by the prior's rule"


def test_the_option_is_off_by_default_and_validated() -> None:
    from engine.errors import VortxError
    from engine.stereo.options import StereoOptions
    assert StereoOptions().planar_prior is False and PatchMatchSchedule().planar_prior is False
    StereoOptions(planar_prior=True).validate()
    with pytest.raises(VortxError, match="planar prior"):
        StereoOptions(planar_prior="yes").validate()  # type: ignore[arg-type]
    # The prior's iterations count in the photometric stage's, where the geometric passes go on from.
    assert PatchMatchSchedule(planar_prior=True).photometric_iterations() == PatchMatchSchedule().photometric_iterations() + 2
