"""Export a result mesh to GLB/glTF, PLY or OBJ with the options that keep it a faithful room.

All three keep metres (scale 1, modifiers and the object transform applied) and the vertex colours:
- PLY and OBJ are written in Blender's own axes (forward +Y, up +Z), so file coordinates equal the
  world coordinates in metres with Z up, the convention of the engine and of its PLY files. (OBJ's
  exporter defaults to Y up; that default is overridden.) Colours are sRGB bytes / floats, as the
  photos were.
- glTF is Y-up by specification, and VR viewers rely on it: the exporter's +Y-up conversion stays
  on, so the room stands upright in a headset, and importing the file back into Blender gives the
  same Z-up world coordinates. Vertex colours go into COLOR_0 (linear, as glTF requires), and the
  object's `vortx_*` custom properties into the node's extras (provenance travels with the file).

Exporters work on the selection, so the selection and active object are set for the call and put
back afterwards.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import bpy

from ..engine.errors import VortxError

FORMATS = {".glb": "GLB", ".gltf": "glTF", ".ply": "PLY", ".obj": "OBJ"}
FILE_GLOB = "*.glb;*.gltf;*.ply;*.obj"


@contextmanager
def _only_selected(obj: bpy.types.Object, view_layer: bpy.types.ViewLayer) -> Iterator[None]:
    # View layers list newly linked objects only after a sync; the exporters evaluate it anyway.
    view_layer.update()
    if view_layer.objects.get(obj.name) is None:
        raise VortxError(f"'{obj.name}' is not in the view layer '{view_layer.name}', so it cannot be exported")
    selected = [o for o in view_layer.objects if o.select_get(view_layer=view_layer)]
    active = view_layer.objects.active
    hidden = obj.hide_get(view_layer=view_layer)
    try:
        for o in selected:
            o.select_set(False, view_layer=view_layer)
        obj.hide_set(False, view_layer=view_layer)  # hidden objects count as unselected to exporters
        obj.select_set(True, view_layer=view_layer)
        view_layer.objects.active = obj
        yield
    finally:
        obj.select_set(False, view_layer=view_layer)
        obj.hide_set(hidden, view_layer=view_layer)
        for o in selected:
            o.select_set(True, view_layer=view_layer)
        view_layer.objects.active = active


@contextmanager
def _photo_colours_shown(obj: bpy.types.Object) -> Iterator[None]:
    """The exporters write the shown colour attribute: a result showing its confidence layer (Show
    Observation) is exported with its photo colours, and shown as before afterwards."""
    from .result import SHOW_OBSERVATION, show_observation

    showing = bool(getattr(obj, SHOW_OBSERVATION, False))
    if showing:
        show_observation(obj, False)
    try:
        yield
    finally:
        if showing:
            show_observation(obj, True)


def export_result(obj: bpy.types.Object, path: str | Path, view_layer: bpy.types.ViewLayer | None = None) -> Path:
    """Write `obj` to `path`; the format comes from the extension (.glb, .gltf, .ply, .obj).

    Raises VortxError for an unknown extension, a non-mesh object or a failed export.
    """
    path = Path(bpy.path.abspath(str(path)))
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise VortxError(f"cannot export to '{path.name}': use a .glb, .gltf, .ply or .obj file name")
    if obj.type != "MESH":
        raise VortxError(f"'{obj.name}' is not a mesh")
    path.parent.mkdir(parents=True, exist_ok=True)
    view_layer = view_layer or bpy.context.view_layer
    with _only_selected(obj, view_layer), _photo_colours_shown(obj):
        if kind == "PLY":
            outcome = bpy.ops.wm.ply_export(
                filepath=str(path), export_selected_objects=True, forward_axis="Y", up_axis="Z", global_scale=1.0,
                apply_modifiers=True, export_normals=True, export_uv=False, export_colors="SRGB",
                export_attributes=False, export_triangulated_mesh=True, ascii_format=False,
            )
        elif kind == "OBJ":
            outcome = bpy.ops.wm.obj_export(
                filepath=str(path), export_selected_objects=True, forward_axis="Y", up_axis="Z", global_scale=1.0,
                apply_modifiers=True, apply_transform=True, export_normals=True, export_uv=False,
                export_colors=True, export_materials=False, export_triangulated_mesh=True,
            )
        else:
            outcome = bpy.ops.export_scene.gltf(
                filepath=str(path), export_format="GLB" if kind == "GLB" else "GLTF_SEPARATE", use_selection=True,
                export_yup=True, export_apply=True, export_normals=True, export_texcoords=False,
                export_vertex_color="ACTIVE", export_materials="EXPORT", export_extras=True,
                export_cameras=False, export_lights=False, export_animations=False,
            )
    if "FINISHED" not in outcome or not path.is_file():
        raise VortxError(f"the {kind} exporter did not write {path}")
    return path
