"""PatchMatch stereo for one reference view: a depth and a slanted plane per pixel.

The scheme of ACMM (Xu & Tao, CVPR 2019), vectorised so the same code runs on CPU and CUDA:
- red-black checkerboard: the pixels of one colour are updated at once from the other colour's
  planes, so a good plane crosses the image in a few iterations;
- adaptive propagation: from each of 8 areas around the pixel (4 short V-shapes, 4 long lines) the
  neighbour plane with the lowest cost is a candidate;
- per-pixel view selection: a source counts for a pixel when several candidates match well in it and
  few match badly (an occluded or unrelated source does neither), weighted by how well they match;
- random refinement: the chosen plane, its depth perturbed, its normal perturbed, both, and a random
  plane, with perturbations that shrink every iteration;
- the cost of a plane is the view-weighted mean of its per-source costs (plane_cost.py), which adds
  the geometric-consistency term when the sources carry depth maps.

`PlaneState` holds a reference's planes at one scale; `patchmatch_iterations` improves it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch
import torch.nn.functional as F
from torch import Tensor

from ..jobs import CancelToken, check
from .plane_cost import MAX_COST, ReferenceWindows, SourceViews, plane_costs, plane_depth, random_normals
from .stage_clock import stage

# The 8 propagation areas (dv, du) of ACMM: every offset has an odd |dv| + |du|, so it lies on the
# other colour of the checkerboard.
_NEAR = [(-1, 0), (-2, -1), (-2, 1), (-3, 0), (-3, -2), (-3, 2), (-4, -1), (-4, 1)]
_FAR = [(-k, 0) for k in range(1, 24, 2)]


def _rotations(offsets: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """The area pointing up and its three quarter turns (left, down, right)."""
    turns = [offsets]
    for _ in range(3):
        turns.append([(-du, dv) for dv, du in turns[-1]])
    return turns


PROPAGATION_AREAS: list[list[tuple[int, int]]] = _rotations(_NEAR) + _rotations(_FAR)

GOOD_COST_START = 0.8  # ACMM: a source matches a candidate well below this cost at the first iteration...
GOOD_COST_DECAY = 4.0  # ...and the bar lowers as exp(-t^2 / decay) over iterations t
GOOD_COST_FLOOR = 0.4
BAD_COST = 1.2  # a source matches a candidate badly above this
MIN_GOOD = 2  # a source counts when at least this many candidates match well in it...
MAX_BAD = 3  # ...and at most this many badly
VIEW_SIGMA = 0.3  # a good match's weight exp(-cost^2 / (2 sigma^2))
DEPTH_PERTURBATION = 0.05  # relative depth perturbation of the first refinement, halved every iteration
NORMAL_PERTURBATION_DEG = 30.0  # normal perturbation of the first refinement, halved every iteration


@dataclass
class PlaneState:
    """The planes of one reference at one scale; flat arrays over the H * W pixels."""

    depth: Tensor  # (HW,) metres along the pixel ray (planar z), > 0
    normal: Tensor  # (HW, 3) unit, reference camera coordinates, facing the camera
    costs: Tensor  # (S, HW) per-source cost of the current plane
    cost: Tensor  # (HW,) aggregated (view-weighted) cost of the current plane
    view_weights: Tensor  # (S, HW) the view selection of the last update
    prior_depth: Optional[Tensor] = None  # (HW,) the planar prior's depth (planar_prior.py), 0 where none; None when off

    @property
    def rho(self) -> Tensor:
        """(HW,) the plane offset n . X of each pixel's plane."""
        return self.depth * (self.normal * self._rays).sum(-1)

    _rays: Tensor = None  # type: ignore[assignment]  # (HW, 3) set by `initial_state`


def _checker(height: int, width: int, device: torch.device) -> tuple[Tensor, Tensor]:
    """Flat pixel indices of the two checkerboard colours."""
    v, u = torch.meshgrid(torch.arange(height, device=device), torch.arange(width, device=device), indexing="ij")
    colour = ((u + v) % 2).reshape(-1)
    flat = torch.arange(height * width, device=device)
    return flat[colour == 0], flat[colour == 1]


