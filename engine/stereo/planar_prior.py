"""ACMP's planar prior for PatchMatch (Xu & Tao, "Planar Prior Assisted PatchMatch Multi-View Stereo",
AAAI 2020): fills weakly textured walls and floors, where no window matches better than another.

After the photometric PatchMatch of a reference (patchmatch_views.photometric_planes):
- support points: in every SUPPORT_CELL x SUPPORT_CELL cell of the image, the pixel of lowest cost,
  when that cost is below SUPPORT_COST (ACMP: 5 px cells, cost 0.1), its window textured and whole;
- a Delaunay triangulation of them in the image, and for each triangle the plane through its three
  3D points; a triangle is kept only where that plane is supported: seen well away from edge-on
  (a triangle that bridges a depth jump, from a chair to the wall behind it, is seen nearly edge-on)
  and not contradicted by the confident pixels inside it (a triangle across a room's corner or an
  object's edge has them off its plane);
- every pixel inside a kept triangle, whose own cost is not already a support's, starts again from
  its triangle's plane and runs `prior_iterations` more PatchMatch iterations in which a candidate's
  score is ACMP's: the photometric likelihood exp(-cost^2 / beta) times the prior
  gamma + exp(-depth difference^2 / 2 sd^2) exp(-angle^2 / 2 sa^2) from the triangle's plane
  (patchmatch.PriorAt), so a textureless pixel keeps its triangle's plane unless a candidate matches
  clearly better, and a textured one is free to leave it.

The prior's depth is kept with the planes (PlaneState.prior_depth): the depth filter
(depth_maps._patchmatch_maps) keeps a pixel whose cost is too high for the photometric filter when
its depth lies on its prior plane and other views confirm it (ACMP's fusion keeps what 2 views confirm).

Tensors: flat over the H * W pixels of the reference at the stereo size; depths metres (planar z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np
import torch
from torch import Tensor

from ..jobs import CancelToken, check
from .patchmatch import (MIN_GOOD, PlaneState, PriorAt, _checker, _propagation_candidates, _update, aggregate,
                         select_views)
from .plane_cost import MIN_SOURCE_VARIANCE, ReferenceWindows, SourceViews, plane_costs, plane_depth, random_normals
from .stage_clock import stage

SUPPORT_CELL = 5  # pixels: one support point per cell (ACMP: 5)
# A support point's highest aggregated cost (1 - NCC). ACMP's 0.1 is at full resolution with 11 x 11
# windows; at 200 px with 9 x 9 windows sampled every 2nd pixel the costs of good matches run higher.
SUPPORT_COST = 0.15
SUPPORT_MIN_COS = 0.2  # a triangle's plane must face the camera within ~78 deg at its centroid
SUPPORT_AGREEMENT = 0.02  # and the confident pixels inside it lie within 2 % of its plane (at most a third off)
# ACMP's prior: gamma + exp(-dd^2 / 2 sd^2) exp(-da^2 / 2 sa^2) with sd = depth range / 64, sa = 5 deg,
# times the likelihood exp(-cost^2 / beta), beta = 0.18.
PRIOR_GAMMA = 0.5
PRIOR_BETA = 0.18
PRIOR_DEPTH_SIGMA_STEPS = 64.0
PRIOR_ANGLE_SIGMA_DEG = 5.0
PRIOR_PERTURBATION = 0.02  # ACMP's refinement: depth +-2 %, normal within 0.02 pi (3.6 deg) of the current plane


@dataclass
class PlanarPrior:
    """One reference's prior planes, flat over its H * W pixels."""

    depth: Tensor  # (HW,) the pixel's triangle plane's depth along its ray, 0 where no kept triangle covers it
    normal: Tensor  # (HW, 3) that plane's unit normal (camera coordinates, facing the camera); 0 where none
    depth_sigma: float  # metres: the prior's depth falloff

    def at(self, pixels: Tensor) -> PriorAt:
        return PriorAt(self.depth[pixels], self.normal[pixels], self.depth_sigma, math.radians(PRIOR_ANGLE_SIGMA_DEG),
                       PRIOR_BETA, PRIOR_GAMMA)


