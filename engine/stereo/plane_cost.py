"""The matching cost of a slanted plane at a reference pixel, against each source view.

A hypothesis at reference pixel p is a plane in the reference camera's coordinates: a unit normal n
(facing the camera, n . ray < 0) and the pixel's depth d, so the plane is n . X = rho with
rho = d n . K^-1 (p + 0.5). The plane maps reference pixels to a source by the homography
H = K_s (R + t n^T / rho) K^-1 (X_s = R X + t), so the whole window around p is warped as the
surface would appear in the source, not as a fronto-parallel patch (Schoenberger et al., ECCV 2016);
across the window the homography is taken to first order about the pixel (an affine warp: hundredths
of a pixel from the projective one, a third of its cost).

The score of one source is 1 - NCC over the window, each window pixel weighted bilaterally (close in
position and in grey level to the centre, so a window straddling an edge is judged by the side of the
centre), sampled every `WINDOW_STEP` pixels (COLMAP and OpenMVS sample every 2nd pixel: the same
footprint at a quarter of the cost). A source that cannot see the plane scores `MAX_COST`.

Geometric consistency (COLMAP's, ACMM's): with the sources' own depth maps at hand, the plane's point
goes into the source, comes back along the source's depth there, and the distance in reference pixels
between where it left and where it lands (capped at `MAX_REPROJECTION_PX`) is added to that source's
cost, weighted by `geometric_weight`.

Tensors: the reference (H, W) grey in [0, 1]; pixels are flat indices into H * W; depths (N,) metres,
normals (N, 3); costs (S, N) with S sources.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch
import torch.nn.functional as F
from torch import Tensor

from .stage_clock import stage

MAX_COST = 2.0  # 1 - NCC of a source that cannot see the plane (NCC -1: the worst match)
WINDOW_STEP = 2  # window pixels sampled every 2nd pixel
SIGMA_SPATIAL = 5.0  # pixels: the bilateral weight's spatial falloff (COLMAP: 5)
SIGMA_COLOUR = 0.08  # grey level 0..1: the bilateral weight's colour falloff (COLMAP: 3 / 255 of 0..1 intensities is too strict for JPEG noise)
MIN_SOURCE_VARIANCE = 1e-5  # a warped window flatter than this has nothing to correlate
# A reference window this flat has nothing to correlate either (ACMM and ACMP check both windows): on a
# uniform window (a blank patch, a saturated lamp, clipped black) the NCC is a ratio of rounding errors
# and scored any plane, often as a near-perfect match. Far below the source's bar: a window of 8-bit grey
# levels with one texel a level off is ~6e-7, and a smooth wall's faint shading still correlates.
MIN_REFERENCE_VARIANCE = 1e-8
MAX_REPROJECTION_PX = 3.0  # the geometric term's cap (COLMAP: 3 px)
PIXEL_CHUNK = 4096  # pixels scored at once on the CPU (see plane_costs)
MIN_GRAZING_COS = 0.05  # a plane seen this close to edge-on warps the window into a line: no hypothesis


@dataclass
class SourceViews:
    """The sources one reference is matched against, at one scale."""

    images: Tensor  # (S, h, w) grey in [0, 1]; every source at the same size
    K: Tensor  # (S, 3, 3) in pixels of `images`
    rotation: Tensor  # (S, 3, 3) source-from-reference rotation
    translation: Tensor  # (S, 3) source-from-reference translation (metres)
    depths: Optional[Tensor] = None  # (S, h, w) the sources' own depth maps, for the geometric term (0 = none)

    def __len__(self) -> int:
        return int(self.images.shape[0])


class ReferenceWindows:
    """A reference view's windows, computed once per scale: sample offsets, the centred grey levels and
    bilateral weights of every pixel's window, and the rays through the pixel centres."""

    def __init__(self, image: Tensor, K: Tensor, window: int):
        with stage("windows"):
            self._build(image, K, window)

    def _build(self, image: Tensor, K: Tensor, window: int) -> None:
        if window < 3 or window % 2 == 0:
            raise ValueError(f"window must be odd and >= 3, got {window}")
        H, W = image.shape
        self.height, self.width, self.window = H, W, window
        self.image, self.K = image, K
        self.K_inv = torch.linalg.inv(K)
        half = window // 2
        steps = torch.arange(-half, half + 1, WINDOW_STEP, dtype=image.dtype, device=image.device)
        dv, du = torch.meshgrid(steps, steps, indexing="ij")
        self.offsets = torch.stack([du.reshape(-1), dv.reshape(-1)], dim=-1)  # (M, 2) (du, dv)
        padded = F.pad(image[None, None], (half, half, half, half), mode="replicate")[0, 0]
        rows = torch.arange(H, device=image.device)[:, None]
        cols = torch.arange(W, device=image.device)[None, :]
        values = torch.stack([padded[rows + half + int(v), cols + half + int(u)] for u, v in self.offsets.tolist()], dim=-1)
        values = values.reshape(H * W, -1)  # (HW, M)
        centre = image.reshape(H * W, 1)
        spatial = (self.offsets ** 2).sum(-1) / (2 * SIGMA_SPATIAL ** 2)  # (M,)
        colour = (values - centre) ** 2 / (2 * SIGMA_COLOUR ** 2)
        weights = torch.exp(-spatial[None] - colour)
        self.weights = weights / weights.sum(-1, keepdim=True)  # (HW, M), rows sum to 1
        mean = (self.weights * values).sum(-1, keepdim=True)
        self.centred = values - mean  # (HW, M)
        self.weighted_centred = self.weights * self.centred  # (HW, M): the NCC's covariance weights
        self.variance = (self.weights * self.centred ** 2).sum(-1)  # (HW,)
        u, v = torch.meshgrid(torch.arange(W, dtype=image.dtype, device=image.device) + 0.5,
                              torch.arange(H, dtype=image.dtype, device=image.device) + 0.5, indexing="xy")
        self.centres = torch.stack([u.reshape(-1), v.reshape(-1)], dim=-1)  # (HW, 2) pixel centres
        self.rays = torch.cat([self.centres, torch.ones_like(self.centres[:, :1])], -1) @ self.K_inv.T  # (HW, 3), z = 1

    def texture(self) -> Tensor:
        """(H, W) the bilateral-weighted grey-level standard deviation of each pixel's window."""
        return self.variance.clamp_min(0).sqrt().reshape(self.height, self.width)


