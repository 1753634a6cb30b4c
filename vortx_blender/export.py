"""Export a result mesh to GLB/glTF, PLY or OBJ with the options that keep it a faithful room.

All three keep the scene's units (scale 1, modifiers and the object's world transform applied) and the
vertex colours. The world transform puts the mesh in the coordinates the scene shows (frame.py): the
Z-up world in metres, or with Coordinates = Capture the capture's own (the frame empty's transform),
as `engine reconstruct --frame` writes them; the object's `vortx_frame` record says which.
- PLY and OBJ are written in Blender's own axes (forward +Y, up +Z), so file coordinates equal the
  scene's coordinates: the world in metres with Z up, the convention of the engine and of its PLY
  files, or the capture's. (OBJ's exporter defaults to Y up; that default is overridden.) Colours are
  sRGB bytes / floats, as the photos were.
- glTF is Y-up by specification, and VR viewers rely on it: the exporter's +Y-up conversion stays
  on, so the room stands upright in a headset, and importing the file back into Blender gives the
  same Z-up world coordinates. Vertex colours go into COLOR_0 (linear, as glTF requires), the
  confidence layer into `_OBSERVATIONS`, `_STEREO_CONFIDENCE`, `_COMPLETED` (as in the engine's GLB),
  and the object's `vortx_*` custom properties into the node's extras (provenance and the frame record
  travel with the file). The world transform becomes the node's transform (identity in the world).

A result with a baked photo texture (vortx_blender/texture.py) exports it instead of the vertex
colours: glTF gets TEXCOORD_0 and a material whose base colour texture is the photo texture (PNG, as
packed), and no COLOR_0 (glTF viewers multiply the base colour by COLOR_0, which would darken the
texture by the photo colours a second time); OBJ gets its UVs, a .mtl and the texture copied beside
it (<stem>_texture.png). PLY has no textures: it keeps the vertex colours.

The scene's Headset preset (engine/texture/presets.py) shapes a GLB as it does the engine's: Draco
geometry through the glTF exporter's own Draco option, KTX2 textures (KHR_texture_basisu, with a
quarter-size PNG fallback) by rewriting the exported file with the engine's `glb_with_ktx2`. The file is
exported under a temporary name and renamed only when complete: a failed encoder leaves nothing behind.
- USDZ (Apple Vision Pro, Quick Look) through Blender's USD exporter: Y up, metres (meters per unit 1),
  the texture packed into the archive, a UsdPreviewSurface material.

Exporters work on the selection, so the selection and active object are set for the call and put
back afterwards.
"""

from __future__ import annotations

import tempfile
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Iterator

import bpy

from ..engine.errors import VortxError
from ..engine.observation import EVIDENCE_ATTRIBUTES
from ..engine.texture.encoders import basisu_path
from ..engine.texture.options import TextureOptions
from ..engine.texture.presets import with_preset
from .reconstruct import recon_settings_from_scene
from .result import SHOW_OBSERVATION, is_textured, show_observation, texture_image_of

FORMATS = {".glb": "GLB", ".gltf": "glTF", ".ply": "PLY", ".obj": "OBJ", ".usdz": "USDZ"}
FILE_GLOB = "*.glb;*.gltf;*.ply;*.obj;*.usdz"


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
    showing = bool(getattr(obj, SHOW_OBSERVATION, False))
    if showing:
        show_observation(obj, False)
    try:
        yield
    finally:
        if showing:
            show_observation(obj, True)


@contextmanager
def _texture_file_beside(obj: bpy.types.Object, path: Path) -> Iterator[None]:
    """The OBJ exporter copies a texture only from a file on disk, and a baked texture is packed into
    the .blend: its PNG is written beside the .obj as <stem>_texture.png (the engine's OBJ name) and the
    image points there while the exporter runs (path_mode STRIP writes that name into the .mtl)."""
    images = [image for image in map(texture_image_of, obj.data.materials) if image is not None]
    saved = [(image, image.filepath_raw) for image in images]
    try:
        for index, image in enumerate(images):
            target = path.with_name(f"{path.stem}_texture{'' if index == 0 else f'_{index}'}.png")
            if image.packed_file is not None:
                target.write_bytes(image.packed_file.data)
            else:
                image.save(filepath=str(target))
            image.filepath_raw = str(target)
        yield
    finally:
        for image, filepath in saved:
            image.filepath_raw = filepath


