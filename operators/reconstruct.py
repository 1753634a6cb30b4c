"""Reconstruction operators: reconstruct, preview/bake the tiles, clean up and export a result.

Thin: scene settings are read by vortx_blender.reconstruct, Blender data is built by
vortx_blender.result / tile_overlay / export.
"""

# No `from __future__ import annotations`: bpy reads the property annotations as objects.
import functools
import json
import os

import bpy
from bpy.props import StringProperty

from ..engine.errors import VortxError
from ..engine.meshops import remove_small_pieces
from ..vortx_blender import result as results
from ..vortx_blender import tile_overlay
from ..vortx_blender.export import FILE_GLOB, FORMATS, export_result
from ..vortx_blender.job_operator import JobOperatorMixin
from ..vortx_blender.jobs import JobFunction
from ..vortx_blender.poses import RefinedPoses, apply_refined_poses
from ..vortx_blender.texture import PROP_TEXTURE
from ..vortx_blender.reconstruct import (
    CleanupOptions,
    ReconOutcome,
    plan_tiles_job,
    provenance,
    reconstruct_job,
    recon_settings_from_scene,
    request_from_scene,
    scene_capture,
)


class VORTX_OT_reconstruct(JobOperatorMixin, bpy.types.Operator):
    """Reconstruct the room from the posed capture cameras with VoRTX (Esc cancels) and add the mesh to the scene"""

    bl_idname = "vortx.reconstruct"
    bl_label = "Reconstruct"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Reconstruct"
    job_detail = staticmethod(tile_overlay.status_detail)

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        request = request_from_scene(context.scene)
        self._request = request
        uid = context.scene.session_uid
        tile_overlay.begin_run(uid, context.scene.vortx.show_tiles)
        return reconstruct_job(request, on_tiles=functools.partial(tile_overlay.show, uid))

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, outcome: ReconOutcome) -> set[str]:
        request = self._request
        target = request.cleanup.target_faces
        obj = results.insert_result(
            scene, outcome.mesh, provenance(request, outcome), request.result_mode,
            target_faces=target, depsgraph=context.evaluated_depsgraph_get() if target > 0 else None,
        )
        results.show_vertex_colours(context.screen)
        if outcome.refined is not None:
            apply_refined_poses(scene, outcome.refined)
            self.report({"INFO"}, f"The given poses looked off against the photos and were refined first: "
                                  f"{RefinedPoses(outcome.refined).summary()} (Keep Given Poses skips this)")
        for warning in outcome.warnings:
            self.report({"WARNING"}, warning)
        removed = f", {outcome.pieces.removed_pieces} small pieces removed" if outcome.pieces.removed_pieces else ""
        seconds = outcome.result.stats.get("timings_s", {}).get("total", 0.0)
        self.report({"INFO"}, f"Reconstructed '{obj.name}': {len(obj.data.polygons)} faces{removed} in {seconds:.0f} s")
        return {"FINISHED"}

    def job_finished(self, context: bpy.types.Context, succeeded: bool) -> None:
        tile_overlay.end_run(succeeded)


class VORTX_OT_preview_tiles(JobOperatorMixin, bpy.types.Operator):
    """Plan the reconstruction tiles from the capture cameras and the current settings, and show them in the viewport"""

    bl_idname = "vortx.preview_tiles"
    bl_label = "Preview Tiles"
    bl_options = {"REGISTER"}  # changes no saved data, so no undo step
    job_title = "Preview Tiles"

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        scene = context.scene
        return plan_tiles_job(scene_capture(scene), recon_settings_from_scene(scene.vortx, with_weights=False))

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, tiles: list) -> set[str]:
        overlay = tile_overlay.show(scene.session_uid, tiles)
        tile_overlay.sync_draw_handler(scene.vortx.show_tiles)
        counts = overlay.counts()
        hint = "" if scene.vortx.show_tiles else " (turn on Show Tiles to see them)"
        self.report({"INFO"}, f"{len(tiles)} tiles, {len(tiles) - counts['empty']} seen by the photos{hint}")
        return {"FINISHED"}


