"""The texture bake against photos ray-cast from known patterns (tests/fixtures_texture.py): the texture
holds detail the 4 cm vertex colours cannot, occluded photos do not paint what is behind an occluder,
exposure differences are evened out, and gutters carry their chart's colours."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.jobs import CancelToken, Cancelled
from engine.observation import ADDED
from engine.recon.colour import ColourView, colour_vertices
from engine.texture.bake import bake_texture, fill_gutters, neighbourhood_colours
from engine.texture.options import TextureOptions
from engine.texture.texels import rasterise_uv
from fixtures_quads import join, solid, stripes, views_around, wall, Quad

EYES = [(0.2, y, z) for y in (-0.6, 0.0, 0.6) for z in (0.5, 1.0)]
TARGET = (2.0, 0.0, 0.75)
OPTIONS = TextureOptions(texture_size=512, face_budget=0, occlusion_tolerance=0.08)


def texel_error(textured, quad, select=None):
    """Mean absolute error (0..255) of the baked texels against the pattern, and of the vertex colours
    interpolated at the same points; only texels on `quad`'s plane (x = const) when select is given."""
    texels = rasterise_uv(textured.uvs, textured.faces, textured.texture_size)
    points = texels.interpolate(textured.vertices, textured.faces)
    keep = np.ones(len(points), bool) if select is None else select(points)
    truth = quad.pattern(points[keep]) * 255
    baked = textured.texture[texels.rows[keep], texels.cols[keep]].astype(np.float64)
    vertex = texels.interpolate(textured.colors, textured.faces)[keep] * 255
    return np.abs(baked - truth).mean(), np.abs(vertex - truth).mean(), baked


@pytest.fixture(scope="module")
def striped_wall():
    quad = wall(stripes(0.04))
    mesh = quad.grid(0.04)
    views = views_around([quad], EYES, TARGET)
    colour_views = [ColourView(v.load(), v.K, v.pose) for v in views]
    mesh.colors = colour_vertices(mesh, colour_views, tolerance=0.08)
    return quad, mesh, views


def test_texture_holds_detail_that_vertex_colours_lose(striped_wall):
    quad, mesh, views = striped_wall
    textured, stats = bake_texture(mesh, views, OPTIONS)
    assert textured.texture.shape == (512, 512, 3) and textured.texture.dtype == np.uint8
    assert stats["texels_seen"] == stats["texels"] > 0  # every texel of the wall is in some photo
    texture_error, vertex_error, _ = texel_error(textured, quad)
    assert texture_error < 20 and texture_error < 0.45 * vertex_error, (texture_error, vertex_error)
    # The atlas keeps the surface: same faces, vertices copied from the source.
    assert len(textured.faces) == len(mesh.faces)
    np.testing.assert_array_equal(textured.vertices, mesh.vertices[textured.source_vertex])


def test_an_occluder_does_not_paint_the_wall_behind_it():
    grey = wall(stripes(0.08))
    grey.pattern = (lambda p, f=grey.pattern: np.repeat(f(p).mean(axis=1, keepdims=True), 3, axis=1))
    pillar = Quad(np.array([1.2, 0.1, 0.0]), np.array([0.0, -0.2, 0.0]), np.array([0.0, 0.0, 1.5]), solid((1.0, 0.0, 0.0)))
    mesh = join([grey.grid(0.04), pillar.grid(0.04)])
    views = views_around([grey, pillar], EYES, TARGET)
    mesh.colors = np.full((len(mesh.vertices), 3), 0.5, np.float32)

    def red_share(options):
        textured, _ = bake_texture(mesh, views, options)
        texels = rasterise_uv(textured.uvs, textured.faces, textured.texture_size)
        points = texels.interpolate(textured.vertices, textured.faces)
        on_wall = points[:, 0] > 1.9
        rgb = textured.texture[texels.rows[on_wall], texels.cols[on_wall]].astype(np.int64)
        return float(np.mean(rgb[:, 0] - rgb[:, 1] > 40))

    with_test = red_share(OPTIONS)
    without_test = red_share(TextureOptions(texture_size=512, face_budget=0, occlusion_tolerance=100.0))
    assert without_test > 0.03  # the pillar's red lands on the wall when occlusion is ignored ...
    assert with_test < 0.005 and with_test < 0.1 * without_test, (with_test, without_test)  # ... and not with it


def smooth_paint(points: np.ndarray) -> np.ndarray:
    """A wall colour that changes slowly: only exposure can make the photos disagree about it."""
    a = 0.45 + 0.15 * np.sin(1.5 * points[:, 1]) * np.cos(2.0 * points[:, 2])
    return np.stack([a, 0.9 * a, 0.7 * a + 0.1], axis=1)


def test_exposure_differences_are_evened_out():
    quad = wall(smooth_paint)
    mesh = quad.grid(0.04)
    mesh.colors = np.full((len(mesh.vertices), 3), 0.5, np.float32)
    views = views_around([quad], EYES, TARGET, gains={1: 1.8, 4: 0.6})
    evened, _ = bake_texture(mesh, views, OPTIONS)
    raw, _ = bake_texture(mesh, views, TextureOptions(texture_size=512, face_budget=0, exposure=False))
    evened_error = texel_error(evened, quad)[0]
    raw_error = texel_error(raw, quad)[0]
    assert evened_error < 3.0 and evened_error < 0.4 * raw_error, (evened_error, raw_error)


