"""VoRTX for Blender: the extension entry point.

The repository root is the extension. Blender-side code lives in `vortx_blender` (scene properties,
building Blender data, the job runner), `operators` and `ui`; the reconstruction itself is `engine`,
which never imports bpy.
"""

from . import operators, ui, vortx_blender

_modules = (vortx_blender, operators, ui)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
