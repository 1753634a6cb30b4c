"""The reconstructed mesh in Blender: fast insertion, vertex colours, material, result collection.

Insertion follows blender-notes.md section 5: float32 positions into the `position` attribute, int32
corners into `.corner_vert`, `loop_start`, then one `update(calc_edges=True)`; colours as a FLOAT_COLOR
point attribute filled with `foreach_set`. A 2 M-triangle room goes in in about a second.

Colour management: the engine's colours are photo values (sRGB-encoded, 0..1). Blender's float colour
attributes hold scene-linear values, so they are linearised on the way in (`srgb_to_linear`); Blender
shows them as the photos looked, and `color_srgb` reads back the engine's values. Exporters then write
what each format expects (PLY/OBJ bytes in sRGB, glTF linear floats).

The result objects live in a "VoRTX Result" collection (found by a tag, so renaming it is fine) and
carry how they were made as custom properties (`vortx_*`), so a .blend file documents its meshes.

The confidence layer (engine/stereo/vertex_evidence.py): the engine's per-vertex attributes
(observations, stereo_confidence, completed) become FLOAT point attributes of the same names, and an
"Observation" colour attribute shows them red (seen by few photos or weak matches: take more photos
there) to green (well observed). The object's `vortx_show_observation` toggle switches which colour
attribute the viewport and the material show; it changes no geometry.

A baked result (vortx_blender/texture.py) has its own material, "VoRTX Texture", whose Image
Texture node holds the packed photo texture; the toggle relinks that material's base colour between
the texture and the observation colours instead of swapping the material (which holds the only
reference to the texture).
"""

from __future__ import annotations

import datetime
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import bpy
import numpy as np

from .. import engine
from ..engine.colour_space import linear_to_srgb, srgb_to_linear  # noqa: F401 (re-exported)
from ..engine.mesh_io import Mesh
from ..engine.observation import ADDED, EVIDENCE_ATTRIBUTES, observation_colours
from .scene_objects import ensure_tagged_collection, find_tagged_collection, place_new

RESULT_COLLECTION_NAME = "VoRTX Result"
COLLECTION_TAG = "vortx_result_collection"
RESULT_TAG = "vortx_result"
MATERIAL_TAG = "vortx_vertex_colour"
MATERIAL_NAME = "VoRTX Vertex Colour"
COLOUR_ATTRIBUTE = "Color"
OBSERVATION_ATTRIBUTE = "Observation"  # the confidence layer's colours (FLOAT_COLOR point attribute)
OBSERVATION_MATERIAL_TAG = "vortx_observation_colour"
OBSERVATION_MATERIAL_NAME = "VoRTX Observation Colour"
SHOW_OBSERVATION = "vortx_show_observation"  # the Object toggle (registered below)
TEXTURE_MATERIAL_TAG = "vortx_texture_material"  # a baked result's own material (vortx_blender/texture.py)
TEXTURE_MATERIAL_NAME = "VoRTX Texture"
TEXTURE_NODE = "VoRTX Photo Texture"  # its Image Texture node
TEXTURE_OBSERVATION_NODE = "VoRTX Observation"  # its Color Attribute node reading the confidence layer
DECIMATE_MODIFIER = "VoRTX Decimate"
# The faces the finishing stage added where no photo saw surface (engine/finish), as a BOOLEAN face
# attribute: Edit Mode > Select > By Attribute selects them (to delete, or to give them a material).
ADDED_FACES_ATTRIBUTE = "added_faces"

# Custom properties on a result object.
PROP_CAPTURE = "vortx_capture"
PROP_SETTINGS = "vortx_settings"
PROP_WEIGHTS = "vortx_weights"
PROP_VERSION = "vortx_version"
PROP_ENGINE_VERSION = "vortx_engine_version"
PROP_CREATED = "vortx_created"
PROP_STATS = "vortx_stats"
# The coordinates the result is shown and exported in, and the similarities capture <-> world (JSON of
# `engine.recon.output_frame.frame_record`; vortx_blender/frame.py keeps it current). The name is the
# one `engine reconstruct` gives the record in a GLB's extras (capture cameras use the key for their
# frame index: a result is never a camera).
PROP_OUTPUT_FRAME = "vortx_frame"