@contextmanager
def _texture_files_on_disk(obj: bpy.types.Object) -> Iterator[None]:
    """Blender's USD exporter puts a texture into the .usdz only from an image file on disk, and a baked
    texture is packed into the .blend: while the exporter runs, the material's image nodes show a
    temporary image loaded from the packed PNG written to a temporary folder; everything is put back."""
    swapped = []  # (node, its image, the temporary image)
    with tempfile.TemporaryDirectory(prefix="vortx_usdz_") as folder:
        try:
            for material in obj.data.materials:
                if material is None or material.node_tree is None:
                    continue
                for node in material.node_tree.nodes:
                    image = getattr(node, "image", None) if node.type == "TEX_IMAGE" else None
                    if image is None or image.packed_file is None:
                        continue
                    target = Path(folder) / f"{bpy.path.clean_name(image.name)}.png"
                    target.write_bytes(image.packed_file.data)
                    loaded = bpy.data.images.load(str(target))
                    loaded.colorspace_settings.name = image.colorspace_settings.name
                    swapped.append((node, image, loaded))
                    node.image = loaded
            yield
        finally:
            for node, image, loaded in swapped:
                node.image = image
                bpy.data.images.remove(loaded)


def export_result(obj: bpy.types.Object, path: str | Path, view_layer: bpy.types.ViewLayer | None = None,
                  headset: str | None = None) -> Path:
    """Write `obj` to `path`; the format comes from the extension (.glb, .gltf, .ply, .obj, .usdz).
    headset: the preset that shapes a .glb (None: the scene's Headset setting).

    Raises VortxError for an unknown extension, a non-mesh object or a failed export.
    """
    path = Path(bpy.path.abspath(str(path)))
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise VortxError(f"cannot export to '{path.name}': use a .glb, .gltf, .ply, .obj or .usdz file name")
    if kind == "GLB":
        return _export_glb_for_headset(obj, path, view_layer, headset)
    if obj.type != "MESH":
        raise VortxError(f"'{obj.name}' is not a mesh")
    path.parent.mkdir(parents=True, exist_ok=True)
    view_layer = view_layer or bpy.context.view_layer
    textured = is_textured(obj)
    with _only_selected(obj, view_layer), _photo_colours_shown(obj):
        if kind == "PLY":
            outcome = bpy.ops.wm.ply_export(
                filepath=str(path), export_selected_objects=True, forward_axis="Y", up_axis="Z", global_scale=1.0,
                apply_modifiers=True, export_normals=True, export_uv=False, export_colors="SRGB",
                export_attributes=True, export_triangulated_mesh=True, ascii_format=False,
            )
        elif kind == "OBJ":
            with _texture_file_beside(obj, path) if textured else nullcontext():
                outcome = bpy.ops.wm.obj_export(
                    filepath=str(path), export_selected_objects=True, forward_axis="Y", up_axis="Z", global_scale=1.0,
                    apply_modifiers=True, apply_transform=True, export_normals=True, export_uv=textured,
                    export_colors=not textured, export_materials=textured, path_mode="STRIP" if textured else "AUTO",
                    export_triangulated_mesh=True,
                )
        elif kind == "USDZ":
            with _texture_files_on_disk(obj) if textured else nullcontext():
                outcome = bpy.ops.wm.usd_export(
                    filepath=str(path), selected_objects_only=True, export_uvmaps=textured, export_normals=True,
                    export_mesh_colors=not textured, export_materials=True, generate_preview_surface=True,
                    export_textures_mode="NEW", convert_orientation=True, export_global_forward_selection="NEGATIVE_Z",
                    export_global_up_selection="Y", convert_scene_units="METERS", triangulate_meshes=True,
                    export_animation=False, export_lights=False, export_cameras=False, convert_world_material=False,
                    evaluation_mode="VIEWPORT",
                )
        else:
            with _confidence_for_gltf(obj):
                outcome = _export_gltf(path, kind, textured)
    if "FINISHED" not in outcome or not path.is_file():
        raise VortxError(f"the {kind} exporter did not write {path}")
    return path


