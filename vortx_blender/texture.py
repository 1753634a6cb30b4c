"""Bake Texture: a VoRTX result gets a photo texture (the VR preset of engine/texture) in place.

The same split as Reconstruct (reconstruct.py): on the main thread everything is read into a
`BakeRequest` of plain data (the result's evaluated mesh, modifiers applied, in world metres; the
posed capture rebuilt from the camera objects; the texture options from the scene) and checked
there, so "no result", "no posed cameras" or "the photos are gone" are reported before a thread
starts. The worker calls the engine (`views_from_capture`, `textured_result`: small pieces dropped,
decimated to the face budget, atlas, bake) and encodes the texture as PNG, touching no bpy data. On
the main thread `apply_bake` then builds a new mesh (UV map "UVMap", vertex colours and the
confidence layer carried over), a packed image and a material, and swaps them in only once all of
them exist; a failure while building removes what it made, so a failed or cancelled bake leaves the
scene as it was. The engine's native steps (decimation, the xatlas atlas) run in child processes
(engine/native_worker.py): a segfault or hang there fails the bake with the step named, instead of
ending Blender's process and the unsaved scene with it.

Images: the engine's texture is sRGB bytes with row 0 at the top, as PNG stores it; Blender images
start at the bottom row. Packing the engine's PNG bytes (rather than writing `image.pixels`) keeps
the bytes exact, costs no float copy of a 4096 x 4096 texture, and is the file the glTF exporter
writes as it is.
"""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import bpy
import numpy as np

from ..engine.capture import Capture
from ..engine.errors import PoseError, VortxError
from ..engine.jobs import CancelToken, ProgressCallback
from ..engine.mesh_io import Mesh
from ..engine.texture.options import TextureOptions
from ..engine.texture.presets import preset
from . import result as results
from .cameras import posed_capture_from_scene
from .jobs import JobFunction
from .reconstruct import recon_settings_from_scene
from .scene_objects import engine_matrix

if TYPE_CHECKING:
    from ..engine.texture.textured_mesh import TexturedMesh

UV_MAP = "UVMap"
PROP_TEXTURE = "vortx_texture"  # the bake's provenance on the result object (JSON)
MISSING_NAMED = 3  # the error names this many missing photos


@dataclass
class BakeRequest:
    """What the worker needs, read on the main thread. mesh: the result's evaluated triangles in
    the engine's world (metres, Z up), with its colours and confidence layer; matrix_world (4, 4)
    float64: the object's transform into that world at the time (the new mesh goes back into its local
    coordinates)."""

    object_name: str
    mesh: Mesh
    matrix_world: np.ndarray
    capture: Capture
    options: TextureOptions


@dataclass
class BakeOutcome:
    """The worker's result: the textured mesh in world metres, the texture as PNG bytes, the stats."""

    textured: "TexturedMesh"
    png: bytes
    stats: dict[str, Any]


def request_from_scene(scene: "bpy.types.Scene", obj: Optional["bpy.types.Object"],
                       depsgraph: "bpy.types.Depsgraph") -> BakeRequest:
    """Everything a bake of `obj` needs (main thread). Raises VortxError saying what to do."""
    if obj is None or obj.type != "MESH" or not obj.get(results.RESULT_TAG):
        raise VortxError("No VoRTX result to bake: Reconstruct first, or select the result mesh")
    if obj.mode != "OBJECT":
        raise VortxError(f"'{obj.name}' is in {obj.mode.replace('_', ' ').title()} Mode: switch to Object Mode to "
                         "bake (the bake replaces its mesh)")
    options = recon_settings_from_scene(scene.vortx, with_weights=False).texture_options
    recorded = recorded_voxel_size(obj)
    if recorded is not None:  # the occlusion tolerance of the voxels the result was made with
        options = replace(options, occlusion_tolerance=2 * recorded)
    # The cameras as they are (not re-prepared like Reconstruct's scene_capture, which may move them):
    # the result mesh shares their world, so the photos project onto it from exactly there.
    capture = posed_capture_from_scene(scene)
    if capture is None or not capture.posed_frames:
        raise PoseError("The scene has no posed capture cameras to bake the photos from: import the capture "
                        "(with poses) or run Estimate Poses first")
    posed = capture.posed_frames
    missing = [Path(frame.image_path) for frame in posed if not Path(frame.image_path).is_file()]
    if missing:
        names = ", ".join(path.name for path in missing[:MISSING_NAMED])
        more = f" and {len(missing) - MISSING_NAMED} more" if len(missing) > MISSING_NAMED else ""
        raise VortxError(f"Bake Texture needs the capture's photos, but {len(missing)} of {len(posed)} are "
                         f"missing: {names}{more} (in {missing[0].parent}); put them back or import the capture again")
    evaluated = obj.evaluated_get(depsgraph)
    data = evaluated.to_mesh()
    try:
        local = results.mesh_arrays(data, triangulate=True)  # modifiers applied, as the viewport shows the result
    finally:
        evaluated.to_mesh_clear()
    if len(local.faces) == 0:
        raise VortxError(f"'{obj.name}' has no faces to bake a texture onto")
    matrix = engine_matrix(obj, scene)  # the cameras' world, whichever coordinates the scene shows (scene_objects.py)
    if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
        raise VortxError(f"'{obj.name}' is scaled to nothing (its scale has a zero): reset its scale to bake")
    world = Mesh(vertices=transform(local.vertices, matrix), faces=local.faces, colors=local.colors,
                 attributes=local.attributes)
    return BakeRequest(object_name=obj.name, mesh=world, matrix_world=matrix, capture=capture, options=options)


