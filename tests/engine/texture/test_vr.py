"""The VR preset's mesh: small pieces dropped, decimated to the face budget, colours and the confidence
layer carried to the decimated vertices."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.mesh_io import Mesh
from engine.meshops import vertex_normals
from engine.texture.options import TextureOptions
from engine.texture.vr import decimate, vr_mesh


def bumpy_sheet(n: int = 60) -> Mesh:
    ys, xs = np.mgrid[0:n + 1, 0:n + 1] / n
    zs = 0.2 * np.sin(3 * xs) * np.cos(2 * ys)
    vertices = np.stack([3 * xs, 3 * ys, zs], -1).reshape(-1, 3).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    colors = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.5)], 1).astype(np.float32)
    return Mesh(vertices, faces, vertex_normals(vertices, faces), colors, {"observations": 3 * xs.ravel().astype(np.float32)})


def test_decimation_meets_the_budget_and_keeps_the_surface_and_its_colours():
    mesh = bumpy_sheet()
    light = decimate(mesh, 1000)
    assert 800 <= len(light.faces) <= 1000
    # Still the same sheet: every decimated vertex lies near the bumpy surface z = f(x, y).
    x, y = light.vertices[:, 0] / 3, light.vertices[:, 1] / 3
    assert np.abs(light.vertices[:, 2] - 0.2 * np.sin(3 * x) * np.cos(2 * y)).max() < 0.02
    # Colours and attributes follow position (they were functions of x and y).
    np.testing.assert_allclose(light.colors[:, 0], x, atol=0.05)
    np.testing.assert_allclose(light.attributes["observations"], 3 * x, atol=0.15)
    # Normals still face +z like the source's (winding kept).
    assert (light.normals[:, 2] > 0.5).all()
    assert decimate(mesh, 0) is mesh and decimate(mesh, 10 ** 6) is mesh


def test_vr_mesh_drops_specks_before_decimating():
    sheet = bumpy_sheet(30)
    speck = bumpy_sheet(1)
    speck.vertices = speck.vertices * 0.01 + [0, 0, 1]
    offset = len(sheet.vertices)
    both = Mesh(np.concatenate([sheet.vertices, speck.vertices]), np.concatenate([sheet.faces, speck.faces + offset]),
                np.concatenate([sheet.normals, speck.normals]), np.concatenate([sheet.colors, speck.colors]),
                {"observations": np.concatenate([sheet.attributes["observations"], speck.attributes["observations"]])})
    light, stats = vr_mesh(both, TextureOptions(face_budget=500, min_piece_fraction=0.01))
    assert stats["pieces_removed"] == 1 and stats["faces"] == len(light.faces) <= 500
    assert light.vertices[:, 2].max() < 0.5  # the speck at z = 1 is gone


def test_a_tiny_face_budget_is_refused_with_the_setting_named():
    with pytest.raises(VortxError, match="face budget"):
        TextureOptions(face_budget=10).validate()


def test_decimation_leaves_no_triangle_twice_and_meets_small_budgets():
    for budget in (300, 120):
        light = decimate(bumpy_sheet(80), budget)
        assert len(np.unique(np.sort(light.faces, axis=1), axis=0)) == len(light.faces)
        assert len(light.faces) <= budget
