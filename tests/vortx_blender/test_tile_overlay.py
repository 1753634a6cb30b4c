"""The tile overlay and the baked tile wireframe, headless: geometry from engine.recon.tile_grid, the draw
handler following show_tiles (registration only: gpu calls fail without a UI and are never made here),
Preview Tiles and Bake Tiles through bpy.ops."""

from __future__ import annotations

import importlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

TINY = dict(voxel_size=0.16, tile_size=8, view_count=3, max_room_size=(2.0, 2.0, 2.0))


@pytest.fixture(scope="module")
def capture_dir(blender, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("tiles") / "studio"
    synthetic = importlib.import_module(f"{blender.__name__}.engine.recon.synthetic")
    synthetic.make_synthetic_capture(path, room_size=(3.0, 3.0, 2.5), frames=5, image_size=(64, 48))
    return path


@pytest.fixture
def overlay(blender):
    module = blender.vortx_blender.tile_overlay
    module.clear()
    yield module
    module.clear()
    module.sync_draw_handler(False)


@pytest.fixture
def posed(blender, capture_dir):
    """A fresh scene with the capture's cameras and tiny tile settings; plus the engine's own plan."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    capture = blender.engine.capture.load_capture(capture_dir)
    blender.vortx_blender.capture.apply_capture(scene, capture, capture_dir)
    for name, value in TINY.items():
        setattr(scene.vortx, name, value)
    settings = blender.engine.recon.ReconSettings(voxel_size=0.16, tile_size=8, views=3, max_room_size=(2.0, 2.0, 2.0))
    plan = blender.engine.recon.plan_reconstruction(capture, settings)
    return SimpleNamespace(scene=scene, plan=plan)


def test_overlay_lines_are_the_engine_boxes(blender, posed, overlay) -> None:
    tiles = posed.plan.tiles
    assert len(tiles) > 1
    shown = overlay.overlay_from_tiles(posed.scene.session_uid, tiles)
    corners, edges, states = blender.engine.recon.tile_grid(tiles)
    segments = shown.segments()
    assert segments.dtype == np.float32 and segments.shape == (24 * len(tiles), 3)
    np.testing.assert_allclose(segments, corners[:, edges.reshape(-1)].reshape(-1, 3), atol=1e-6)
    # Independently of tile_grid: every segment is a box edge, along one axis, as long as the tile.
    pairs = segments.reshape(len(tiles), 12, 2, 3)
    for tile, lines in zip(tiles, pairs):
        delta = np.abs(lines[:, 1] - lines[:, 0])
        assert np.all(np.sum(delta > 1e-6, axis=1) == 1)
        np.testing.assert_allclose(delta.max(axis=1), (tile.maximum - tile.minimum)[delta.argmax(axis=1)], atol=1e-5)
        assert np.all(lines >= tile.minimum - 1e-5) and np.all(lines <= tile.maximum + 1e-5)
    assert shown.states() == states
    by_state = shown.segments_by_state()
    assert sum(len(v) for v in by_state.values()) == len(segments)
    assert set(by_state) == set(states)


def test_states_and_status_follow_the_tiles(blender, posed, overlay) -> None:
    TileState = blender.engine.recon.TileState
    tiles = posed.plan.tiles
    assert len(tiles) >= 4
    for tile in tiles:
        tile.state = TileState.PENDING
    tiles[-1].state = TileState.EMPTY
    shown = overlay.show(posed.scene.session_uid, tiles)
    assert overlay.status_detail() == f"tiles 0/{len(tiles) - 1} done"
    tiles[0].state, tiles[1].state = TileState.DONE, TileState.RUNNING  # as the engine does, in place
    assert shown.states()[:2] == ["done", "running"]
    assert shown.counts() == {"pending": len(tiles) - 3, "running": 1, "done": 1, "empty": 1}
    assert overlay.status_detail() == f"tiles 1/{len(tiles) - 1} done, 1 running"
    by_state = shown.segments_by_state()
    assert len(by_state["running"]) == len(by_state["done"]) == len(by_state["empty"]) == 24
    np.testing.assert_array_equal(by_state["running"], shown.segments()[24:48])


def test_draw_handler_follows_show_tiles(blender, posed, overlay) -> None:
    settings = posed.scene.vortx
    settings.show_tiles = False
    overlay.show(posed.scene.session_uid, posed.plan.tiles)
    assert not overlay.draw_handler_registered()
    settings.show_tiles = True  # the property's update callback
    assert overlay.draw_handler_registered()
    settings.show_tiles = False
    assert not overlay.draw_handler_registered()
    settings.show_tiles = True
    assert overlay.draw_handler_registered()
    # The callback's guards return before any gpu call: tiles of another scene, or show_tiles off.
    overlay.show(posed.scene.session_uid + 1000, posed.plan.tiles)
    overlay._draw()
    overlay.show(posed.scene.session_uid, posed.plan.tiles)
    settings.show_tiles = False
    overlay._draw()


def test_failed_run_shows_the_previous_tiles_again(blender, posed, overlay) -> None:
    uid = posed.scene.session_uid
    before = overlay.show(uid, posed.plan.tiles[:1])
    overlay.begin_run(uid, show_tiles=True)
    assert overlay.current(posed.scene).tiles == []  # cleared while the new plan is made
    overlay.show(uid, posed.plan.tiles)
    overlay.end_run(succeeded=False)
    assert overlay.current(posed.scene) is before
    overlay.end_run(succeeded=False)  # no run pending: nothing changes
    assert overlay.current(posed.scene) is before
    overlay.begin_run(uid, show_tiles=True)
    after = overlay.show(uid, posed.plan.tiles)
    overlay.end_run(succeeded=True)
    assert overlay.current(posed.scene) is after


def test_preview_tiles_shows_the_engine_plan(blender, posed, overlay) -> None:
    import bpy

    assert bpy.ops.vortx.preview_tiles() == {"FINISHED"}
    shown = overlay.current(posed.scene)
    expected, _, _ = blender.engine.recon.tile_grid(posed.plan.tiles)
    np.testing.assert_allclose(shown.corners, expected, atol=1e-6)
    assert shown.states() == [t.state.value for t in posed.plan.tiles]
    assert overlay.draw_handler_registered()


def test_preview_without_cameras_is_refused(blender, empty_scene, overlay) -> None:
    import bpy

    with pytest.raises(RuntimeError, match="no posed capture cameras"):
        bpy.ops.vortx.preview_tiles()
    assert overlay.current(empty_scene) is None


def test_bake_tiles_makes_one_wire_object(blender, posed, overlay) -> None:
    import bpy

    assert not bpy.ops.vortx.bake_tiles.poll()  # nothing planned yet
    bpy.ops.vortx.preview_tiles()
    assert bpy.ops.vortx.bake_tiles() == {"FINISHED"}
    obj = bpy.data.objects["VoRTX Tiles"]
    mesh = obj.data
    corners, edges, _ = blender.engine.recon.tile_grid(posed.plan.tiles)
    positions = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.attributes["position"].data.foreach_get("vector", positions)
    np.testing.assert_allclose(positions.reshape(-1, 3), corners.reshape(-1, 3), atol=1e-6)
    pairs = np.empty(2 * len(mesh.edges), np.int32)
    mesh.attributes[".edge_verts"].data.foreach_get("value", pairs)
    expected = (edges[None] + 8 * np.arange(len(corners))[:, None, None]).reshape(-1, 2)
    np.testing.assert_array_equal(pairs.reshape(-1, 2), expected)
    assert len(mesh.polygons) == 0 and not mesh.validate()
    assert (obj.display_type, obj.hide_render, obj.hide_select) == ("WIRE", True, True)
    assert [c.name for c in obj.users_collection] == ["VoRTX Result"]
    assert list(obj["vortx_tile_states"]) == [t.state.value for t in posed.plan.tiles]
    # Baking again replaces the object (and its mesh) rather than piling them up.
    assert bpy.ops.vortx.bake_tiles() == {"FINISHED"}
    assert [o.name for o in bpy.data.objects if o.get("vortx_tiles")] == ["VoRTX Tiles"]
    assert len(bpy.data.meshes) == 1
