"""The texture bake: every texel's colour from the full-resolution photos that see its surface point.

For each texel (texels.py) and each photo: the occlusion test the vertex colours use
(`engine/photo_sampling.py`'s `visible_points`, against the mesh's own depth map), then a weight

    w = cos(viewing angle) * (focal px / depth)^2 * sharpness * border ramp,

the texel's footprint in the photo (closer and more frontal views show more detail) times how sharp
the photo is, faded out near the photo's edges (border_ramp). Colours are sampled bilinearly at full resolution, converted to linear light, multiplied
by the photo's exposure gain (exposure.py) and blended with weights w^blend_power (1 by default:
on held-out photos the footprint-weighted blend beat favouring the best view, whose sharper detail
lands a little off wherever poses or geometry are; options.py has the numbers). The weights change
smoothly over the surface, so view changes and chart borders do not step. A texel's weights depend on its 3D point only, so both
sides of a chart seam (the same surface points) get the same colour: the seams are levelled by
construction. Texels no photo sees take the mesh's vertex colours, except on faces the finishing stage
added (engine/finish, the ADDED attribute: a wall behind a wardrobe), which take the colour of the
seen texels nearest them on the same plane (`neighbourhood_colours`). Gutters around the charts are
filled with their border colours, so bilinear filtering and mipmaps do not pull in black.
"""

from __future__ import annotations

import time
from typing import Optional, Sequence

import cv2
import numpy as np

from ..colour_space import SRGB_BYTE_TO_LINEAR, linear_to_srgb
from ..errors import VortxError
from ..geometry.cameras import camera_to_pixels, scale_intrinsics, world_to_camera
from ..geometry.depth_render import NEAR_PLANE
from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import Mesh
from ..meshops import vertex_normals
from ..observation import ADDED
from ..photo_sampling import UNSEEN_GREY, occlusion_depth, sample_bilinear, visible_points
from .atlas import uv_atlas
from .exposure import ViewSamples, exposure_gains
from .options import TextureOptions
from .texels import Texels, rasterise_uv
from .textured_mesh import TexturedMesh
from .views import TextureView, sharpness, sharpness_weights

BORDER_RAMP = 0.05  # share of a photo's short side over which its weight fades out at the picture's edge
TEXELS_PER_CHUNK = 1_000_000  # bounds each photo's per-texel temporaries to ~100 MB
# Added faces (engine/finish) no photo saw take their colour from the seen texels nearest on their plane.
NORMAL_METRES = 10.0  # m of distance a unit of normal difference counts as (a wall and the floor are 14 apart)
NEIGHBOURS = 64  # the weighted mean of this many cells of seen texels
FILL_CELL = 0.1  # m: seen texels are pooled in cells this size; nearer cells weigh as if this far
EDGE_MARGIN = 0.04  # m: seen texels this near unseen ones are not sources (an occluder's colour bleeds there)
NEIGHBOUR_SAMPLES = 400_000