def support_points(cost: Tensor, height: int, width: int, cell: int = SUPPORT_CELL,
                   max_cost: float = SUPPORT_COST, margin: int = 0) -> Tensor:
    """(P,) flat pixel indices of the support points: each cell's lowest-cost pixel, where below `max_cost`,
    among the pixels at least `margin` pixels from the image's edge. cost: (H * W,) aggregated cost per pixel."""
    rows, cols = -(-height // cell), -(-width // cell)
    padded = torch.full((rows * cell, cols * cell), math.inf, dtype=cost.dtype, device=cost.device)
    padded[margin:height - margin, margin:width - margin] = cost.reshape(height, width)[margin:height - margin,
                                                                                        margin:width - margin]
    cells = padded.reshape(rows, cell, cols, cell).permute(0, 2, 1, 3).reshape(rows, cols, cell * cell)
    lowest, where = cells.min(-1)  # (rows, cols)
    r = torch.arange(rows, device=cost.device)[:, None] * cell + where // cell
    c = torch.arange(cols, device=cost.device)[None, :] * cell + where % cell
    keep = lowest < max_cost  # padding is +inf: never kept
    return (r * width + c)[keep]


def triangle_planes(points: Tensor) -> tuple[Tensor, Tensor]:
    """Planes n . X = rho through triangles of 3D points (T, 3, 3) (camera coordinates): unit normals
    (T, 3) facing the camera (n . X < 0 on the plane, so rho < 0) and rho (T,); normal 0 for a degenerate
    triangle."""
    cross = torch.linalg.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0])
    length = cross.norm(dim=-1, keepdim=True)
    normal = torch.where(length > 1e-12, cross / length.clamp_min(1e-12), torch.zeros_like(cross))
    rho = (normal * points[:, 0]).sum(-1)
    flip = rho > 0
    normal = torch.where(flip[:, None], -normal, normal)
    return normal, torch.where(flip, -rho, rho)


