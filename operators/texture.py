"""Bake Texture: the active (or newest) VoRTX result gets a photo texture, the VR preset.

Thin: vortx_blender.texture reads the scene, runs the engine and builds the Blender data.
"""

# No `from __future__ import annotations`: bpy reads the property annotations as objects.
import bpy

from ..engine.errors import VortxError
from ..vortx_blender import result as results
from ..vortx_blender import texture
from ..vortx_blender.job_operator import JobOperatorMixin
from ..vortx_blender.jobs import JobFunction


class VORTX_OT_bake_texture(JobOperatorMixin, bpy.types.Operator):
    """Bake the photos into a texture on the VoRTX result: small pieces dropped, decimated to Face Budget, modifiers applied (Esc cancels)"""

    bl_idname = "vortx.bake_texture"
    bl_label = "Bake Texture"
    bl_options = {"REGISTER", "UNDO"}
    job_title = "Bake Texture"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        if not super().poll(context):
            return False
        if results.shown_result(context.scene, context.active_object) is None:
            cls.poll_message_set("No VoRTX result to bake: Reconstruct first")
            return False
        return True

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        obj = results.shown_result(context.scene, context.active_object)
        self._request = texture.request_from_scene(context.scene, obj, context.evaluated_depsgraph_get())
        return texture.bake_texture_job(self._request)

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, outcome: texture.BakeOutcome) -> set[str]:
        request = self._request
        obj = scene.objects.get(request.object_name)
        if obj is None or obj.type != "MESH":
            raise VortxError(f"'{request.object_name}' was removed or renamed while the texture was baking; nothing was changed")
        texture.apply_bake(obj, request, outcome)
        results.show_texture_colours(context.screen)
        width, height = outcome.textured.texture_size
        seconds = outcome.stats.get("timings_s", {}).get("total", 0.0)
        self.report({"INFO"}, f"Baked a {width} x {height} texture onto '{obj.name}': {len(obj.data.polygons)} faces "
                              f"from {len(request.capture.posed_frames)} photos in {seconds:.0f} s")
        return {"FINISHED"}


classes = (VORTX_OT_bake_texture,)