def aggregate(costs: Tensor, weights: Tensor) -> Tensor:
    """(..., N) view-weighted mean of per-source costs (..., S, N) with weights (S, N); where no
    source is selected, the mean of the best half of the sources (robust to occluders)."""
    total = weights.sum(0)
    weighted = (costs * weights).sum(-2) / total.clamp_min(1e-9)
    k = max(1, (costs.shape[-2] + 1) // 2)
    fallback = costs.topk(k, dim=-2, largest=False).values.mean(-2)
    return torch.where(total > 1e-9, weighted, fallback)


def select_views(candidate_costs: Tensor, iteration: int, previous: Optional[Tensor] = None) -> Tensor:
    """(S, N) view weights from the per-source costs (C, S, N) of C candidate planes (ACMM's rule).

    A source is selected where at least MIN_GOOD candidates match well in it and at most MAX_BAD
    badly; its weight is the mean confidence exp(-cost^2 / 2 sigma^2) of its good matches. A source
    selected at the pixel's previous update keeps a share of its old weight (ACMM's view prior).
    """
    good_bar = max(GOOD_COST_FLOOR, GOOD_COST_START * math.exp(-iteration ** 2 / GOOD_COST_DECAY))
    good = candidate_costs < good_bar
    bad = candidate_costs > BAD_COST
    selected = (good.sum(0) >= MIN_GOOD) & (bad.sum(0) <= MAX_BAD)
    confidence = torch.exp(-candidate_costs ** 2 / (2 * VIEW_SIGMA ** 2)) * good
    weights = confidence.sum(0) / good.sum(0).clamp_min(1)
    weights = torch.where(selected, weights, torch.zeros_like(weights))
    if previous is not None:
        weights = weights + 0.2 * previous
    return weights


def initial_state(ref: ReferenceWindows, sources: SourceViews, depth_range: tuple[float, float],
                  generator: torch.Generator, depth: Optional[Tensor] = None, normal: Optional[Tensor] = None,
                  geometric_weight: float = 0.0) -> PlaneState:
    """Planes to start from: `depth` (HW,) and `normal` (HW, 3) where given (> 0), random elsewhere
    (depth uniform in inverse depth over `depth_range`, normal within 60 deg of facing the camera)."""
    HW = ref.height * ref.width
    dtype, device = ref.image.dtype, ref.image.device
    near, far = depth_range
    inv = 1.0 / far + torch.rand(HW, dtype=dtype, device=device, generator=generator) * (1.0 / near - 1.0 / far)
    random_depth = 1.0 / inv
    random_normal = random_normals(HW, ref.rays, generator, 60.0)
    if depth is None:
        depth = random_depth
    else:
        depth = torch.where(depth > 0, depth, random_depth)
    if normal is None:
        normal = random_normal
    else:
        ok = (normal.norm(dim=-1) > 0.5) & ((normal * ref.rays).sum(-1) < 0)
        normal = torch.where(ok[:, None], normal, random_normal)
    pixels = torch.arange(HW, device=device)
    costs = plane_costs(ref, sources, pixels, depth[None], normal[None], geometric_weight)[0]
    weights = select_views(costs[None].expand(MIN_GOOD, *costs.shape), 0)
    state = PlaneState(depth, normal, costs, aggregate(costs, weights), weights)
    state._rays = ref.rays
    return state


def _area_groups() -> list[tuple[int, int, int]]:
    """(first row, areas, neighbours per area) of each run of consecutive equal-sized areas in the
    concatenated offsets: the 4 short areas of 8 and the 4 long ones of 12."""
    groups: list[tuple[int, int, int]] = []
    row = 0
    for area in PROPAGATION_AREAS:
        if groups and groups[-1][2] == len(area):
            first, count, size = groups[-1]
            groups[-1] = (first, count + 1, size)
        else:
            groups.append((row, 1, len(area)))
        row += len(area)
    return groups


_AREA_GROUPS = _area_groups()


def _area_neighbours(ref: ReferenceWindows, pixels: Tensor) -> tuple[Tensor, Tensor]:
    """The flat indices (A, N) of every propagation area's neighbours of `pixels` (the areas' offsets
    concatenated, A = 80; H * W where the neighbour lies outside the image) and whether each area (8, N)
    has one inside; computed once per reference and checkerboard colour, since the same pixels are
    updated every iteration."""
    cache = ref.__dict__.setdefault("_area_neighbours", {})
    # A checkerboard colour or a subset of one (the planar prior's pixels): told apart by their count,
    # ends and sum, so a subset never reads a colour's neighbours.
    key = (int(pixels[0]) if len(pixels) else -1, int(pixels[-1]) if len(pixels) else -1, int(pixels.shape[0]),
           int(pixels.sum()))
    if key not in cache:
        H, W = ref.height, ref.width
        v, u = pixels // W, pixels % W
        offsets = torch.tensor([o for area in PROPAGATION_AREAS for o in area], device=pixels.device)  # (A, 2) (dv, du)
        nv, nu = v[None] + offsets[:, :1], u[None] + offsets[:, 1:]  # (A, N)
        inside = (nv >= 0) & (nv < H) & (nu >= 0) & (nu < W)
        area_has_one = torch.cat([inside[first:first + count * size].reshape(count, size, -1).any(1)
                                  for first, count, size in _AREA_GROUPS])
        # Outside the image a neighbour reads the slot past the last pixel, which holds a prohibitive cost.
        cache[key] = (torch.where(inside, nv.clamp(0, H - 1) * W + nu.clamp(0, W - 1), H * W), area_has_one)
    return cache[key]


def _propagation_candidates(state: PlaneState, ref: ReferenceWindows, pixels: Tensor) -> tuple[Tensor, Tensor]:
    """For each of the 8 areas, the lowest-cost neighbour plane re-expressed at `pixels`:
    depths (8, N) (0 where none) and normals (8, N, 3)."""
    neighbour, found = _area_neighbours(ref, pixels)
    N = int(pixels.shape[0])
    cost = torch.cat([state.cost, state.cost.new_full((1,), 10.0)])[neighbour]  # (A, N)
    best = []
    for first, count, size in _AREA_GROUPS:
        rows = slice(first, first + count * size)
        # min(1).indices, not argmin: argmin over a middle axis is ~5x slower on the CPU (measured).
        pick = cost[rows].reshape(count, size, N).min(1).indices  # (count, N)
        best.append(neighbour[rows].reshape(count, size, N).gather(1, pick[:, None])[:, 0])
    best_t = torch.cat(best).clamp_max(state.depth.shape[0] - 1)  # (8, N); an area with none inside is masked below
    normals = state.normal[best_t]  # (8, N, 3)
    rho = state.rho[best_t]  # (8, N) the neighbours' plane offsets
    rays = ref.rays[pixels]
    depths = plane_depth(normals.reshape(-1, 3), rho.reshape(-1),
                         rays[None].expand(len(best_t), -1, -1).reshape(-1, 3)).reshape(best_t.shape)
    return torch.where(found, depths, torch.zeros_like(depths)), normals


def _refinement_candidates(state: PlaneState, ref: ReferenceWindows, pixels: Tensor, iteration: int,
                           depth_range: tuple[float, float], generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Perturbed and random planes around the current ones at `pixels`: depths (4, N), normals (4, N, 3)."""
    N = int(pixels.shape[0])
    dtype, device = state.depth.dtype, state.depth.device
    rays = ref.rays[pixels]
    depth, normal = state.depth[pixels], state.normal[pixels]
    scale = 0.5 ** iteration
    spread = DEPTH_PERTURBATION * scale
    perturbed_depth = depth * (1.0 + spread * (2.0 * torch.rand(N, dtype=dtype, device=device, generator=generator) - 1.0))
    perturbed_normal = random_normals(N, rays, generator, NORMAL_PERTURBATION_DEG * scale, around=normal)
    near, far = depth_range
    inv = 1.0 / far + torch.rand(N, dtype=dtype, device=device, generator=generator) * (1.0 / near - 1.0 / far)
    random_normal = random_normals(N, rays, generator, 60.0)
    depths = torch.stack([perturbed_depth, depth, perturbed_depth, 1.0 / inv])
    normals = torch.stack([normal, perturbed_normal, perturbed_normal, random_normal])
    return depths, normals


@dataclass
class PriorAt:
    """The planar prior at the pixels being updated (ACMP, Xu & Tao 2020): a candidate's aggregated cost
    c becomes the score exp(-c^2 / beta) x (gamma + exp(-dd^2 / 2 sd^2) exp(-da^2 / 2 sa^2)), highest
    wins, where dd and da are its depth's and normal's differences from the pixel's triangle plane."""

    depth: Tensor  # (N,) the prior plane's depth along each pixel's ray (> 0)
    normal: Tensor  # (N, 3) the prior plane's unit normal
    depth_sigma: float  # metres
    angle_sigma: float  # radians
    beta: float
    gamma: float

    def scores(self, costs: Tensor, depths: Tensor, normals: Tensor) -> Tensor:
        """(C, N) ACMP's score (higher is better) of C candidates with aggregated costs (C, N), depths
        (C, N) and normals (C, N, 3)."""
        depth_term = torch.exp(-(depths - self.depth[None]) ** 2 / (2 * self.depth_sigma ** 2))
        angle = torch.arccos((normals * self.normal[None]).sum(-1).clamp(-1.0, 1.0))
        angle_term = torch.exp(-angle ** 2 / (2 * self.angle_sigma ** 2))
        return torch.exp(-costs ** 2 / self.beta) * (self.gamma + depth_term * angle_term)


def _update(state: PlaneState, ref: ReferenceWindows, sources: SourceViews, pixels: Tensor, depths: Tensor,
            normals: Tensor, iteration: int, geometric_weight: float, reselect_views: bool,
            prior: Optional[PriorAt] = None) -> None:
    """Score candidate planes (C, N) at `pixels` and keep, per pixel, the best of them and the current
    plane: the lowest aggregated cost, or with a `prior` the highest ACMP score."""
    C, N = depths.shape
    costs = plane_costs(ref, sources, pixels, depths, normals, geometric_weight)  # (C, S, N)
    current = state.costs[:, pixels]  # (S, N)
    if reselect_views:
        weights = select_views(torch.cat([costs, current[None]]), iteration, state.view_weights[:, pixels])
        state.view_weights[:, pixels] = weights
    else:
        weights = state.view_weights[:, pixels]
    scores = aggregate(torch.cat([current[None], costs]), weights)  # (C + 1, N)
    scores = torch.where(torch.cat([torch.ones_like(depths[:1]), depths]) > 0, scores, torch.full_like(scores, 10.0))
    if prior is None:
        best = scores.min(0).indices  # 0 = keep the current plane (min, not argmin: see _propagation_candidates)
    else:
        all_depths = torch.cat([state.depth[pixels][None], depths])
        all_normals = torch.cat([state.normal[pixels][None], normals])
        best = prior.scores(scores, all_depths, all_normals).argmax(0)
    changed = best > 0
    pick = (best - 1).clamp_min(0)
    index = torch.arange(N, device=pixels.device)
    at = pixels[changed]
    state.depth[at] = depths[pick, index][changed]
    state.normal[at] = normals[pick, index][changed]
    state.costs[:, at] = costs[pick, :, index][changed].T
    state.cost[pixels] = scores.gather(0, best[None])[0]


def patchmatch_iterations(state: PlaneState, ref: ReferenceWindows, sources: SourceViews, depth_range: tuple[float, float],
                          iterations: int, generator: torch.Generator, geometric_weight: float = 0.0,
                          first_iteration: int = 0, cancel: Optional[CancelToken] = None) -> PlaneState:
    """Improve `state` in place by `iterations` red-black sweeps of propagation and refinement.

    `first_iteration` sets where the shrinking schedules (good-match bar, perturbation sizes) start:
    a finer scale continues from the coarser one's count instead of starting over.
    """
    colours = _checker(ref.height, ref.width, state.depth.device)
    for t in range(first_iteration, first_iteration + iterations):
        for pixels in colours:
            check(cancel)
            with stage("propagation"):
                depths, normals = _propagation_candidates(state, ref, pixels)
            with stage("selection"):
                _update(state, ref, sources, pixels, depths, normals, t, geometric_weight, reselect_views=True)
            with stage("refinement"):
                depths, normals = _refinement_candidates(state, ref, pixels, t, depth_range, generator)
            with stage("selection"):
                _update(state, ref, sources, pixels, depths, normals, t, geometric_weight, reselect_views=False)
    return state


def rescore(state: PlaneState, ref: ReferenceWindows, sources: SourceViews, geometric_weight: float,
            iteration: int) -> PlaneState:
    """The state's planes scored anew against `sources` (e.g. once their depth maps are known)."""
    pixels = torch.arange(ref.height * ref.width, device=state.depth.device)
    state.costs = plane_costs(ref, sources, pixels, state.depth[None], state.normal[None], geometric_weight)[0]
    state.view_weights = select_views(state.costs[None].expand(MIN_GOOD, *state.costs.shape), iteration,
                                      state.view_weights)
    state.cost = aggregate(state.costs, state.view_weights)
    return state


def upsample_planes(state: PlaneState, from_size: tuple[int, int], to_ref: ReferenceWindows) -> tuple[Tensor, Tensor]:
    """A coarser scale's planes (depth, normal) carried to a finer reference's pixels: each fine pixel
    takes its coarse pixel's plane (same camera, so the plane n . X = rho carries over; only the
    intrinsics change), re-intersected with the fine pixel's ray. Returns depth (HW,), normal (HW, 3)."""
    h, w = from_size
    rho = state.rho.reshape(1, 1, h, w)
    normal = state.normal.T.reshape(1, 3, h, w)
    size = (to_ref.height, to_ref.width)
    rho_f = F.interpolate(rho, size=size, mode="nearest").reshape(-1)
    normal_f = F.interpolate(normal, size=size, mode="nearest").reshape(3, -1).T
    return plane_depth(normal_f, rho_f, to_ref.rays), normal_f


def final_cost(state: PlaneState) -> Tensor:
    """(HW,) the aggregated cost, MAX_COST where no source was usable."""
    return state.cost.clamp(0.0, MAX_COST)