@dataclass(frozen=True)
class Provenance:
    """How a result was made; stored on the object as custom properties."""

    capture_path: str
    settings: dict[str, Any]  # engine ReconSettings.to_dict() plus the Blender-side options
    weights: str  # the engine's label: a path, "random (seed 0)", ...
    stats: dict[str, Any]  # a JSON-friendly summary of the run

    def write(self, obj: bpy.types.Object) -> None:
        obj[RESULT_TAG] = True
        obj[PROP_CAPTURE] = self.capture_path
        obj[PROP_SETTINGS] = json.dumps(self.settings, sort_keys=True)
        obj[PROP_WEIGHTS] = self.weights
        obj[PROP_VERSION] = extension_version()
        obj[PROP_ENGINE_VERSION] = engine.__version__
        obj[PROP_CREATED] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        obj[PROP_STATS] = json.dumps(self.stats, sort_keys=True)


def extension_version() -> str:
    """The `version` of blender_manifest.toml in the extension root (the installed package's version)."""
    manifest = Path(__file__).resolve().parents[1] / "blender_manifest.toml"
    try:
        with open(manifest, "rb") as f:
            return str(tomllib.load(f)["version"])
    except (OSError, KeyError, tomllib.TOMLDecodeError):
        return "unknown"


# --- mesh datablock ---------------------------------------------------------------------------------


