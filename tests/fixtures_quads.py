"""Analytic scenes for the texture bake: flat textured quads photographed by ray casting.

Every photo pixel is the colour of the nearest quad its ray hits (pattern functions of the 3D point),
computed independently of the engine's renderers, so a baked texture can be checked against the
pattern the photos were made from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from engine.geometry.cameras import look_at
from engine.mesh_io import Mesh
from engine.meshops import vertex_normals
from engine.texture.views import TextureView

Pattern = Callable[[np.ndarray], np.ndarray]  # (N, 3) world points -> (N, 3) sRGB 0..1


@dataclass
class Quad:
    """A rectangle origin + s * edge_u + t * edge_v, s, t in [0, 1]; its normal faces the cameras."""

    origin: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    pattern: Pattern

    def grid(self, step: float) -> Mesh:
        nu = max(1, int(round(np.linalg.norm(self.edge_u) / step)))
        nv = max(1, int(round(np.linalg.norm(self.edge_v) / step)))
        s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
        vertices = (self.origin + s.reshape(-1, 1) * self.edge_u + t.reshape(-1, 1) * self.edge_v).astype(np.float32)
        idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
        faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
        return Mesh(vertices=vertices, faces=faces, normals=vertex_normals(vertices, faces))

    def hit(self, eye: np.ndarray, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray parameters (N,) (inf for a miss) and hit points (N, 3)."""
        normal = np.cross(self.edge_u, self.edge_v)
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.origin - eye) @ normal) / denom
        points = eye + t[:, None] * rays
        rel = points - self.origin
        s = rel @ self.edge_u / (self.edge_u @ self.edge_u)
        q = rel @ self.edge_v / (self.edge_v @ self.edge_v)
        inside = (t > 0) & (s >= 0) & (s <= 1) & (q >= 0) & (q <= 1) & np.isfinite(t)
        return np.where(inside, t, np.inf), points


def join(meshes: list[Mesh]) -> Mesh:
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    vertices = np.concatenate([m.vertices for m in meshes])
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]).astype(np.int32)
    return Mesh(vertices=vertices, faces=faces, normals=np.concatenate([m.normals for m in meshes]))


def photograph(quads: list[Quad], K: np.ndarray, pose: np.ndarray, size: tuple[int, int], background=(0, 0, 0),
               supersample: int = 3) -> np.ndarray:
    """(h, w, 3) uint8 sRGB: each pixel the mean of supersample^2 rays (a camera's pixel integrates)."""
    w, h = size
    offsets = (np.arange(supersample) + 0.5) / supersample
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    total = np.zeros((h * w, 3))
    for oy in offsets:
        for ox in offsets:
            uv1 = np.stack([jj.ravel() + ox, ii.ravel() + oy, np.ones(h * w)], 1)
            rays = (np.linalg.inv(K) @ uv1.T).T @ pose[:3, :3].T
            best = np.full(h * w, np.inf)
            colour = np.tile(np.asarray(background, np.float64) / 255.0, (h * w, 1))
            for quad in quads:
                t, points = quad.hit(pose[:3, 3], rays)
                nearer = t < best
                best[nearer] = t[nearer]
                colour[nearer] = quad.pattern(points[nearer])
            total += colour
    return np.clip(np.round(total / supersample ** 2 * 255), 0, 255).astype(np.uint8).reshape(h, w, 3)


def stripes(period: float = 0.04) -> Pattern:
    """Fine grey stripes along world y and z with a colour gradient: detail a 4 cm vertex grid cannot hold."""
    def pattern(points: np.ndarray) -> np.ndarray:
        a = 0.5 + 0.35 * np.sign(np.sin(2 * np.pi * points[:, 1] / period))
        b = 0.5 + 0.2 * np.sin(2 * np.pi * points[:, 2] / (2.5 * period))
        return np.clip(np.stack([a * 0.9 + 0.1 * b, a * 0.8 + 0.2 * b, 0.6 * a + 0.3 * b], 1), 0, 1)
    return pattern


def solid(rgb) -> Pattern:
    return lambda points: np.tile(np.asarray(rgb, np.float64), (len(points), 1))


def wall(pattern: Pattern, x: float = 2.0, width: float = 2.0, height: float = 1.5) -> Quad:
    """A wall in the plane x = `x`, facing -x (the cameras stand at x < `x`)."""
    return Quad(np.array([x, width / 2, 0.0]), np.array([0.0, -width, 0.0]), np.array([0.0, 0.0, height]), pattern)


def views_around(quads: list[Quad], eyes: list, target, size=(320, 240), focal: float = 300.0,
                 gains: dict[int, float] | None = None) -> list[TextureView]:
    """Photos of the quads from `eyes`, all looking at `target`; gains: photo index -> linear exposure factor."""
    from engine.colour_space import linear_to_srgb, srgb_to_linear

    w, h = size
    K = np.array([[focal, 0, w / 2], [0, focal, h / 2], [0, 0, 1.0]])
    views = []
    for i, eye in enumerate(eyes):
        pose = look_at(eye, target)
        image = photograph(quads, K, pose, size)
        if gains and i in gains:
            linear = srgb_to_linear(image / 255.0) * gains[i]
            image = np.clip(np.round(linear_to_srgb(linear) * 255), 0, 255).astype(np.uint8)
        views.append(TextureView(f"{i:03d}.png", K, pose, size, (lambda img=image: img)))
    return views
