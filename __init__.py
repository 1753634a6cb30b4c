"""VoRTX for Blender: the extension entry point.

The repository root is the extension. Blender-side code lives in `vortx_blender` (scene properties,
building Blender data, the job runner), `operators` and `ui`; the reconstruction itself is `engine`,
which never imports bpy.
"""

from .engine.process_guards import keep_triton_out

# Blender renders with an LLVM of its own; Triton's clashes with it (see process_guards).
keep_triton_out()

from . import operators, ui, vortx_blender  # noqa: E402

# Order matters: operators and panels reference scene.vortx, which vortx_blender registers.
_modules = (vortx_blender, operators, ui)


def register() -> None:
    registered = []
    try:
        for module in _modules:
            module.register()
            registered.append(module)
    except Exception:
        # Undo the part that did register, so fixing the cause and enabling again does not fail
        # with "already registered".
        for module in reversed(registered):
            module.unregister()
        raise


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