def _export_gltf(path: Path, kind: str, textured: bool, draco: bool = False) -> set[str]:
    return bpy.ops.export_scene.gltf(
        filepath=str(path), export_format="GLB" if kind == "GLB" else "GLTF_SEPARATE", use_selection=True,
        export_yup=True, export_apply=True, export_normals=True, export_texcoords=textured,
        export_vertex_color="NONE" if textured else "ACTIVE", export_materials="EXPORT",
        export_image_format="AUTO", export_extras=True, export_attributes=True,
        export_cameras=False, export_lights=False, export_animations=False,
        export_draco_mesh_compression_enable=draco,
        **({"export_draco_position_quantization": 14, "export_draco_texcoord_quantization": 14,
            "export_draco_normal_quantization": 10, "export_draco_mesh_compression_level": 7} if draco else {}),
    )


def headset_options(obj: bpy.types.Object, headset: str | None):
    """The texture options of `headset` (None: the Headset setting of a scene holding `obj`)."""
    if headset is None:
        scenes = list(obj.users_scene) or [bpy.context.scene]
        settings = getattr(scenes[0], "vortx", None)
        headset = recon_settings_from_scene(settings, with_weights=False).headset if settings is not None else "desktop"
    return with_preset(TextureOptions(), headset)


def _export_glb_for_headset(obj: bpy.types.Object, path: Path, view_layer: bpy.types.ViewLayer | None,
                            headset: str | None) -> Path:
    """A GLB shaped by the headset preset (Draco, KTX2), exported under a temporary name and renamed."""
    # defers cv2 (the KTX2 rewrite reads the texture with it): the extension registers without OpenCV
    from ..engine.texture.files import staged
    from ..engine.texture.ktx2 import glb_with_ktx2

    options = headset_options(obj, headset)
    needed_by = f"the '{options.preset}' headset preset"
    # Draco: Blender's glTF exporter has its own Draco library. KTX2: the encoder is checked first.
    if options.texture_format != "png" and is_textured(obj):
        basisu_path(needed_by)
    if view_layer is None:
        view_layer = bpy.context.view_layer
    if obj.type != "MESH":
        raise VortxError(f"'{obj.name}' is not a mesh")
    textured = is_textured(obj)
    with staged([path]) as (temporary,):
        exported = temporary.with_name(temporary.name + ".glb")  # the exporter wants the suffix
        try:
            with _only_selected(obj, view_layer), _photo_colours_shown(obj), _confidence_for_gltf(obj):
                outcome = _export_gltf(exported, "GLB", textured, draco=options.geometry == "draco")
            if "FINISHED" not in outcome or not exported.is_file():
                raise VortxError(f"the GLB exporter did not write {path}")
            data = exported.read_bytes()
            if options.texture_format != "png" and textured:
                data = glb_with_ktx2(data, options.texture_format, needed_by)
            temporary.write_bytes(data)
        finally:
            exported.unlink(missing_ok=True)
    return path


@contextmanager
def _confidence_for_gltf(obj: bpy.types.Object) -> Iterator[None]:
    """The confidence layer as glTF custom attributes (`_OBSERVATIONS`, ...: glTF's rule for
    application-specific semantics, the names the engine's GLB uses). Blender's exporter writes only
    attributes whose name starts with an underscore, so upper-case copies live on the mesh for the
    export and are removed afterwards."""
    mesh = obj.data
    made = []
    try:
        for name in EVIDENCE_ATTRIBUTES:
            source = mesh.attributes.get(name)
            if source is None or source.domain != "POINT" or source.data_type != "FLOAT":
                continue
            values = [0.0] * len(mesh.vertices)
            source.data.foreach_get("value", values)
            copy = mesh.attributes.new("_" + name.upper(), "FLOAT", "POINT")
            made.append(copy.name)
            copy.data.foreach_set("value", values)
        yield
    finally:
        for name in made:
            attribute = mesh.attributes.get(name)
            if attribute is not None:
                mesh.attributes.remove(attribute)