def border_ramp(u: np.ndarray, v: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(N,) in (0, 1]: 1 inside the photo, falling to ~0 over the last BORDER_RAMP of its short side, so a
    photo's weight fades out where its picture ends instead of stepping (the colour would step there)."""
    w, h = size
    to_edge = np.minimum(np.minimum(u, w - u), np.minimum(v, h - v))
    return np.clip(to_edge / (BORDER_RAMP * min(w, h)), 1e-3, 1.0)


def _to_linear(srgb_0_255: np.ndarray) -> np.ndarray:
    """Bilinearly sampled sRGB values (0..255, fractional) -> linear, interpolating the byte table."""
    low = np.clip(np.floor(srgb_0_255).astype(np.int64), 0, 254)
    frac = np.clip(srgb_0_255 - low, 0.0, 1.0)
    return SRGB_BYTE_TO_LINEAR[low] * (1 - frac) + SRGB_BYTE_TO_LINEAR[low + 1] * frac


def fill_gutters(image: np.ndarray, filled: np.ndarray, passes: int) -> np.ndarray:
    """Grow the colours of `filled` texels (H, W) bool outwards by `passes` texels (each empty texel
    takes the mean of its filled 3 x 3 neighbours); whatever is still empty gets the mean colour."""
    image = image.astype(np.float32).copy()
    mask = filled.astype(np.float32)
    for _ in range(passes):
        total = cv2.boxFilter(image * mask[..., None], -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        count = cv2.boxFilter(mask, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        grow = (mask == 0) & (count > 0)
        if not grow.any():
            break
        image[grow] = total[grow] / count[grow][:, None]
        mask[grow] = 1.0
    empty = mask == 0
    if empty.any() and (~empty).any():
        image[empty] = image[~empty].mean(axis=0)
    return image


def _exposure_and_occlusion(mesh: Mesh, views: Sequence[TextureView], options: TextureOptions,
                            progress: Optional[ProgressCallback], cancel: Optional[CancelToken],
                            ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """First pass over the photos: each one's occlusion depth map, sharpness and the vertex samples that
    give its exposure gain. -> (depth maps, sharpness weights (n,), gains (n, 3))."""
    depths, scores, samples = [], [], []
    for i, view in enumerate(views):
        check(cancel)
        report(progress, "texture: photos", i, len(views))
        image = view.load()
        scores.append(sharpness(image))
        depth = occlusion_depth(mesh, view.K, view.pose, view.size, options.occlusion_long_side)
        depths.append(depth)
        if options.exposure:
            # Samples from a copy at the occlusion size: exposure is a smooth, whole-photo property.
            dh, dw = depth.shape
            small = cv2.resize(image, (dw, dh), interpolation=cv2.INTER_AREA)
            K_small = scale_intrinsics(view.K, view.size, (dw, dh))
            ids, u, v, cosine, _ = visible_points(mesh.vertices, mesh.normals, K_small, view.pose, (dw, dh), depth,
                                                  options.occlusion_tolerance)
            samples.append(ViewSamples(ids, _to_linear(sample_bilinear(small, u, v)), cosine))
    report(progress, "texture: photos", len(views), len(views))
    gains = exposure_gains(samples, len(mesh.vertices)) if options.exposure else np.ones((len(views), 3), np.float32)
    return depths, sharpness_weights(scores), gains


def faces_in_view(mesh: Mesh, view: TextureView) -> np.ndarray:
    """(F,) bool: faces that may show in the photo (a corner in front of the camera, and the corners
    not all beyond one side of the image). A cheap cull before the per-texel test: a room photo sees a
    fifth of the room, so four fifths of the texels are skipped without projecting them."""
    w, h = view.size
    cam = world_to_camera(mesh.vertices, view.pose)
    in_front = cam[:, 2] > NEAR_PLANE
    u, v = camera_to_pixels(np.where(in_front[:, None], cam, [0.0, 0.0, 1.0]), view.K)
    # Corners behind the camera project anywhere: such faces are kept unless no corner is in front.
    u = np.where(in_front, u, np.nan)
    v = np.where(in_front, v, np.nan)
    fu, fv = u[mesh.faces], v[mesh.faces]
    with np.errstate(invalid="ignore"):
        beyond = ((fu < 0).all(1) | (fu >= w).all(1) | (fv < 0).all(1) | (fv >= h).all(1))
    return in_front[mesh.faces].any(axis=1) & ~beyond


def added_texels(mesh: Mesh, texels: Texels) -> np.ndarray:
    """(N,) bool: the texels on faces the finishing stage added (every corner's ADDED attribute is 1)."""
    flag = mesh.attributes.get(ADDED)
    if flag is None or len(texels) == 0:
        return np.zeros(len(texels), bool)
    face_added = (np.asarray(flag)[np.asarray(mesh.faces)] > 0.5).all(axis=1)
    return face_added[texels.face]


def _texel_normals(mesh: Mesh, texels: Texels) -> np.ndarray:
    normals = texels.interpolate(mesh.normals, mesh.faces)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def neighbourhood_colours(points: np.ndarray, normals: np.ndarray, colours: np.ndarray, seen: np.ndarray,
                          fill: np.ndarray) -> np.ndarray:
    """(M,) x 3 colours for the `fill` texels (M of N) from the nearest seen texels on the same plane.

    points, normals (N, 3): the texels' surface points and unit normals; colours (N, 3) linear; seen,
    fill (N,) bool. Nearness counts the normal as NORMAL_METRES of distance per unit of difference, so a
    hidden stretch of wall takes the wall's colour around it, not the floor's or a cabinet's. The mean of
    the NEIGHBOURS nearest cells of seen texels (FILL_CELL, per normal axis) weighed by inverse square
    distance, leaving out seen texels within EDGE_MARGIN of unseen ones (samples of at most
    NEIGHBOUR_SAMPLES texels keep the trees small)."""
    from scipy.spatial import cKDTree  # defers scipy: slow to import, only for added faces

    rng = np.random.default_rng(0)
    candidates, unseen = np.flatnonzero(seen), np.flatnonzero(~seen)
    if len(candidates) > NEIGHBOUR_SAMPLES:
        candidates = rng.choice(candidates, NEIGHBOUR_SAMPLES, replace=False)
    if len(unseen) > NEIGHBOUR_SAMPLES:
        unseen = rng.choice(unseen, NEIGHBOUR_SAMPLES, replace=False)
    # Seen texels at the edge of what no photo sees lie at an occluder's silhouette, where its colour
    # bleeds in (the pillar's red on the wall beside its shadow): the colour comes from beyond them.
    distance, _ = cKDTree(points[unseen]).query(points[candidates], k=1, distance_upper_bound=EDGE_MARGIN)
    if np.isinf(distance).any():
        candidates = candidates[np.isinf(distance)]
    # The seen texels pooled into FILL_CELL cells (by position and the axis their normal is nearest):
    # the sources of a fill are then spread over a patch, not the few texels at the nearest edge.
    cell = np.floor(points[candidates] / FILL_CELL).astype(np.int64)
    source_normal = normals[candidates]
    dominant = np.argmax(np.abs(source_normal), axis=1)
    facing = 2 * dominant + (source_normal[np.arange(len(candidates)), dominant] > 0)  # +-x, +-y, +-z: 0..5
    _, pool, count = np.unique(np.c_[cell, facing], axis=0, return_inverse=True, return_counts=True)
    pool = pool.ravel()

    def pooled(values: np.ndarray) -> np.ndarray:
        total = np.zeros((len(count), values.shape[1]))
        np.add.at(total, pool, values)
        return total / count[:, None]

    source_points, source_colours = pooled(points[candidates]), pooled(colours[candidates])
    source_normals = pooled(normals[candidates])
    source_normals /= np.maximum(np.linalg.norm(source_normals, axis=1, keepdims=True), 1e-12)
    tree = cKDTree(np.concatenate([source_points, NORMAL_METRES * source_normals], axis=1))
    k = min(NEIGHBOURS, len(source_points))
    distance, index = tree.query(np.concatenate([points[fill], NORMAL_METRES * normals[fill]], axis=1), k=k)
    distance, index = np.asarray(distance).reshape(-1, k), np.asarray(index).reshape(-1, k)
    # Weighed by inverse square distance, the colour changes smoothly across a large hidden stretch (the
    # median of the nearest few texels was constant over each region that shares them: a patchwork of
    # flat cells with straight edges over the floor under a camera path).
    weight = 1.0 / np.maximum(distance, FILL_CELL) ** 2
    return (np.einsum("mk,mkc->mc", weight, source_colours[index]) / weight.sum(axis=1, keepdims=True)).astype(np.float32)


def bake_colours(mesh: Mesh, texels: Texels, views: Sequence[TextureView], options: TextureOptions,
                 progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Linear colours (N, 3) float32 of the texels and which of them a photo saw (N,) bool, plus stats.

    mesh: the surface (vertices, faces, normals pointing to free space) the texels lie on.
    """
    points = texels.interpolate(mesh.vertices, mesh.faces)
    normals = texels.interpolate(mesh.normals, mesh.faces)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    depths, sharp, gains = _exposure_and_occlusion(mesh, views, options, progress, cancel)
    total = np.zeros((len(texels), 3), np.float32)
    weight = np.zeros(len(texels), np.float32)
    for i, view in enumerate(views):
        check(cancel)
        report(progress, "texture: bake", i, len(views))
        candidates = np.flatnonzero(faces_in_view(mesh, view)[texels.face])
        if len(candidates) == 0:
            continue
        image = view.load()
        focal = float(np.sqrt(view.K[0, 0] * view.K[1, 1]))
        for start in range(0, len(candidates), TEXELS_PER_CHUNK):
            chunk = candidates[start:start + TEXELS_PER_CHUNK]
            ids, u, v, cosine, z = visible_points(points[chunk], normals[chunk], view.K, view.pose, view.size,
                                                  depths[i], options.occlusion_tolerance)
            if len(ids) == 0:
                continue
            w = (cosine * (focal / z) ** 2 * sharp[i] * border_ramp(u, v, view.size)) ** options.blend_power
            w = (w / (focal ** (2 * options.blend_power))).astype(np.float32)  # keeps float32 in range
            colour = _to_linear(sample_bilinear(image, u, v)) * gains[i]
            ids = chunk[ids]
            total[ids] += w[:, None] * colour
            weight[ids] += w
    report(progress, "texture: bake", len(views), len(views))
    seen = weight > 0
    colours = np.zeros((len(texels), 3), np.float32)
    colours[seen] = total[seen] / weight[seen, None]
    stats = {"views": len(views), "texels": int(len(texels)), "texels_seen": int(seen.sum()),
             "exposure_gains": {"min": np.round(gains.min(axis=0), 3).tolist(), "max": np.round(gains.max(axis=0), 3).tolist()},
             "sharpness_weights": {"min": round(float(sharp.min()), 3), "median": round(float(np.median(sharp)), 3)}}
    return colours, seen, stats


def bake_texture(mesh: Mesh, views: Sequence[TextureView], options: TextureOptions,
                 progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
                 ) -> tuple[TexturedMesh, dict]:
    """A UV atlas for `mesh` and its texture baked from `views`. -> (textured mesh, stats).

    mesh: vertices, faces and normals pointing to free space (the engine's result meshes); colours,
    if present, fill texels no photo sees.
    """
    options.validate()
    if not views:
        raise VortxError("no photos to bake the texture from: the capture needs posed photos")
    if mesh.normals is None:  # meshes from files or other tools; the engine's results carry them
        mesh = Mesh(mesh.vertices, mesh.faces, vertex_normals(mesh.vertices, mesh.faces), mesh.colors, mesh.attributes)
    started, timings = time.perf_counter(), {}
    report(progress, "texture: atlas", 0, 1)
    atlas = uv_atlas(mesh.vertices, mesh.faces, mesh.normals, options.texture_size, options.padding, cancel)
    timings["atlas"] = time.perf_counter() - started
    report(progress, "texture: atlas", 1, 1)
    check(cancel)
    size = (options.texture_size, options.texture_size)
    mark = time.perf_counter()
    texels = rasterise_uv(atlas.uvs, atlas.faces, size)
    timings["texels"] = time.perf_counter() - mark
    mark = time.perf_counter()
    # Texel points are interpolated on the source mesh: same faces, same order as the atlas's.
    colours, seen, stats = bake_colours(mesh, texels, views, options, progress, cancel)
    timings["bake"] = time.perf_counter() - mark
    if mesh.colors is not None and (~seen).any():
        fallback = texels.interpolate(np.asarray(mesh.colors, np.float32), mesh.faces)
        colours[~seen] = SRGB_BYTE_TO_LINEAR[np.clip(np.round(fallback[~seen] * 255), 0, 255).astype(np.int64)]
    elif (~seen).any():
        colours[~seen] = SRGB_BYTE_TO_LINEAR[round(UNSEEN_GREY * 255)]
    added = added_texels(mesh, texels) & ~seen
    if added.any() and seen.any():
        colours[added] = neighbourhood_colours(texels.interpolate(mesh.vertices, mesh.faces), _texel_normals(mesh, texels),
                                               colours, seen, added)
    stats["texels_filled_from_neighbours"] = int(added.sum())
    W, H = size
    image = np.zeros((H, W, 3), np.float32)
    filled = np.zeros((H, W), bool)
    image[texels.rows, texels.cols] = linear_to_srgb(colours)
    filled[texels.rows, texels.cols] = True
    texture = np.clip(np.round(fill_gutters(image, filled, 2 * options.padding + 2) * 255), 0, 255).astype(np.uint8)
    source = atlas.source_vertex
    textured = TexturedMesh(
        vertices=np.asarray(mesh.vertices, np.float32)[source], faces=atlas.faces,
        normals=np.asarray(mesh.normals, np.float32)[source], uvs=atlas.uvs, texture=texture,
        colors=None if mesh.colors is None else np.asarray(mesh.colors, np.float32)[source],
        attributes={k: np.asarray(v)[source] for k, v in mesh.attributes.items()}, source_vertex=source,
    )
    timings["total"] = time.perf_counter() - started
    stats.update({"texture_size": options.texture_size, "charts": atlas.charts,
                  "atlas_utilisation": round(atlas.utilisation, 4), "padding_texels": round(atlas.padding, 2), "faces": int(len(atlas.faces)),
                  "vertices": int(len(source)), "timings_s": {k: round(v, 3) for k, v in timings.items()}})
    return textured, stats
