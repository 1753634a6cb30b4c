"""Showing the add-on's sub-panels open, as a user clicks their headers. Python can neither open a
drawn panel nor reset it (one registered again keeps its state), so each panel to show open is
registered again under a new idname ("..._open", its children moved under it) without
DEFAULT_CLOSED: a new panel, open; registered under its own idname again it is the closed one it was."""

from __future__ import annotations

from typing import Collection, Sequence


def panel_classes(classes: Sequence[type], opened: Collection[str]) -> list[type]:
    """The classes to register, in the add-on's order (parents first), for the panels `opened` (class
    names) shown open and every other one as it was."""
    result = []
    for cls in classes:
        attributes: dict = {}
        if cls.__name__ in opened:
            attributes = {"bl_idname": f"{cls.bl_idname}_open",
                          "bl_options": set(getattr(cls, "bl_options", set())) - {"DEFAULT_CLOSED"}}
        parent = getattr(cls, "bl_parent_id", "")
        if parent in opened:
            attributes["bl_parent_id"] = f"{parent}_open"
        if attributes:
            attributes.setdefault("bl_idname", f"{cls.bl_idname}_moved")
            cls = type(attributes["bl_idname"], (cls,), attributes)
        result.append(cls)
    return result
