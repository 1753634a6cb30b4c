"""Sub-panels shown open in the GUI workflow (devtools/gui_workflow/panels.py), on stand-in classes."""

from __future__ import annotations

from devtools.gui_workflow.panels import panel_classes


class VORTX_PT_capture:
    bl_idname = "VORTX_PT_capture"


class VORTX_PT_capture_details:
    bl_idname = "VORTX_PT_capture_details"
    bl_parent_id = "VORTX_PT_capture"
    bl_options = {"DEFAULT_CLOSED"}


class VORTX_PT_scale_notes:
    bl_idname = "VORTX_PT_scale_notes"
    bl_parent_id = "VORTX_PT_capture_details"
    bl_options = {"DEFAULT_CLOSED"}


CLASSES = [VORTX_PT_capture, VORTX_PT_capture_details, VORTX_PT_scale_notes]


def test_an_opened_panel_is_a_new_open_one_and_its_children_move_under_it() -> None:
    capture, details, notes = panel_classes(CLASSES, {"VORTX_PT_capture_details"})
    assert capture is VORTX_PT_capture  # untouched panels are registered as they are
    assert details.bl_idname == "VORTX_PT_capture_details_open" and "DEFAULT_CLOSED" not in details.bl_options
    assert issubclass(details, VORTX_PT_capture_details) and details.bl_parent_id == "VORTX_PT_capture"
    assert notes.bl_idname == "VORTX_PT_scale_notes_moved" and notes.bl_parent_id == "VORTX_PT_capture_details_open"
    assert notes.bl_options == {"DEFAULT_CLOSED"}  # a child not opened stays closed


def test_none_opened_registers_the_add_ons_own_classes_again() -> None:
    assert panel_classes(CLASSES, set()) == CLASSES