def planar_prior(state: PlaneState, ref: ReferenceWindows, depth_range: tuple[float, float]) -> Optional[PlanarPrior]:
    """The prior planes of a reference from its PatchMatch `state` (None when fewer than 3 supports or
    none of their triangles is supported)."""
    # defers scipy: not loaded when Blender registers the add-on
    from scipy.spatial import Delaunay, QhullError

    H, W = ref.height, ref.width
    # Not within half a window of the edge: there the window is padded by repeating the edge, and a low
    # cost is no sign of a right depth (on a synthetic floor, 15 % errors at costs below 0.15).
    # And only where the window has texture enough for a source's (MIN_SOURCE_VARIANCE): a faint window
    # that matched well is a weak witness to hang a triangle of other pixels on.
    cost = torch.where(ref.variance > MIN_SOURCE_VARIANCE, state.cost, torch.full_like(state.cost, math.inf))
    supports = support_points(cost, H, W, SUPPORT_CELL, SUPPORT_COST, margin=ref.window // 2)
    if len(supports) < 3:
        return None
    centres = ref.centres[supports].cpu().numpy().astype(np.float64)
    try:
        triangulation = Delaunay(centres)
    except QhullError:  # all supports on one line
        return None
    corners = torch.as_tensor(triangulation.simplices, dtype=torch.long, device=supports.device)  # (T, 3) into supports
    pixels = supports[corners]  # (T, 3) flat pixel indices
    points = state.depth[pixels][..., None] * ref.rays[pixels]  # (T, 3, 3)
    normal, rho = triangle_planes(points)
    # Every pixel's triangle (-1 outside the supports' hull): each triangle drawn with its index (the
    # supports are pixels, so their corners are exact; a pixel on a shared edge takes either plane).
    # scipy's find_simplex took up to 17 s a view here, walking the near-regular grid of supports.
    label = np.full((H, W), -1, np.int32)
    corner_uv = torch.stack([pixels % W, pixels // W], -1).cpu().numpy().astype(np.int32)  # (T, 3, 2)
    for t, triangle in enumerate(corner_uv):
        cv2.fillConvexPoly(label, triangle, t)
    triangle = torch.as_tensor(label.reshape(-1), dtype=torch.long, device=supports.device)
    inside = triangle >= 0
    triangle = triangle.clamp_min(0)
    pixel_normal = normal[triangle]
    depth = plane_depth(pixel_normal, rho[triangle], ref.rays)
    near, far = depth_range
    inside &= (depth >= near) & (depth <= far)  # ACMP: a prior outside the depth range is no prior
    # Supported: seen well away from edge-on at the centroid (a triangle bridging a depth jump, from a
    # chair to the wall behind it, is seen nearly edge-on), and not contradicted by the confident pixels
    # inside it: at most a third of them off its plane by more than SUPPORT_AGREEMENT (a triangle across
    # a room's corner or an object's edge). The corners' own normals were tried as the test: at 200 px
    # a third of PatchMatch's normals are within 30 deg, and it dropped nearly every triangle.
    centroid = points.mean(1)
    facing = -(normal * centroid).sum(-1) / centroid.norm(dim=-1)
    confident = inside & (state.cost < SUPPORT_COST)
    off_plane = confident & ((state.depth - depth).abs() > SUPPORT_AGREEMENT * depth)
    T = int(corners.shape[0])
    confident_count = torch.bincount(triangle[confident], minlength=T)
    off_count = torch.bincount(triangle[off_plane], minlength=T)
    supported = (facing > SUPPORT_MIN_COS) & (3 * off_count <= confident_count)
    inside &= supported[triangle]
    if not bool(inside.any()):
        return None
    depth = torch.where(inside, depth, torch.zeros_like(depth))
    pixel_normal = torch.where(inside[:, None], pixel_normal, torch.zeros_like(pixel_normal))
    return PlanarPrior(depth, pixel_normal, (far - near) / PRIOR_DEPTH_SIGMA_STEPS)


def _prior_candidates(state: PlaneState, ref: ReferenceWindows, prior: PlanarPrior, pixels: Tensor,
                      generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """ACMP's refinement candidates at `pixels` (N,): a depth drawn within 3 sd of the prior's, a normal
    within sa of the prior's, and the current plane perturbed by 2 %. Depths (5, N), normals (5, N, 3)."""
    N = int(pixels.shape[0])
    dtype, device = state.depth.dtype, state.depth.device
    rays = ref.rays[pixels]
    depth, normal = state.depth[pixels], state.normal[pixels]
    prior_depth, prior_normal = prior.depth[pixels], prior.normal[pixels]
    uniform = lambda: 2.0 * torch.rand(N, dtype=dtype, device=device, generator=generator) - 1.0  # noqa: E731
    near_prior = (prior_depth + 3.0 * prior.depth_sigma * uniform()).clamp_min(1e-3)
    prior_tilted = random_normals(N, rays, generator, PRIOR_ANGLE_SIGMA_DEG, around=prior_normal)
    perturbed_depth = depth * (1.0 + PRIOR_PERTURBATION * uniform())
    perturbed_normal = random_normals(N, rays, generator, math.degrees(PRIOR_PERTURBATION * math.pi), around=normal)
    depths = torch.stack([near_prior, depth, near_prior, depth, perturbed_depth])
    normals = torch.stack([normal, prior_tilted, prior_tilted, perturbed_normal, normal])
    return depths, normals


def prior_iterations(state: PlaneState, ref: ReferenceWindows, sources: SourceViews, prior: PlanarPrior,
                     iterations: int, generator: torch.Generator, first_iteration: int,
                     cancel: Optional[CancelToken] = None) -> PlaneState:
    """Restart the pixels under the prior that are not supports from their triangle's plane, then improve
    them in place by `iterations` red-black sweeps scored with the prior (ACMP); the other pixels keep
    their planes (they are the supports and what the prior does not cover)."""
    active = (prior.depth > 0) & (state.cost >= SUPPORT_COST)
    if not bool(active.any()):
        return state
    with stage("prior initialisation"):
        # ACMP restarts them from the prior plane outright: the plane they had was chosen by a cost that
        # could not tell planes apart, so it has no claim to be kept against the prior.
        pixels = torch.nonzero(active)[:, 0]
        state.depth[pixels], state.normal[pixels] = prior.depth[pixels], prior.normal[pixels]
        costs = plane_costs(ref, sources, pixels, state.depth[pixels][None], state.normal[pixels][None])[0]  # (S, N)
        weights = select_views(costs[None].expand(MIN_GOOD, *costs.shape), first_iteration, state.view_weights[:, pixels])
        state.costs[:, pixels], state.view_weights[:, pixels] = costs, weights
        state.cost[pixels] = aggregate(costs, weights)
    colours = [c[active[c]] for c in _checker(ref.height, ref.width, state.depth.device)]
    for t in range(first_iteration, first_iteration + iterations):
        for pixels in colours:
            if not len(pixels):
                continue
            check(cancel)
            at = prior.at(pixels)
            with stage("propagation"):
                depths, normals = _propagation_candidates(state, ref, pixels)
            with stage("selection"):
                _update(state, ref, sources, pixels, depths, normals, t, 0.0, reselect_views=True, prior=at)
            with stage("refinement"):
                depths, normals = _prior_candidates(state, ref, prior, pixels, generator)
            with stage("selection"):
                _update(state, ref, sources, pixels, depths, normals, t, 0.0, reselect_views=False, prior=at)
    return state
