"""The GUI workflow and the demo reach into the add-on's modules by name, in a real window or a long
run this suite does not make: every name they use must exist in this checkout's add-on, so a moved
function fails here and not only in the 15-minute window run."""

from __future__ import annotations

import ast
import importlib

from conftest import REPO


def used_names(path, module_of) -> set[tuple[str, str]]:
    """(add-on module, attribute) for each `variable.attribute` whose variable `module_of` maps to a module,
    and each `addon("module").attribute`."""
    tree = ast.parse(path.read_text())
    modules: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            module = module_of(node.value)
            if module:
                modules[node.targets[0].id] = module
    used = {(modules[n.value.id], n.attr) for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id in modules}
    return used | {(module_of(n.value), n.attr) for n in ast.walk(tree) if isinstance(n, ast.Attribute) and module_of(n.value)}


def addon_call(value: ast.expr) -> str:
    """`addon("vortx_blender.jobs")` -> "vortx_blender.jobs"."""
    if isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id == "addon" and value.args:
        return value.args[0].value if isinstance(value.args[0], ast.Constant) else ""
    return ""


def addon_attribute(value: ast.expr) -> str:
    """`addon.vortx_blender.cameras` -> "vortx_blender.cameras"."""
    parts = []
    while isinstance(value, ast.Attribute):
        parts.insert(0, value.attr)
        value = value.value
    return ".".join(parts) if isinstance(value, ast.Name) and value.id == "addon" and parts else ""


def test_every_add_on_name_the_gui_workflow_and_the_demo_use_exists(blender) -> None:
    used = used_names(REPO / "devtools" / "gui_workflow" / "steps.py", addon_call)
    used |= used_names(REPO / "devtools" / "demo" / "blender_views.py", addon_attribute)
    assert ("vortx_blender.scene_objects", "find_capture_collection") in used and ("vortx_blender.cameras", "PROP_IMAGE") in used
    missing = sorted(f"{module}.{name}" for module, name in used
                     if not hasattr(importlib.import_module(f"{blender.__name__}.{module}"), name))
    assert not missing, f"the add-on has no {', '.join(missing)}: follow where it moved"
