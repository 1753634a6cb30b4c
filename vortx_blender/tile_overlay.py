"""The reconstruction tiles in the 3D View: a live gpu overlay, and an optional baked wireframe object.

Geometry comes from the engine (`engine.recon.tile_grid`: box corners and the 12 box edges) and is
kept as numpy here. Two ways to show it (blender-notes.md section 4):
- Overlay: a SpaceView3D draw handler draws the boxes as lines coloured by tile state (pending grey,
  running yellow, done green, empty dark red). During a reconstruction the engine updates the plan's
  Tile objects in place from the worker thread; the job operator's timer redraws the 3D Views, so the
  colours follow the run. Every gpu call lives inside the draw callback: it only runs with a UI,
  and headless (tests, `blender -b`) gpu calls fail, so nothing here may touch gpu outside it.
- Bake (`bake_tiles`): one mesh of loose edges, displayed as wire, not rendered, not selectable. It is
  saved with the .blend file and shows in renders of the viewport; it costs an outliner entry.

The overlay is not scene data (it is not saved and has no undo). It belongs to one scene, identified by
its `session_uid` (stable across renames and undo, new for a scene loaded from another file), so
tiles never show over a different room after a file load, without a load handler of their own.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional, Sequence

import bpy
import gpu
import numpy as np
from gpu_extras.batch import batch_for_shader

from ..engine.recon import tile_grid
from .scene_objects import find_frame_empty, place_new

if TYPE_CHECKING:
    from ..engine.recon import Tile

# RGBA per TileState value. Empty tiles stay faintly visible: they show where no photo looked.
STATE_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "pending": (0.6, 0.6, 0.6, 0.5),
    "running": (1.0, 0.85, 0.1, 1.0),
    "done": (0.25, 0.9, 0.35, 0.9),
    "empty": (0.45, 0.1, 0.1, 0.45),
}
LINE_WIDTH = 2.0

TILES_OBJECT_TAG = "vortx_tiles"
TILES_OBJECT_NAME = "VoRTX Tiles"


@dataclass
class TileOverlay:
    """The tiles drawn for one scene. `tiles` is replaced (never mutated) by `set_tiles`; the engine
    mutates each Tile's `state` in place while it runs, which `states()` reads."""

    scene_uid: int  # bpy Scene.session_uid
    tiles: list["Tile"] = field(default_factory=list)
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 8, 3), np.float32))  # (T, 8, 3) world metres
    edges: np.ndarray = field(default_factory=lambda: np.zeros((12, 2), np.int32))  # (12, 2) into each box's corners

    def states(self) -> list[str]:
        return [tile.state.value for tile in self.tiles]

    def counts(self) -> dict[str, int]:
        """Tiles per state, e.g. {"done": 3, "running": 1, "pending": 8, "empty": 0}."""
        states = self.states()
        return {state: states.count(state) for state in STATE_COLOURS}

    def segments(self, select: Optional[np.ndarray] = None) -> np.ndarray:
        """Line segment end points (2 * 12 * T, 3) float32: box t's edge e is rows 24 t + 2 e, + 1."""
        corners = self.corners if select is None else self.corners[select]
        return corners[:, self.edges.reshape(-1)].reshape(-1, 3).astype(np.float32)

    def segments_by_state(self) -> dict[str, np.ndarray]:
        """{state: segments of the tiles in that state}, only for states that have tiles."""
        states = np.array(self.states(), dtype=object)
        out = {}
        for state in STATE_COLOURS:
            select = states == state
            if select.any():
                out[state] = self.segments(select)
        return out


def overlay_from_tiles(scene_uid: int, tiles: Sequence["Tile"]) -> TileOverlay:
    """Overlay data for `tiles` from the engine's tile_grid (numpy only: safe on the worker thread)."""
    corners, edges, _ = tile_grid(list(tiles))
    return TileOverlay(scene_uid, list(tiles), corners.astype(np.float32), edges.astype(np.int32))


# --- the overlay shown now, and the one to go back to when a run fails -----------------------------

_lock = threading.Lock()
_current: Optional[TileOverlay] = None
_in_run = False
_before_run: Optional[TileOverlay] = None
_handle: Optional[object] = None


def current(scene: Optional[bpy.types.Scene] = None) -> Optional[TileOverlay]:
    """The overlay shown now; with `scene`, only if it belongs to that scene."""
    overlay = _current
    if scene is not None and (overlay is None or overlay.scene_uid != scene.session_uid):
        return None
    return overlay


def show(scene_uid: int, tiles: Sequence["Tile"]) -> TileOverlay:
    """Show `tiles` for the scene. Called from the worker thread during a run, so no bpy here: the
    draw handler is already registered by `begin_run`."""
    global _current
    overlay = overlay_from_tiles(scene_uid, tiles)
    with _lock:
        _current = overlay
    return overlay


def begin_run(scene_uid: int, show_tiles: bool) -> None:
    """A run starts (main thread): remember what was shown, clear it, ready the draw handler."""
    global _current, _before_run, _in_run
    with _lock:
        if not _in_run:
            _before_run = _current
        _in_run = True
        _current = TileOverlay(scene_uid)
    sync_draw_handler(show_tiles)