def plane_depth(normals: Tensor, rho: Tensor, rays: Tensor) -> Tensor:
    """(N,) depth along `rays` (N, 3) (z = 1) where the planes n . X = rho meet them; 0 where the ray
    meets the plane behind the camera or nearly edge-on."""
    facing = (normals * rays).sum(-1)
    cos = -facing / rays.norm(dim=-1)
    depth = rho / torch.where(facing.abs() > 1e-9, facing, torch.full_like(facing, 1e-9))
    return torch.where((cos > MIN_GRAZING_COS) & (depth > 0), depth, torch.zeros_like(depth))


def window_warp_matrix(offsets: Tensor) -> Tensor:
    """(6, 2M) matrix taking a pixel's affine warp (the Jacobian's columns d/du, d/dv and the centre, each
    (x, y), flattened to 6) to its M window samples (x, y) at `offsets` (M, 2) (du, dv): one matrix
    product for every pixel and source, sample m at du_m J_u + dv_m J_v + c."""
    M = int(offsets.shape[0])
    weights = torch.cat([offsets, torch.ones_like(offsets[:, :1])], -1)  # (M, 3) (du, dv, 1)
    matrix = torch.zeros((3, 2, M, 2), dtype=offsets.dtype, device=offsets.device)
    for axis in range(2):
        matrix[:, axis, :, axis] = weights.T
    return matrix.reshape(6, 2 * M)


