"""The capture's sparse 3D points (SfM's, a COLMAP model's points3D) as one object in the capture collection.

Photogrammetry importers show these points so the user sees the scene before reconstructing and can
pick points on it (Set Scale). The object is a mesh of vertices only, with the points' colours in a
point colour attribute:
- Edit Mode shows and selects the vertices, which is how two points are picked;
- Blender draws no loose vertices in Object Mode, so a Geometry Nodes modifier (Mesh to Points)
  turns them into points there, which Solid mode draws with the attribute colours
  (Viewport Shading > Color > Attribute).

The object's vertices are the capture's points in the engine's world coordinates (the object keeps an
identity transform relative to that world: under the frame empty when the scene shows the capture's
own coordinates, scene_objects.py), so `scene_points` reads them back exactly as the engine wrote them, up to float32.
"""

from __future__ import annotations

from typing import Optional

import bmesh
import bpy
import numpy as np

from ..engine.colour_space import linear_to_srgb
from .result import COLOUR_ATTRIBUTE, set_point_colours
from .scene_objects import engine_matrix, ensure_capture_collection, find_capture_collection, place_new

POINT_CLOUD_NAME = "VoRTX Sparse Points"
POINT_CLOUD_TAG = "vortx_points"  # custom property marking the object we own
POINTS_MODIFIER = "VoRTX Points"
POINTS_NODE_GROUP = "VoRTX Mesh to Points"
POINT_RADIUS_M = 0.01  # drawn size in Object Mode: visible in a room, small enough not to hide the walls


def is_point_cloud(obj: "bpy.types.Object") -> bool:
    return obj.type == "MESH" and bool(obj.get(POINT_CLOUD_TAG))


def find_point_cloud(scene: "bpy.types.Scene") -> Optional["bpy.types.Object"]:
    """The scene's sparse-points object, or None."""
    collection = find_capture_collection(scene)
    if collection is None:
        return None
    return next((obj for obj in collection.objects if is_point_cloud(obj)), None)


def scene_points(scene: "bpy.types.Scene") -> tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """(points (N, 3) float64 in the engine's world, colours (N, 3) uint8) of the scene's sparse points, or (None, None)."""
    obj = find_point_cloud(scene)
    if obj is None:
        return None, None
    mesh = obj.data
    if mesh.is_editmode:  # the edit mesh holds the data then; the Mesh's own arrays are stale or empty
        local, rgba = _edit_mesh_arrays(mesh, COLOUR_ATTRIBUTE)
    else:
        local = np.empty(3 * len(mesh.vertices), dtype=np.float32)
        mesh.vertices.foreach_get("co", local)
        local = local.reshape(-1, 3)
        attribute = mesh.color_attributes.get(COLOUR_ATTRIBUTE)
        rgba = None
        if attribute is not None and attribute.domain == "POINT" and len(attribute.data) == len(local):
            rgba = np.empty(4 * len(local), dtype=np.float32)
            attribute.data.foreach_get("color", rgba)
            rgba = rgba.reshape(-1, 4)
    matrix = engine_matrix(obj, scene)
    points = local.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
    colours = None
    if rgba is not None and len(rgba):
        colours = np.clip(np.round(linear_to_srgb(rgba[:, :3]) * 255.0), 0, 255).astype(np.uint8)
    return points, colours


def _edit_mesh_arrays(mesh: "bpy.types.Mesh", colour_name: str) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(positions (N, 3), linear RGBA (N, 4) or None) of a mesh in Edit Mode, from its BMesh."""
    bm = bmesh.from_edit_mesh(mesh)
    local = np.array([vertex.co[:] for vertex in bm.verts], dtype=np.float64).reshape(-1, 3)
    layer = bm.verts.layers.float_color.get(colour_name)
    if layer is None:
        return local, None
    return local, np.array([vertex[layer][:] for vertex in bm.verts], dtype=np.float32).reshape(-1, 4)


def checked_points(points: Optional[np.ndarray], colours: Optional[np.ndarray]) -> tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """Points (N, 3) float32 and colours (N, 3) float 0..1 sRGB ready for `apply_point_cloud`, computed
    before any Blender data is touched; (None, None) when there are no points."""
    if points is None or len(points) == 0:
        return None, None
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(points), axis=1)
    if colours is None:
        colours = np.full((len(points), 3), 128, dtype=np.uint8)
    colours = np.asarray(colours).reshape(-1, 3)
    if len(colours) != len(points):
        raise ValueError(f"{len(points)} sparse points but {len(colours)} colours")
    return points[keep].astype(np.float32), colours[keep].astype(np.float32) / 255.0


def apply_point_cloud(scene: "bpy.types.Scene", points: Optional[np.ndarray], colours: Optional[np.ndarray]) -> Optional["bpy.types.Object"]:
    """Replace the scene's sparse-points object with `points` (N, 3) float32 world and `colours`
    (N, 3) 0..1 sRGB from `checked_points`; with no points, just remove the old one."""
    old = find_point_cloud(scene)
    if old is not None:
        data = old.data
        bpy.data.objects.remove(old, do_unlink=True)
        if data.users == 0:
            bpy.data.meshes.remove(data)
    if points is None:
        return None
    collection = ensure_capture_collection(scene)
    mesh = bpy.data.meshes.new(POINT_CLOUD_NAME)
    mesh.vertices.add(len(points))
    mesh.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(points, dtype=np.float32).ravel())
    mesh.update()
    set_point_colours(mesh, colours)
    obj = bpy.data.objects.new(POINT_CLOUD_NAME, mesh)
    obj[POINT_CLOUD_TAG] = True
    # A guide for the viewport (seeing the scene, picking points for Set Scale), not part of the
    # room: renders of the result must not show it.
    obj.hide_render = True
    modifier = obj.modifiers.new(POINTS_MODIFIER, "NODES")
    modifier.node_group = _mesh_to_points_group()
    collection.objects.link(obj)
    place_new(obj, scene)
    return obj


def scale_point_cloud(scene: "bpy.types.Scene", obj: "bpy.types.Object", points: np.ndarray) -> None:
    """Move the point cloud's vertices to `points` (N, 3) in the engine's world (same count, same order),
    also in Edit Mode."""
    local = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inverse = np.linalg.inv(engine_matrix(obj, scene))
    local = local @ inverse[:3, :3].T + inverse[:3, 3]
    mesh = obj.data
    if mesh.is_editmode:
        bm = bmesh.from_edit_mesh(mesh)
        bm.verts.ensure_lookup_table()
        for vertex, co in zip(bm.verts, local):
            vertex.co = co
        bmesh.update_edit_mesh(mesh)
    else:
        mesh.vertices.foreach_set("co", local.astype(np.float32).ravel())
        mesh.update()


def _mesh_to_points_group() -> "bpy.types.NodeTree":
    """The Geometry Nodes group Mesh -> Points (shared by every point cloud; made once per file)."""
    group = bpy.data.node_groups.get(POINTS_NODE_GROUP)
    if group is not None and group.bl_idname == "GeometryNodeTree":
        return group
    group = bpy.data.node_groups.new(POINTS_NODE_GROUP, "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    inputs = group.nodes.new("NodeGroupInput")
    outputs = group.nodes.new("NodeGroupOutput")
    to_points = group.nodes.new("GeometryNodeMeshToPoints")
    to_points.inputs["Radius"].default_value = POINT_RADIUS_M
    inputs.location, to_points.location, outputs.location = (-300, 0), (0, 0), (300, 0)
    group.links.new(inputs.outputs[0], to_points.inputs["Mesh"])
    group.links.new(to_points.outputs[0], outputs.inputs[0])
    return group