def end_run(succeeded: bool) -> None:
    """Keep the run's tiles (their final states) on success; otherwise show what was there before.
    Does nothing when no run began (a run refused before starting leaves the overlay alone)."""
    global _current, _before_run, _in_run
    with _lock:
        if not _in_run:
            return
        if not succeeded:
            _current = _before_run
        _before_run = None
        _in_run = False


def clear() -> None:
    global _current, _before_run, _in_run
    with _lock:
        _current = None
        _before_run = None
        _in_run = False


def status_detail() -> str:
    """Tile counts for the status bar while a run goes on, e.g. "tiles 3/12 done, 1 running"."""
    overlay = _current
    if overlay is None or not overlay.tiles:
        return ""
    counts = overlay.counts()
    active = len(overlay.tiles) - counts["empty"]
    text = f"tiles {counts['done']}/{active} done"
    if counts["running"]:
        text += f", {counts['running']} running"
    return text


# --- the draw handler --------------------------------------------------------------------------------


def draw_handler_registered() -> bool:
    return _handle is not None


def sync_draw_handler(show_tiles: bool) -> None:
    """Register the draw handler while tiles are to be shown, remove it otherwise (main thread).

    Registering is plain bookkeeping and works headless; only the callback touches gpu, and Blender
    calls it only when it draws a 3D View.
    """
    global _handle
    if show_tiles and _handle is None:
        _handle = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")
    elif not show_tiles and _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None


def _draw() -> None:
    overlay = _current
    context = bpy.context
    scene = context.scene
    if overlay is None or not overlay.tiles or scene is None or scene.session_uid != overlay.scene_uid:
        return
    if not scene.vortx.show_tiles:  # another scene's setting may have registered the handler
        return
    # The shader is fetched here, lazily: this is the only place a GPU context exists.
    # POLYLINE_UNIFORM_COLOR draws wide lines on every backend (UNIFORM_COLOR's line width is
    # ignored on Metal/Vulkan).
    shader = gpu.shader.from_builtin("POLYLINE_UNIFORM_COLOR")
    frame = find_frame_empty(scene)  # tiles are in the engine's world: shown where the scene shows it (scene_objects.py)
    gpu.matrix.push()
    if frame is not None:
        gpu.matrix.multiply_matrix(frame.matrix_world)
    gpu.state.blend_set("ALPHA")
    # No depth test: tiles enclose the mesh, and seeing the whole grid through it is the point.
    gpu.state.depth_test_set("NONE")
    shader.uniform_float("viewportSize", gpu.state.viewport_get()[2:])
    shader.uniform_float("lineWidth", LINE_WIDTH)
    for state, segments in overlay.segments_by_state().items():
        batch = batch_for_shader(shader, "LINES", {"pos": segments})
        shader.uniform_float("color", STATE_COLOURS[state])
        batch.draw(shader)
    gpu.state.blend_set("NONE")
    gpu.matrix.pop()


# --- baked wireframe object ----------------------------------------------------------------------------


def wire_arrays(overlay: TileOverlay) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8 T, 3) float32 and loose edges (12 T, 2) int32 of all tile boxes."""
    count = len(overlay.corners)
    vertices = overlay.corners.reshape(-1, 3).astype(np.float32)
    edges = (overlay.edges[None, :, :] + 8 * np.arange(count, dtype=np.int32)[:, None, None]).reshape(-1, 2)
    return vertices, edges.astype(np.int32)


def find_tiles_object(scene: bpy.types.Scene) -> Optional[bpy.types.Object]:
    for obj in scene.objects:
        if obj.get(TILES_OBJECT_TAG):
            return obj
    return None


def bake_tiles(scene: bpy.types.Scene, overlay: TileOverlay, collection: bpy.types.Collection) -> bpy.types.Object:
    """Replace the scene's baked tile object with one wire mesh of `overlay`'s boxes in `collection`."""
    vertices, edges = wire_arrays(overlay)
    mesh = bpy.data.meshes.new(TILES_OBJECT_NAME)
    mesh.vertices.add(len(vertices))
    mesh.edges.add(len(edges))
    # The attribute API with exact dtypes is the fast path (blender-notes.md section 5).
    mesh.attributes["position"].data.foreach_set("vector", vertices.ravel())
    mesh.attributes[".edge_verts"].data.foreach_set("value", edges.ravel())
    mesh.update()
    obj = bpy.data.objects.new(TILES_OBJECT_NAME, mesh)
    obj[TILES_OBJECT_TAG] = True
    obj["vortx_tile_states"] = overlay.states()
    obj.display_type = "WIRE"
    obj.hide_render = True
    obj.hide_select = True  # a helper: clicking the room should select the room, not a tile box
    old = find_tiles_object(scene)
    if old is not None:
        old_mesh = old.data
        bpy.data.objects.remove(old, do_unlink=True)
        if old_mesh is not None and old_mesh.users == 0:
            bpy.data.meshes.remove(old_mesh)
    collection.objects.link(obj)
    place_new(obj, scene)
    obj.name = mesh.name = TILES_OBJECT_NAME  # the removed object freed the name (new ones got ".001")
    return obj


# --- registration -------------------------------------------------------------------------------------


def register() -> None:
    pass  # the draw handler is added when tiles are first shown (begin_run / sync_draw_handler)


def unregister() -> None:
    clear()
    sync_draw_handler(False)