def plane_costs(ref: ReferenceWindows, sources: SourceViews, pixels: Tensor, depths: Tensor, normals: Tensor,
                geometric_weight: float = 0.0) -> Tensor:
    """(C, S, N) cost of C candidate planes at each of N pixels against each source: depths (C, N) at
    flat pixels `pixels` (N,), normals (C, N, 3). 1 - bilateral NCC, plus `geometric_weight` x the
    capped forward-backward reprojection error when the sources carry depth maps; the worst cost where
    the plane cannot be seen by the source or the hypothesis is invalid."""
    S, (C, N) = len(sources), depths.shape
    dtype = ref.image.dtype
    worst = MAX_COST + (geometric_weight * MAX_REPROJECTION_PX if sources.depths is not None else 0.0)
    if S == 0 or N == 0:
        return torch.full((C, S, N), worst, dtype=dtype, device=ref.image.device)
    h, w = sources.images.shape[-2:]
    to_grid = torch.tensor([[2.0 / w, 0.0, -1.0], [0.0, 2.0 / h, -1.0], [0.0, 0.0, 1.0]], dtype=dtype, device=ref.image.device)
    G = to_grid @ sources.K @ sources.rotation  # (S, 3, 3)
    g = (to_grid @ sources.K @ sources.translation[..., None])[..., 0]  # (S, 3)
    k0, k1 = ref.K_inv[:, 0], ref.K_inv[:, 1]
    Gk0, Gk1 = (G @ k0)[:, None, :], (G @ k1)[:, None, :]  # (S, 1, 3)
    warp_matrix = window_warp_matrix(ref.offsets)
    out = torch.empty((C, S, N), dtype=dtype, device=ref.image.device)
    # Pixels in chunks: a chunk's (S, chunk, M) intermediates stay in the CPU's cache, where the whole
    # image's (tens of MB each) went through memory at every step (measured 1.6x on 2 cores).
    chunk = N if ref.image.device.type != "cpu" else PIXEL_CHUNK
    for start in range(0, N, chunk):
        part = slice(start, min(N, start + chunk))
        at = pixels[part]
        rays = ref.rays[at]  # (n, 3)
        weights = ref.weights[at]  # (n, M), gathered once for all candidates
        weighted_centred = ref.weighted_centred[at]
        variance = ref.variance[at]
        G_rays = rays @ G.transpose(1, 2)  # (S, n, 3)
        for c in range(C):
            out[c, :, part] = _candidate_costs(ref, sources, at, rays, weights, weighted_centred, variance, G, g, G_rays,
                                               Gk0, Gk1, k0, k1, warp_matrix, depths[c, part], normals[c, part],
                                               geometric_weight, worst)
    return out


def _candidate_costs(ref: ReferenceWindows, sources: SourceViews, pixels: Tensor, rays: Tensor, weights: Tensor,
                     weighted_centred: Tensor, variance: Tensor, G: Tensor, g: Tensor, G_rays: Tensor, Gk0: Tensor,
                     Gk1: Tensor, k0: Tensor, k1: Tensor, warp_matrix: Tensor, depth: Tensor, normal: Tensor,
                     geometric_weight: float, worst: float) -> Tensor:
    """(S, n) costs of one plane per pixel (depth (n,), normal (n, 3)) at `pixels` (n,): `plane_costs`'s
    inner step, with the per-pixel and per-source terms it prepared."""
    S, N, M = len(sources), int(pixels.shape[0]), int(warp_matrix.shape[1]) // 2
    centre = M // 2
    h, w = sources.images.shape[-2:]
    with stage("warp"):
        facing = (normal * rays).sum(-1)  # n . ray (negative: the normal faces the camera)
        valid = (depth > 0) & (-facing / rays.norm(dim=-1) > MIN_GRAZING_COS)
        depth = torch.where(valid, depth, torch.ones_like(depth))
        rho = torch.where(valid, depth * facing, -torch.ones_like(facing))  # the plane n . X = rho
        # The plane's homography for the window offset (du, dv) from the pixel centre, in the source's
        # grid_sample coordinates: p = a du + b dv + c with a = G k0 + g (n . k0) / rho,
        # b = G k1 + g (n . k1) / rho, c = G ray + g / d, where G = T K_s R, g = T K_s t, k0 and k1 the
        # first columns of K^-1 and T maps pixels to [-1, 1].
        a = Gk0 + g[:, None, :] * ((normal @ k0) / rho)[None, :, None]  # (S, N, 3)
        b = Gk1 + g[:, None, :] * ((normal @ k1) / rho)[None, :, None]
        c = G_rays + g[:, None, :] / depth[None, :, None]
        # Across the window the homography is taken as affine about the centre, its first-order
        # expansion: the centre c / c_z plus the Jacobian times the offset, one product per sample and no
        # division (3x cheaper than the projective warp). The second-order term is the offset times the
        # depth's relative change across it (a_z du / c_z: well under 1 % over 4 px for any plane not
        # seen edge-on), so samples move by hundredths of a pixel (costs 1e-4 from the exact
        # homography's in the median, 3e-3 at worst, on a wide-angle camera and random slants: tested).
        in_front = c[..., 2] > 1e-6
        z = c[..., 2:].clamp_min(1e-6)
        centre_xy = c[..., :2] / z  # (S, N, 2)
        jacobian_u = (a[..., :2] - centre_xy * a[..., 2:]) / z
        jacobian_v = (b[..., :2] - centre_xy * b[..., 2:]) / z
        affine = torch.stack([jacobian_u, jacobian_v, centre_xy], dim=-2).reshape(S * N, 6)
        grid = (affine @ warp_matrix).reshape(S, N, M, 2)
    with stage("sampling"):
        sampled = F.grid_sample(sources.images[:, None], grid, mode="bilinear", padding_mode="border",
                                align_corners=False)[:, 0]  # (S, N, M)
    with stage("NCC"):
        mean_s = torch.einsum("snm,nm->sn", sampled, weights)
        var_s = torch.einsum("snm,nm->sn", sampled * sampled, weights) - mean_s ** 2
        cov = torch.einsum("snm,nm->sn", sampled, weighted_centred)
        ncc = cov / (variance * var_s.clamp_min(0)).sqrt().clamp_min(1e-9)
        centre_grid = centre_xy  # (S, N, 2)
        sees = in_front & (centre_grid.abs() <= 1.0).all(-1) & valid & (var_s > MIN_SOURCE_VARIANCE) \
            & (variance > MIN_REFERENCE_VARIANCE)
        cost = torch.where(sees, 1.0 - ncc.clamp(-1.0, 1.0), torch.full_like(ncc, MAX_COST))
    if sources.depths is not None:
        with stage("geometric term"):
            u0 = (centre_grid[..., 0] + 1.0) * (w / 2.0)
            v0 = (centre_grid[..., 1] + 1.0) * (h / 2.0)
            error = reprojection_error(ref, sources, pixels, depth, u0, v0, in_front)
            cost = torch.where(sees, cost + geometric_weight * error, torch.full_like(cost, worst))
    return cost