class VORTX_OT_bake_tiles(bpy.types.Operator):
    """Add the tiles shown in the viewport as a wireframe object (not rendered, not selectable), replacing a previous one"""

    bl_idname = "vortx.bake_tiles"
    bl_label = "Bake Tiles"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        overlay = tile_overlay.current(context.scene) if context.scene is not None else None
        if overlay is None or not overlay.tiles:
            cls.poll_message_set("No tiles yet: Preview Tiles or Reconstruct first")
            return False
        return True

    def execute(self, context: bpy.types.Context) -> set[str]:
        scene = context.scene
        overlay = tile_overlay.current(scene)
        obj = tile_overlay.bake_tiles(scene, overlay, results.ensure_result_collection(scene))
        self.report({"INFO"}, f"Baked {len(overlay.tiles)} tiles into '{obj.name}'")
        return {"FINISHED"}


def _active_result(context: bpy.types.Context) -> "bpy.types.Object | None":
    obj = context.active_object
    return obj if obj is not None and obj.type == "MESH" and obj.get(results.RESULT_TAG) else None


class VORTX_OT_clean_result(bpy.types.Operator):
    """Drop small disconnected pieces from the active VoRTX result and decimate it, with the Result settings"""

    bl_idname = "vortx.clean_result"
    bl_label = "Clean Up Result"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        obj = _active_result(context)
        if obj is None:
            cls.poll_message_set("Select a VoRTX result mesh")
            return False
        if obj.get(PROP_TEXTURE):
            # Rebuilding the mesh would drop its UVs under the texture; the bake's VR preset already
            # dropped small pieces and decimated to the face budget.
            cls.poll_message_set("This result is textured: clean up before Bake Texture (its Face Budget decimates)")
            return False
        return True

    def execute(self, context: bpy.types.Context) -> set[str]:
        obj = _active_result(context)
        if obj.get(PROP_TEXTURE):
            self.report({"ERROR"}, f"'{obj.name}' is textured, and cleaning it up would drop its UVs: clean up "
                                   "before Bake Texture, whose Face Budget decimates")
            return {"CANCELLED"}
        options = CleanupOptions.from_scene(context.scene.vortx)
        before = len(obj.data.polygons)
        try:
            mesh = results.mesh_arrays(obj.data)
        except ValueError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        cleaned, pieces = remove_small_pieces(mesh, options.min_piece_faces, options.min_piece_fraction)
        if len(cleaned.faces) == 0:
            self.report({"ERROR"}, "every piece is smaller than the minimum piece size; nothing was changed")
            return {"CANCELLED"}
        if pieces.removed_faces:
            results.replace_mesh(obj, cleaned)
        after = results.decimate(obj, options.target_faces, context.evaluated_depsgraph_get())
        _record_cleanup(obj, options)
        self.report({"INFO"}, f"'{obj.name}': {before} -> {after} faces, {pieces.removed_pieces} small pieces removed")
        return {"FINISHED"}


def _record_cleanup(obj: bpy.types.Object, options: CleanupOptions) -> None:
    # The settings property says how the mesh now on the object was made, so clean-ups are appended.
    try:
        settings = json.loads(obj.get(results.PROP_SETTINGS, "{}"))
    except json.JSONDecodeError:
        settings = {}
    settings.setdefault("cleanups", []).append(
        {"min_piece_faces": options.min_piece_faces, "min_piece_fraction": options.min_piece_fraction,
         "target_faces": options.target_faces}
    )
    obj[results.PROP_SETTINGS] = json.dumps(settings, sort_keys=True)


class VORTX_OT_export_result(bpy.types.Operator):
    """Export the active mesh as GLB/glTF, PLY or OBJ (by the file name's extension), in metres with its vertex colours"""

    bl_idname = "vortx.export_result"
    bl_label = "Export Result"
    bl_options = {"REGISTER"}

    filepath: StringProperty(name="File Path", subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default=FILE_GLOB, options={"HIDDEN"})

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            cls.poll_message_set("Select a mesh (a VoRTX result) to export")
            return False
        return True

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if not self.filepath:
            folder = os.path.dirname(bpy.data.filepath) if bpy.data.filepath else os.path.expanduser("~")
            self.filepath = os.path.join(folder, bpy.path.clean_name(context.active_object.name) + ".glb")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        path = self.filepath
        if os.path.splitext(path)[1].lower() not in FORMATS:
            path += ".glb"  # the VR-ready default
        try:
            written = export_result(context.active_object, path, context.view_layer)
        except VortxError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Exported '{context.active_object.name}' to {written}")
        return {"FINISHED"}


classes = (
    VORTX_OT_reconstruct,
    VORTX_OT_preview_tiles,
    VORTX_OT_bake_tiles,
    VORTX_OT_clean_result,
    VORTX_OT_export_result,
)