def build_mesh(
    name: str, vertices: np.ndarray, faces: np.ndarray, colors: Optional[np.ndarray],
    attributes: Optional[dict[str, np.ndarray]] = None,
) -> bpy.types.Mesh:
    """A new Mesh datablock of triangles (not linked to anything), smooth shaded, with a colour attribute.

    vertices (V, 3) float32 world metres; faces (F, 3) int32; colors (V, 3) float 0..1 sRGB or None;
    attributes: name -> (V,) per-vertex values, stored as FLOAT point attributes (with the evidence
    attributes also the Observation colours); the photo colours stay the shown ones.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    mesh = bpy.data.meshes.new(name)
    try:
        mesh.vertices.add(len(vertices))
        mesh.loops.add(3 * len(faces))
        mesh.polygons.add(len(faces))
        # float64/int64 would drop to the slow per-item path (blender-notes.md section 5): dtypes are exact.
        mesh.attributes["position"].data.foreach_set("vector", vertices.ravel())
        mesh.attributes[".corner_vert"].data.foreach_set("value", faces.ravel())
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
        mesh.update(calc_edges=True)
        # Marching-cubes surfaces are sampled smooth surfaces; flat shading would show every 4 cm facet.
        mesh.shade_smooth()
        set_vertex_attributes(mesh, attributes or {})
        if colors is not None:
            set_point_colours(mesh, colors)
        if attributes and ADDED in attributes:  # last: the active attribute is set by index
            set_added_faces(mesh, faces, attributes[ADDED])
    except Exception:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def set_added_faces(mesh: bpy.types.Mesh, faces: np.ndarray, added: np.ndarray) -> bpy.types.Attribute:
    """The BOOLEAN face attribute ADDED_FACES_ATTRIBUTE: True on the faces (F, 3) whose corners are all
    marked added (`added` (V,) 1 / 0, the engine's ADDED vertex attribute), made the active attribute so
    Select > By Attribute picks them at once."""
    flags = (np.asarray(added, np.float32)[np.asarray(faces).reshape(-1, 3)] > 0.5).all(axis=1)
    attribute = mesh.attributes.new(ADDED_FACES_ATTRIBUTE, "BOOLEAN", "FACE")
    attribute.data.foreach_set("value", flags)
    mesh.attributes.active_index = mesh.attributes.find(ADDED_FACES_ATTRIBUTE)
    return attribute


def set_point_colours(mesh: bpy.types.Mesh, colors: np.ndarray) -> bpy.types.Attribute:
    """(Re)create the FLOAT_COLOR point attribute from sRGB colours (V, 3) and make it the shown one."""
    colors = np.asarray(colors, dtype=np.float32).reshape(-1, 3)
    if len(colors) != len(mesh.vertices):
        raise ValueError(f"{len(colors)} colours for {len(mesh.vertices)} vertices")
    old = mesh.color_attributes.get(COLOUR_ATTRIBUTE)
    if old is not None:
        mesh.color_attributes.remove(old)
    attribute = mesh.color_attributes.new(COLOUR_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    rgba = np.ones((len(colors), 4), dtype=np.float32)
    rgba[:, :3] = srgb_to_linear(colors)
    attribute.data.foreach_set("color", rgba.ravel())
    # Active = what the viewport's Attribute colour mode shows; render = what Color Attribute nodes
    # with an empty name read. Both by index, which is stable until attributes are added.
    mesh.color_attributes.active_color = attribute
    mesh.color_attributes.render_color_index = mesh.color_attributes.find(COLOUR_ATTRIBUTE)
    return attribute


def set_vertex_attributes(mesh: bpy.types.Mesh, attributes: dict[str, np.ndarray]) -> None:
    """FLOAT point attributes from (V,) arrays, and the Observation colours when the evidence is complete.

    Names Blender already uses on the mesh (position, ...) are refused: they would clobber geometry.
    """
    for name, values in attributes.items():
        values = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
        if len(values) != len(mesh.vertices):
            raise ValueError(f"attribute {name!r} has {len(values)} values for {len(mesh.vertices)} vertices")
        if name.startswith(".") or name in mesh.attributes or name == OBSERVATION_ATTRIBUTE:
            raise ValueError(f"attribute name {name!r} is taken by Blender or VoRTX on mesh '{mesh.name}'")
        mesh.attributes.new(name, "FLOAT", "POINT").data.foreach_set("value", values)
    if all(name in attributes for name in EVIDENCE_ATTRIBUTES):
        colours = observation_colours(attributes)
        layer = mesh.color_attributes.new(OBSERVATION_ATTRIBUTE, "FLOAT_COLOR", "POINT")
        rgba = np.ones((len(colours), 4), dtype=np.float32)
        rgba[:, :3] = srgb_to_linear(colours)
        layer.data.foreach_set("color", rgba.ravel())


def vertex_attributes(mesh: bpy.types.Mesh) -> dict[str, np.ndarray]:
    """The evidence attributes present on `mesh`, name -> (V,) float32 (the inverse of set_vertex_attributes
    for the names the engine writes)."""
    out = {}
    for name in EVIDENCE_ATTRIBUTES:
        attribute = mesh.attributes.get(name)
        if attribute is not None and attribute.domain == "POINT" and attribute.data_type == "FLOAT":
            values = np.empty(len(mesh.vertices), dtype=np.float32)
            attribute.data.foreach_get("value", values)
            out[name] = values
    return out


def has_observation(mesh: bpy.types.Mesh) -> bool:
    """Whether the mesh carries the confidence layer (results made before it, or by other tools, do not)."""
    return mesh.color_attributes.get(OBSERVATION_ATTRIBUTE) is not None


def show_colour_attribute(mesh: bpy.types.Mesh, name: str) -> None:
    """Make the colour attribute `name` the one the viewport (active) and Color Attribute nodes (render) show."""
    attribute = mesh.color_attributes.get(name)
    if attribute is None:
        return
    mesh.color_attributes.active_color = attribute
    mesh.color_attributes.render_color_index = mesh.color_attributes.find(name)


def show_observation(obj: bpy.types.Object, show: bool) -> None:
    """Show `obj`'s confidence layer (True) or its photo colours (False): the shown colour attribute and,
    in the slots holding one of our two materials, the material that reads it. Geometry is untouched;
    a mesh without the layer keeps its photo colours."""
    mesh = obj.data
    show = bool(show) and has_observation(mesh)
    show_colour_attribute(mesh, OBSERVATION_ATTRIBUTE if show else COLOUR_ATTRIBUTE)
    for index, material in enumerate(mesh.materials):
        if material is None:
            continue
        if material.get(MATERIAL_TAG) or material.get(OBSERVATION_MATERIAL_TAG):
            mesh.materials[index] = observation_material() if show else vertex_colour_material()
        elif material.get(TEXTURE_MATERIAL_TAG):
            # A baked result keeps its own material (it holds the only reference to its texture):
            # its base colour is switched between the photo texture and the observation colours.
            show_texture_base_colour(material, observation=show)


def shown_colour_attribute(mesh: bpy.types.Mesh) -> Optional[str]:
    """The name of the colour attribute the viewport shows, or None."""
    active = mesh.color_attributes.active_color
    return active.name if active is not None else None


def _show_observation_changed(obj: bpy.types.Object, context: bpy.types.Context) -> None:
    show = getattr(obj, SHOW_OBSERVATION)
    show_observation(obj, show)
    if is_textured(obj):
        # Solid mode draws either attribute colours or the material's image, not the material's links.
        _solid_colour(context.screen, "VERTEX" if show and has_observation(obj.data) else "TEXTURE")


def mesh_arrays(mesh: bpy.types.Mesh, triangulate: bool = False) -> Mesh:
    """The triangle mesh of a Blender mesh as engine arrays (colours back in sRGB, normals None).

    Polygons must be triangles (as VoRTX results and their decimations are), unless `triangulate`:
    then other polygons are split into Blender's own loop triangles (as its renderers draw them).
    """
    vertices = np.empty(3 * len(mesh.vertices), dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", vertices)
    sizes = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    if len(sizes) and np.any(sizes != 3):
        if not triangulate:
            raise ValueError(f"mesh '{mesh.name}' has polygons that are not triangles")
        mesh.calc_loop_triangles()
        corners = np.empty(3 * len(mesh.loop_triangles), dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", corners)
    else:
        corners = np.empty(len(mesh.loops), dtype=np.int32)
        mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    colors = None
    attribute = mesh.color_attributes.get(COLOUR_ATTRIBUTE)
    if attribute is not None and attribute.domain == "POINT":
        rgba = np.empty(4 * len(mesh.vertices), dtype=np.float32)
        attribute.data.foreach_get("color", rgba)
        colors = linear_to_srgb(rgba.reshape(-1, 4)[:, :3])
    return Mesh(vertices=vertices.reshape(-1, 3), faces=corners.reshape(-1, 3), colors=colors,
                attributes=vertex_attributes(mesh))


# --- material ----------------------------------------------------------------------------------------


def vertex_colour_material() -> bpy.types.Material:
    """The shared material showing the photo colour attribute (reused while its tag is on it)."""
    return _colour_attribute_material(MATERIAL_TAG, MATERIAL_NAME, COLOUR_ATTRIBUTE)


def observation_material() -> bpy.types.Material:
    """The shared material showing the confidence layer's colours (reused while its tag is on it)."""
    return _colour_attribute_material(OBSERVATION_MATERIAL_TAG, OBSERVATION_MATERIAL_NAME, OBSERVATION_ATTRIBUTE)


def _colour_attribute_material(tag: str, name: str, attribute: str) -> bpy.types.Material:
    for material in bpy.data.materials:
        if material.get(tag):
            return material
    material = bpy.data.materials.new(name)
    material[tag] = True
    material.use_nodes = True  # a no-op from 5.0 (always nodes), needed in 4.x
    tree = material.node_tree
    principled = next(node for node in tree.nodes if node.type == "BSDF_PRINCIPLED")
    principled.inputs["Roughness"].default_value = 0.9  # walls and furniture are matte; no fake gloss
    colour = tree.nodes.new("ShaderNodeVertexColor")
    colour.layer_name = attribute
    colour.location = (principled.location.x - 300, principled.location.y)
    tree.links.new(colour.outputs["Color"], principled.inputs["Base Color"])
    return material


def texture_material(image: bpy.types.Image, observation: bool) -> bpy.types.Material:
    """A new material for one baked result: the photo texture `image` as base colour (an Image
    Texture node the glTF and OBJ exporters turn into the file's texture), matte (roughness 1,
    metallic 0: the photos already hold the room's lighting). With `observation`, a Color Attribute
    node reading the confidence layer too, which Show Observation links in instead of the image."""
    material = bpy.data.materials.new(TEXTURE_MATERIAL_NAME)
    try:
        material[TEXTURE_MATERIAL_TAG] = True
        material.use_nodes = True  # a no-op from 5.0 (always nodes), needed in 4.x
        tree = material.node_tree
        principled = next(node for node in tree.nodes if node.type == "BSDF_PRINCIPLED")
        principled.inputs["Roughness"].default_value = 1.0
        principled.inputs["Metallic"].default_value = 0.0
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.name = texture.label = TEXTURE_NODE
        texture.image = image
        texture.interpolation = "Linear"
        texture.extension = "EXTEND"  # the atlas is padded; wrapping would bleed the opposite edge in
        texture.location = (principled.location.x - 400, principled.location.y)
        tree.nodes.active = texture  # solid mode's Texture colour shows the active image node
        if observation:
            colour = tree.nodes.new("ShaderNodeVertexColor")
            colour.name = colour.label = TEXTURE_OBSERVATION_NODE
            colour.layer_name = OBSERVATION_ATTRIBUTE
            colour.location = (principled.location.x - 400, principled.location.y - 320)
        tree.links.new(texture.outputs["Color"], principled.inputs["Base Color"])
    except Exception:
        bpy.data.materials.remove(material)
        raise
    return material


def show_texture_base_colour(material: bpy.types.Material, observation: bool) -> None:
    """Link the texture material's base colour to the observation colours (True) or the photo texture."""
    tree = material.node_tree
    source = tree.nodes.get(TEXTURE_OBSERVATION_NODE if observation else TEXTURE_NODE)
    principled = next((node for node in tree.nodes if node.type == "BSDF_PRINCIPLED"), None)
    if source is not None and principled is not None:
        tree.links.new(source.outputs["Color"], principled.inputs["Base Color"])


def texture_image_of(material: Optional[bpy.types.Material]) -> Optional[bpy.types.Image]:
    """The photo texture of a baked result's material, or None for any other material."""
    if material is None or not material.get(TEXTURE_MATERIAL_TAG) or material.node_tree is None:
        return None
    node = material.node_tree.nodes.get(TEXTURE_NODE)
    return node.image if node is not None else None


def is_textured(obj: bpy.types.Object) -> bool:
    """Whether `obj` is a result with a baked photo texture (a UV map and the texture material)."""
    mesh = obj.data
    return (isinstance(mesh, bpy.types.Mesh) and len(mesh.uv_layers) > 0
            and any(texture_image_of(material) is not None for material in mesh.materials))


def show_vertex_colours(screen: Optional[bpy.types.Screen]) -> None:
    """Solid-mode 3D Views of `screen` show attribute colours (so the result looks like the room)."""
    _solid_colour(screen, "VERTEX")


def show_texture_colours(screen: Optional[bpy.types.Screen]) -> None:
    """Solid-mode 3D Views of `screen` show the materials' images (a baked result's photo texture)."""
    _solid_colour(screen, "TEXTURE")


def _solid_colour(screen: Optional[bpy.types.Screen], color_type: str) -> None:
    if screen is None:
        return
    for area in screen.areas:
        if area.type != "VIEW_3D":
            continue
        for space in area.spaces:
            if space.type == "VIEW_3D":
                space.shading.color_type = color_type


# --- collection and objects -----------------------------------------------------------------------------


def find_result_collection(scene: bpy.types.Scene) -> Optional[bpy.types.Collection]:
    return find_tagged_collection(scene, COLLECTION_TAG)


def ensure_result_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    return ensure_tagged_collection(scene, COLLECTION_TAG, RESULT_COLLECTION_NAME)


def result_objects(scene: bpy.types.Scene) -> list[bpy.types.Object]:
    """The scene's VoRTX result meshes, oldest first (by name, as Blender numbers duplicates)."""
    return sorted((obj for obj in scene.objects if obj.get(RESULT_TAG)), key=lambda obj: obj.name)


def remove_object(obj: bpy.types.Object) -> None:
    """Delete an object and its mesh when nothing else uses the mesh."""
    data = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    if isinstance(data, bpy.types.Mesh) and data.users == 0:
        bpy.data.meshes.remove(data)


def result_name(capture_path: str) -> str:
    """The result object's name: the capture folder's (or file's parent folder's) name."""
    path = Path(capture_path.rstrip("/\\")) if capture_path else None
    if path is None or not path.name:
        return "VoRTX Result"
    # transforms.json / video.mp4 name the format, not the room: use their folder.
    name = path.parent.name if path.suffix and path.parent.name else path.stem
    return (name or "VoRTX Result")[:63]


def insert_result(
    scene: bpy.types.Scene,
    mesh: Mesh,
    provenance: Provenance,
    mode: str = "REPLACE",
    name: Optional[str] = None,
    target_faces: int = 0,
    depsgraph: Optional[bpy.types.Depsgraph] = None,
) -> bpy.types.Object:
    """Put `mesh` (engine world) into the scene's result collection as a new object, shown in the
    coordinates the scene shows (frame.py) and recording them (`vortx_frame`), decimated to about
    `target_faces` (0: not decimated; needs the scene's `depsgraph`); with mode REPLACE the previous
    results go. The old results are removed last, and a failure before that removes what was added,
    so an error leaves the scene as it was."""
    if mode not in ("REPLACE", "ADD"):
        raise ValueError(f"mode must be REPLACE or ADD, got {mode!r}")
    if target_faces > 0 and depsgraph is None:
        raise ValueError("decimating needs the scene's depsgraph")
    name = name or result_name(provenance.capture_path)
    had_material = any(m.get(MATERIAL_TAG) for m in bpy.data.materials)
    had_collection = find_result_collection(scene) is not None
    data = build_mesh(name, mesh.vertices, mesh.faces, mesh.colors, mesh.attributes)
    obj: Optional[bpy.types.Object] = None
    try:
        data.materials.append(vertex_colour_material())
        obj = bpy.data.objects.new(name, data)
        provenance.write(obj)
        collection = ensure_result_collection(scene)
        collection.objects.link(obj)
        place_new(obj, scene)
        if scene.vortx.capture_frame:  # the coordinates, as the scene records them now
            obj[PROP_OUTPUT_FRAME] = scene.vortx.capture_frame
        if target_faces > 0:
            decimate(obj, target_faces, depsgraph)
    except Exception:
        _undo_insert(obj, data, scene, had_material, had_collection)
        raise
    if mode == "REPLACE":
        for old in result_objects(scene):
            if old != obj:
                remove_object(old)
        if obj.name != name:
            obj.name = name  # the replaced object freed the name; take it back from "name.001"
            obj.data.name = name
    return obj


def _undo_insert(obj: Optional[bpy.types.Object], data: bpy.types.Mesh, scene: bpy.types.Scene, had_material: bool,
                 had_collection: bool) -> None:
    if obj is not None:
        current = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if current is not None and current != data and current.users == 0:
            bpy.data.meshes.remove(current)
    try:
        if data.users == 0:
            bpy.data.meshes.remove(data)
    except ReferenceError:
        pass  # decimate() already swapped it out and removed it
    if not had_material:
        for material in [m for m in bpy.data.materials if m.get(MATERIAL_TAG) and m.users == 0]:
            bpy.data.materials.remove(material)
    if not had_collection:
        collection = find_result_collection(scene)
        if collection is not None and not collection.all_objects:
            bpy.data.collections.remove(collection)


# --- decimation ------------------------------------------------------------------------------------------


def decimate(obj: bpy.types.Object, target_faces: int, depsgraph: bpy.types.Depsgraph) -> int:
    """Reduce `obj`'s mesh to about `target_faces` triangles with a Collapse Decimate modifier, applied.

    Blender's collapse decimation is quadric-error based and interpolates point attributes, so the
    colours survive. Applied through the evaluated mesh (`new_from_object`), which needs no operator
    context and so works headless. Returns the new face count (unchanged when already small enough).
    """
    faces = len(obj.data.polygons)
    if target_faces <= 0 or faces <= target_faces:
        return faces
    modifier = obj.modifiers.new(DECIMATE_MODIFIER, "DECIMATE")
    modifier.decimate_type = "COLLAPSE"
    modifier.use_collapse_triangulate = True  # keep a triangle mesh: exporters and mesh_arrays expect one
    modifier.ratio = target_faces / faces
    try:
        depsgraph.update()
        evaluated = obj.evaluated_get(depsgraph)
        new = bpy.data.meshes.new_from_object(evaluated, preserve_all_data_layers=True, depsgraph=depsgraph)
    finally:
        obj.modifiers.remove(modifier)
    old = obj.data
    name = old.name
    obj.data = new
    if old.users == 0:
        bpy.data.meshes.remove(old)
    new.name = name
    # new_from_object keeps the attributes (interpolated) but not which colour attribute is shown.
    show_observation(obj, getattr(obj, SHOW_OBSERVATION, False))
    return len(new.polygons)


def replace_mesh(obj: bpy.types.Object, mesh: Mesh) -> None:
    """Give `obj` new geometry from arrays, keeping its materials (used by Clean Result)."""
    old = obj.data
    name = old.name
    new = build_mesh(name, mesh.vertices, mesh.faces, mesh.colors, mesh.attributes)
    for material in old.materials:
        new.materials.append(material)
    obj.data = new
    if old.users == 0:
        bpy.data.meshes.remove(old)
    new.name = name
    show_observation(obj, getattr(obj, SHOW_OBSERVATION, False))


def shown_result(scene: bpy.types.Scene, active: Optional[bpy.types.Object]) -> Optional[bpy.types.Object]:
    """The result the Result panel's toggle acts on: the active object when it is a result, else the newest."""
    if active is not None and active.get(RESULT_TAG) and active.name in scene.objects:
        return active
    results = result_objects(scene)
    return results[-1] if results else None


# --- registration (the Object toggle) --------------------------------------------------------------------


def register() -> None:
    setattr(bpy.types.Object, SHOW_OBSERVATION, bpy.props.BoolProperty(
        name="Show Observation",
        description="Colour the result by how well the photos observed it: red = seen by few photos or only weak "
                    "matches (take more photos there), green = well observed. Changes no geometry",
        default=False,
        update=_show_observation_changed,
    ))


def unregister() -> None:
    delattr(bpy.types.Object, SHOW_OBSERVATION)