def transform(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(N, 3) points through a (4, 4) affine matrix -> (N, 3) float32."""
    points = np.asarray(points, np.float64)
    return (points @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)


def bake_texture_job(request: BakeRequest) -> JobFunction:
    """A bpy-free job function: the VR preset and the bake on the request's mesh, the texture as PNG."""

    def run(progress: ProgressCallback, cancel: CancelToken) -> BakeOutcome:
        # defers cv2 (the texture engine reads and writes images with it): the extension registers without OpenCV
        from ..engine.texture.files import encode_png
        from ..engine.texture.views import views_from_capture
        from ..engine.texture.vr import textured_result

        views = views_from_capture(request.capture)
        # The mesh comes without normals (the world transform would turn them): the bake computes
        # them from the winding, which points to the cameras.
        textured, stats = textured_result(request.mesh, views, request.options, progress, cancel)
        cancel.check()
        return BakeOutcome(textured, encode_png(textured.texture), stats)

    return run


def texture_image(name: str, png: bytes, size: tuple[int, int]) -> "bpy.types.Image":
    """A new image packed into the .blend from PNG bytes (sRGB), so the file carries its texture.
    size: (width, height) of the PNG."""
    image = bpy.data.images.new(name, size[0], size[1], alpha=False)
    try:
        image.pack(data=png, data_len=len(png))
        image.source = "FILE"  # the packed PNG is now the image's data (pixels read from it)
        image.filepath_raw = "//" + bpy.path.clean_name(name) + ".png"  # where Unpack would write it
        image.colorspace_settings.name = "sRGB"  # photo colours; Blender linearises them for shading
        if tuple(image.size) != tuple(size):
            raise VortxError(f"the baked texture did not load back into Blender ({tuple(image.size)} instead of {size})")
    except Exception:
        bpy.data.images.remove(image)
        raise
    return image


def textured_mesh_data(name: str, textured: "TexturedMesh", matrix_world: np.ndarray) -> "bpy.types.Mesh":
    """A new Mesh datablock (unlinked) of `textured` in the local coordinates of an object at
    `matrix_world`: vertex colours, the confidence layer and the UV map "UVMap" (one UV per corner)."""
    local = transform(textured.vertices, np.linalg.inv(matrix_world))
    mesh = results.build_mesh(name, local, textured.faces, textured.colors, textured.attributes)
    try:
        faces = np.asarray(textured.faces, np.int64)
        uvs = np.asarray(textured.uvs, np.float32)
        layer = mesh.uv_layers.new(name=UV_MAP)
        # build_mesh lays the corners out face by face (loop_start = 3 * face), so corner UVs follow faces.
        layer.data.foreach_set("uv", np.ascontiguousarray(uvs[faces].reshape(-1)))
        mesh.uv_layers.active = layer
    except Exception:
        bpy.data.meshes.remove(mesh)
        raise
    return mesh


def apply_bake(obj: "bpy.types.Object", request: BakeRequest, outcome: BakeOutcome) -> None:
    """Give `obj` the baked result (main thread): new mesh, packed image, texture material, provenance.

    The object's modifiers are removed (the bake was made on their result); its previous mesh, and a
    previous bake's material and image, go when nothing else uses them. Until the swap nothing of
    the scene is changed, and whatever was made is removed when building fails.
    """
    if obj.mode != "OBJECT":  # Edit Mode keeps its own copy of the mesh: a swap would not take
        raise VortxError(f"'{obj.name}' was put in {obj.mode.replace('_', ' ').title()} Mode while the texture "
                         "was baking; nothing was changed: switch to Object Mode and bake again")
    textured = outcome.textured
    made: list[tuple[Any, Any]] = []  # (bpy.data collection, new datablock), removed again on failure
    try:
        mesh = textured_mesh_data(obj.data.name, textured, request.matrix_world)
        made.append((bpy.data.meshes, mesh))
        image = texture_image(f"{obj.name} Texture", outcome.png, textured.texture_size)
        made.append((bpy.data.images, image))
        material = results.texture_material(image, observation=results.has_observation(mesh))
        made.append((bpy.data.materials, material))
        mesh.materials.append(material)
        provenance = json.dumps(texture_provenance(request, outcome), sort_keys=True)
    except Exception:
        for collection, block in reversed(made):  # the material first: it uses the image
            collection.remove(block)
        raise
    old = obj.data
    old_materials = [m for m in old.materials if m is not None]
    name = old.name
    obj.data = mesh
    if obj.data != mesh:  # refused by Blender: leave everything as it was
        for collection, block in reversed(made):
            collection.remove(block)
        raise VortxError(f"Blender did not let the bake replace the mesh of '{obj.name}'; nothing was changed")
    obj.modifiers.clear()
    obj[PROP_TEXTURE] = provenance
    if old.users == 0:
        bpy.data.meshes.remove(old)
    mesh.name = name
    for material in old_materials:  # a previous bake of this result: its material and texture
        if material.users == 0 and material.get(results.TEXTURE_MATERIAL_TAG):
            image = results.texture_image_of(material)
            bpy.data.materials.remove(material)
            if image is not None and image.users == 0:
                bpy.data.images.remove(image)
    results.show_observation(obj, getattr(obj, results.SHOW_OBSERVATION, False))


def recorded_voxel_size(obj: "bpy.types.Object") -> Optional[float]:
    """The voxel size the result was reconstructed with (its settings property), or None."""
    try:
        value = json.loads(obj.get(results.PROP_SETTINGS, "{}")).get("voxel_size")
    except (json.JSONDecodeError, AttributeError):
        return None
    return float(value) if isinstance(value, (int, float)) and value > 0 else None


def texture_provenance(request: BakeRequest, outcome: BakeOutcome) -> dict[str, Any]:
    """How the texture was made, kept on the object as `vortx_texture` (JSON)."""
    options = request.options
    return {
        "texture_size": options.texture_size,
        "face_budget": options.face_budget,
        "headset": options.preset,
        "occlusion_tolerance": options.occlusion_tolerance,
        "photos": len(request.capture.posed_frames),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "stats": json.loads(json.dumps(outcome.stats, default=_plain)),
    }


def _plain(value: Any) -> Any:
    # numpy scalars and arrays in the engine's stats
    return value.tolist() if hasattr(value, "tolist") else str(value)


def headset_budget_text(scene: "bpy.types.Scene") -> str:
    """One line for the Result panel: what Bake Texture and Export will make under the scene's Headset
    preset (its budget applied to Texture Size and Face Budget), e.g. "Standalone Headset: 2048 px,
    100k faces, KTX2 ETC1S, Draco"."""
    try:
        options = recon_settings_from_scene(scene.vortx, with_weights=False).texture_options
    except VortxError as error:
        return str(error)
    faces = f"{options.face_budget:,} faces" if options.face_budget else "all faces"
    texture = {"png": "PNG", "ktx2-etc1s": "KTX2 ETC1S", "ktx2-uastc": "KTX2 UASTC"}[options.texture_format]
    geometry = ", Draco" if options.geometry == "draco" else ""
    return f"{preset(options.preset).label}: {options.texture_size} px, {faces}, {texture}{geometry}"


def bake_summary(obj: "bpy.types.Object") -> Optional[dict[str, Any]]:
    """The bake provenance recorded on `obj` (None when it was never baked)."""
    text = obj.get(PROP_TEXTURE)
    try:
        return json.loads(text) if text else None
    except json.JSONDecodeError:
        return None
