"""Seamless texture images for the fast (Workbench) renderer, generated with numpy.

Workbench cannot evaluate procedural shader nodes; in TEXTURE colour mode it shows a material's active
image texture. So for that renderer every MaterialSpec is also painted into a tileable 1 m x 1 m image
in the same spirit as its Cycles node tree (noise, voronoi cells, bricks, waves, checks, marble, plus
fine noise for detail). Images tile exactly: every pattern is periodic over the image.
"""

from __future__ import annotations

import zlib

import numpy as np
from scipy.spatial import cKDTree

from .room import MaterialSpec


def material_image(material: MaterialSpec, room_seed: int, size: int = 256) -> np.ndarray:
    """(size, size, 3) float32 linear RGB covering 1 m x 1 m of the surface (UV unit = 1 m)."""
    rng = np.random.default_rng([room_seed, zlib.crc32(material.name.encode())])
    a, b, tint = (np.asarray(c, np.float32) for c in material.colors)
    reps = max(1, int(round(material.scale)))  # whole repeats per tile keep the image seamless
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size  # 0..1, periodic coordinates
    pattern = material.pattern
    if pattern == "noise":
        fac = _contrast(_fbm(rng, size, reps * 2, octaves=4))
    elif pattern == "voronoi":
        fac = _voronoi(rng, size, reps * 3)
    elif pattern == "brick":
        fac = _bricks(rng, size, reps)
    elif pattern == "wave":
        fac = 0.5 + 0.5 * np.sin(2 * np.pi * (reps * 2 * x + 0.15 * _fbm(rng, size, 3, octaves=3)))
    elif pattern == "checker":
        fac = ((np.floor(x * reps * 2) + np.floor(y * reps * 2)) % 2).astype(np.float32)
    else:  # marble
        fac = 0.5 + 0.5 * np.sin(2 * np.pi * (reps * (x + y) + 1.2 * _fbm(rng, size, 4, octaves=5)))
    image = a * (1 - fac[..., None]) + b * fac[..., None]
    detail_reps = max(2, int(round(material.detail_scale)))
    detail = _fbm(rng, size, detail_reps, octaves=3)
    mix = np.clip(material.detail_strength * detail, 0, 1)[..., None]
    image = image * (1 - mix) + tint * mix
    if material.speckle_strength > 0:
        spots = _speckles(rng, size, max(2, int(round(material.speckle_scale))))
        spot_color = np.clip(np.asarray(material.colors[1], np.float32) * 0.35, 0, 1)
        alpha = (material.speckle_strength * spots)[..., None]
        image = image * (1 - alpha) + spot_color * alpha
    if material.emission > 0:
        # Backdrops are light sources in Cycles; in Workbench a brighter image stands in for that.
        image = np.clip(image * 1.6, 0, 1)
    return np.clip(image, 0, 1).astype(np.float32)


def _contrast(fac: np.ndarray) -> np.ndarray:
    lo, hi = np.quantile(fac, [0.05, 0.95])
    return np.clip((fac - lo) / max(hi - lo, 1e-6), 0, 1)


def _periodic_value_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Smooth value noise on a `cells` x `cells` lattice that wraps around: (size, size) in 0..1."""
    lattice = rng.random((cells, cells)).astype(np.float32)
    coords = np.arange(size, dtype=np.float32) * cells / size
    i0 = np.floor(coords).astype(np.int64)
    f = coords - i0
    f = f * f * (3 - 2 * f)  # smoothstep between lattice points
    i1 = (i0 + 1) % cells
    rows0, rows1 = lattice[i0 % cells], lattice[i1]  # (size, cells) along y
    top = rows0[:, i0 % cells] * (1 - f) + rows0[:, i1] * f
    bottom = rows1[:, i0 % cells] * (1 - f) + rows1[:, i1] * f
    return top * (1 - f[:, None]) + bottom * f[:, None]


def _fbm(rng: np.random.Generator, size: int, cells: int, octaves: int) -> np.ndarray:
    total, norm, amp = np.zeros((size, size), np.float32), 0.0, 1.0
    for o in range(octaves):
        c = min(cells * 2 ** o, size)
        total += amp * _periodic_value_noise(rng, size, c)
        norm += amp
        amp *= 0.5
    return total / norm


def _voronoi(rng: np.random.Generator, size: int, n_cells: int) -> np.ndarray:
    """Per-cell random value with dark cell borders, periodic: distances are taken to 9 tiled copies."""
    n = max(4, n_cells * n_cells)
    seeds = rng.random((n, 2)).astype(np.float32)
    values = rng.random(n).astype(np.float32)
    offsets = np.array([[dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1)], np.float32)
    tiled = (seeds[None] + offsets[:, None]).reshape(-1, 2)
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32) / size
    pix = np.stack([xs.ravel(), ys.ravel()], axis=1)
    dist, index = cKDTree(tiled).query(pix, k=2)
    owner = index[:, 0] % n
    border = np.clip((dist[:, 1] - dist[:, 0]) * n_cells * 8, 0, 1)
    return (values[owner] * border).reshape(size, size).astype(np.float32)


def _speckles(rng: np.random.Generator, size: int, per_tile: int) -> np.ndarray:
    """(size, size) 0..1 soft round spots of random size, ~per_tile^2 of them, periodic."""
    n = per_tile * per_tile
    seeds = rng.random((n, 2)).astype(np.float32)
    radius = rng.uniform(0.15, 0.45, n).astype(np.float32) / per_tile
    offsets = np.array([[dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1)], np.float32)
    tiled = (seeds[None] + offsets[:, None]).reshape(-1, 2)
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32) / size
    dist, index = cKDTree(tiled).query(np.stack([xs.ravel(), ys.ravel()], axis=1), k=1)
    r = radius[index % n]
    return np.clip((r - dist) / (0.3 * r), 0, 1).reshape(size, size).astype(np.float32)


def _bricks(rng: np.random.Generator, size: int, reps: int) -> np.ndarray:
    rows, cols = 4 * reps, 2 * reps
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    row = np.floor(y * rows).astype(np.int64)
    shifted = x * cols + 0.5 * (row % 2)
    col = np.floor(shifted).astype(np.int64) % cols
    shade = rng.random((rows, cols)).astype(np.float32)
    mortar = (np.minimum((y * rows) % 1, 1 - (y * rows) % 1) < 0.06) | (np.minimum(shifted % 1, 1 - shifted % 1) < 0.03)
    return np.where(mortar, 0.0, 0.25 + 0.75 * shade[row, col]).astype(np.float32)