def reprojection_error(ref: ReferenceWindows, sources: SourceViews, pixels: Tensor, depths: Tensor, u: Tensor, v: Tensor,
                       in_front: Tensor) -> Tensor:
    """(S, N) forward-backward reprojection error in reference pixels, capped at MAX_REPROJECTION_PX:
    the reference point (depth `depths` at `pixels`) seen at source pixel (u, v) (S, N), lifted to the
    source's own depth there and projected back into the reference."""
    assert sources.depths is not None
    S, h, w = sources.depths.shape
    col = u.floor().long().clamp(0, w - 1)
    row = v.floor().long().clamp(0, h - 1)
    inside = in_front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    source_depth = sources.depths.reshape(S, -1).gather(1, row * w + col)  # (S, N) nearest: no blending across edges
    # The source pixel lifted to its own depth and moved into the reference, X = R^T (d K_s^-1 p - t),
    # then projected, K X: one matrix for all of it, K R^T K_s^-1, and one offset, K R^T t.
    to_ref = ref.K @ sources.rotation.transpose(1, 2)  # (S, 3, 3)
    lift = to_ref @ torch.linalg.inv(sources.K)
    offset = to_ref @ sources.translation[..., None]  # (S, 3, 1)
    pixel = torch.stack([u, v, torch.ones_like(u)], dim=-1)  # (S, N, 3)
    reprojected = (pixel @ lift.transpose(1, 2)) * source_depth[..., None] - offset.transpose(1, 2)  # (S, N, 3)
    zb = reprojected[..., 2]  # K's last row is (0, 0, 1): the depth in the reference
    ok = inside & (source_depth > 0) & (zb > 1e-6)
    reprojected = reprojected[..., :2] / torch.where(ok, zb, torch.ones_like(zb))[..., None]
    error = (reprojected - ref.centres[pixels][None]).norm(dim=-1)
    return torch.where(ok, error.clamp_max(MAX_REPROJECTION_PX), torch.full_like(error, MAX_REPROJECTION_PX))


def random_normals(count: int, rays: Tensor, generator: torch.Generator, max_angle_deg: float = 90.0,
                   around: Optional[Tensor] = None) -> Tensor:
    """(count, 3) unit normals facing the camera along `rays` (count, 3): uniform over the hemisphere
    (`around` None), or within `max_angle_deg` of the normals `around` (count, 3)."""
    dtype, device = rays.dtype, rays.device
    if around is None:
        around = -rays / rays.norm(dim=-1, keepdim=True)
    # A random direction within the cone: rotate `around` towards a random tangent by a random angle.
    tangent = torch.randn(count, 3, dtype=dtype, device=device, generator=generator)
    tangent = tangent - (tangent * around).sum(-1, keepdim=True) * around
    tangent = tangent / tangent.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    # Uniform over the cone's solid angle: cos(angle) uniform in [cos(max), 1].
    lowest = math.cos(math.radians(max_angle_deg))
    cos_angle = 1.0 - torch.rand(count, dtype=dtype, device=device, generator=generator) * (1.0 - lowest)
    sin_angle = (1.0 - cos_angle ** 2).clamp_min(0).sqrt()
    normals = cos_angle[:, None] * around + sin_angle[:, None] * tangent
    facing = (normals * rays).sum(-1, keepdim=True)
    return torch.where(facing > 0, -normals, normals)
