"""Panels and menus (no logic): the "VoRTX" sidebar tab in the 3D View."""

import bpy

from . import panels

classes: tuple = (*panels.classes,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