def test_gutters_take_their_charts_colours():
    image = np.zeros((16, 16, 3), np.float32)
    filled = np.zeros((16, 16), bool)
    image[4:8, 4:8] = (0.2, 0.4, 0.6)
    filled[4:8, 4:8] = True
    out = fill_gutters(image, filled, passes=2)
    np.testing.assert_allclose(out[2:10, 2:10], np.broadcast_to((0.2, 0.4, 0.6), (8, 8, 3)), atol=1e-6)
    np.testing.assert_allclose(out[0, 15], (0.2, 0.4, 0.6), atol=1e-6)  # beyond the passes: the mean colour


def test_bake_can_be_cancelled_and_refuses_bad_options(striped_wall):
    _, mesh, views = striped_wall
    token = CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        bake_texture(mesh, views, OPTIONS, cancel=token)
    with pytest.raises(VortxError, match="texture size must be one of"):
        bake_texture(mesh, views, TextureOptions(texture_size=1000))
    with pytest.raises(VortxError, match="no photos to bake"):
        bake_texture(mesh, [], OPTIONS)


def test_a_mesh_without_normals_gets_them_from_its_winding(striped_wall):
    quad, mesh, views = striped_wall
    bare = type(mesh)(mesh.vertices, mesh.faces, None, mesh.colors)
    textured, stats = bake_texture(bare, views, OPTIONS)
    assert stats["texels_seen"] == stats["texels"]
    np.testing.assert_allclose(textured.normals, mesh.normals[textured.source_vertex], atol=1e-5)


def test_added_faces_no_photo_sees_take_their_planes_colour_not_black():
    """A wall behind a pillar, the stretch behind it added by the finishing stage (ADDED = 1) with black
    vertex colours: its texels no photo sees take the wall's yellow around them, not black, nor the
    pillar's red in front."""
    yellow = wall(solid((0.9, 0.8, 0.1)))
    pillar = Quad(np.array([1.2, 0.15, 0.0]), np.array([0.0, -0.3, 0.0]), np.array([0.0, 0.0, 1.5]), solid((1.0, 0.0, 0.0)))
    mesh = join([yellow.grid(0.04), pillar.grid(0.04)])
    behind = (mesh.vertices[:, 0] > 1.9) & (np.abs(mesh.vertices[:, 1]) < 0.32)  # the pillar's shadow: |y| < 0.27
    mesh.attributes = {ADDED: behind.astype(np.float32)}
    mesh.colors = np.zeros((len(mesh.vertices), 3), np.float32)
    views = views_around([yellow, pillar], [(0.2, 0.0, 0.75)], TARGET)  # one photo, straight behind the pillar
    textured, stats = bake_texture(mesh, views, OPTIONS)
    assert stats["texels_filled_from_neighbours"] > 0
    texels = rasterise_uv(textured.uvs, textured.faces, textured.texture_size)
    points = texels.interpolate(textured.vertices, textured.faces)
    rgb = textured.texture[texels.rows, texels.cols].astype(np.int64)
    hidden = (points[:, 0] > 1.9) & (np.abs(points[:, 1]) < 0.05) & (points[:, 2] > 0.1) & (points[:, 2] < 1.4)
    assert hidden.sum() > 50
    np.testing.assert_allclose(rgb[hidden].mean(axis=0), (230, 204, 26), atol=25)
    on_added = (points[:, 0] > 1.9) & (np.abs(points[:, 1]) < 0.27)  # faces whose corners are all added
    assert rgb[on_added].max(axis=1).min() > 60  # no black texel on the added faces


def test_a_large_hidden_stretch_blends_from_one_side_to_the_other_without_steps():
    """A floor 2 m long, seen dark at one end and bright at the other, hidden in between (the floor under
    a camera path): the fill goes from one colour to the other smoothly; the nearest few texels' median
    gave a patchwork of flat cells, here a jump of the whole difference halfway."""
    x, y = np.meshgrid(np.arange(0.0, 2.0, 0.01), np.arange(0.0, 0.5, 0.01), indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    seen = (points[:, 0] < 0.2) | (points[:, 0] >= 1.8)
    colours = np.where(points[:, :1] < 1.0, 0.1, 0.9).astype(np.float32) * np.ones((1, 3), np.float32)

    filled = neighbourhood_colours(points, normals, colours, seen, ~seen)

    profile = np.array([filled[points[~seen, 0] == xv, 0].mean() for xv in np.unique(points[~seen, 0])])
    assert profile[0] < 0.3 and profile[-1] > 0.7  # each end takes its side's colour
    assert np.abs(np.diff(profile)).max() < 0.05  # no step between neighbouring centimetres
    assert (np.diff(profile) > -1e-3).all()  # from dark to bright, not back
