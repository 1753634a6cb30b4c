"""register()/unregister() survive repeated disable/enable (Blender raises on double (un)registration)."""

from __future__ import annotations

import sys

from conftest import EXTENSION_MODULE


def _registered(bpy) -> dict[str, bool]:
    import_menu = getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])
    return {
        "file > import entry": any(getattr(f, "__module__", "").startswith(EXTENSION_MODULE) for f in import_menu),
        "scene.vortx": hasattr(bpy.types.Scene, "vortx"),
        "import operator": hasattr(bpy.types, "VORTX_OT_import_capture"),
        "estimate operator": hasattr(bpy.types, "VORTX_OT_estimate_poses"),
        "capture panel": hasattr(bpy.types, "VORTX_PT_capture"),
        "reconstruction panel": hasattr(bpy.types, "VORTX_PT_reconstruction"),
    }


def test_disable_enable_cycles(blender, empty_scene) -> None:
    import addon_utils
    import bpy

    assert all(_registered(bpy).values()), _registered(bpy)
    for _ in range(3):
        addon_utils.disable(EXTENSION_MODULE, default_set=True)
        assert not any(_registered(bpy).values()), _registered(bpy)
        assert EXTENSION_MODULE not in bpy.context.preferences.addons
        addon_utils.enable(EXTENSION_MODULE, default_set=True)
        assert EXTENSION_MODULE in sys.modules
        assert all(_registered(bpy).values()), _registered(bpy)
    # The settings work again after the cycles (the PointerProperty was re-created, not left dangling).
    bpy.context.scene.vortx.view_count = 33
    assert bpy.context.scene.vortx.view_count == 33


def test_load_handler_registered_once(blender) -> None:
    import addon_utils
    import bpy

    def ours() -> list:
        return [h for h in bpy.app.handlers.load_pre if getattr(h, "__module__", "").startswith(EXTENSION_MODULE)]

    assert len(ours()) == 1
    addon_utils.disable(EXTENSION_MODULE, default_set=True)
    assert ours() == []
    addon_utils.enable(EXTENSION_MODULE, default_set=True)
    assert len(ours()) == 1
