"""Panels and menus (no logic): the "VoRTX" sidebar tab in the 3D View and File > Import."""

import bpy

from . import panels

classes: tuple = (*panels.classes,)


def menu_import(self: bpy.types.Menu, context: bpy.types.Context) -> None:
    # Where users look for importers first; the sidebar tab has the same button.
    self.layout.operator("vortx.import_capture", text="VoRTX Capture (photos, video, transforms.json)")


def menu_export(self: bpy.types.Menu, context: bpy.types.Context) -> None:
    self.layout.operator("vortx.export_result", text="VoRTX Result (.glb, .ply, .obj)")


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(menu_import)
    bpy.types.TOPBAR_MT_file_export.append(menu_export)


def unregister() -> None:
    bpy.types.TOPBAR_MT_file_export.remove(menu_export)
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
    for cls in reversed(classes):
        # Quitting a windowed Blender frees the panel types before it disables the add-ons: unregistering
        # them again raised "missing bl_rna attribute" on every quit (Blender 4.3, a real window).
        if cls.is_registered:
            bpy.utils.unregister_class(cls)
