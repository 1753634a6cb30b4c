"""A status line with its whole text as the tooltip: the Capture panel's one-line warnings and scale.

Blender's labels have no tooltips, so a panel line that stands for a longer text (the scale's derivation,
why poses look off, which photos were skipped) is drawn as this operator without emboss: it reads as a
label, hovering shows `text`, clicking puts `text` in the report (the status bar and the Info editor).
"""

# No `from __future__ import annotations`: bpy reads the property annotations as objects.
import bpy
from bpy.props import EnumProperty, StringProperty


class VORTX_OT_explain(bpy.types.Operator):
    """Show the whole text of a status line"""

    bl_idname = "vortx.explain"
    bl_label = "Details"
    bl_options = {"INTERNAL"}

    text: StringProperty(name="Text", description="The whole text the line stands for", options={"SKIP_SAVE", "HIDDEN"})
    level: EnumProperty(name="Level", items=[("INFO", "Info", ""), ("WARNING", "Warning", "")], default="INFO",
                        options={"SKIP_SAVE", "HIDDEN"})

    @classmethod
    def description(cls, context: bpy.types.Context, properties: bpy.types.OperatorProperties) -> str:
        return properties.text or cls.__doc__

    def execute(self, context: bpy.types.Context) -> set[str]:
        if self.text:
            self.report({self.level}, self.text)
        return {"FINISHED"}


classes = (VORTX_OT_explain,)
