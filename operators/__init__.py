"""bpy operators (`vortx.*`). Thin: they read scene.vortx, call vortx_blender and the engine, report."""

import bpy

from . import capture, explain, reconstruct, texture

classes: tuple = (*capture.classes, *explain.classes, *reconstruct.classes, *texture.classes)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
