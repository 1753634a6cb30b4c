"""The extension's preferences: which engine packages are missing, and the button that installs them.

Scene settings stay on `scene.vortx` (a .blend carries its own run); what belongs to the Blender
installation rather than to a file -- the Python packages -- lives here. Drawing goes through
`draw_dependencies(layout, ...)` so tests can drive it with a recording layout (nothing draws headless).

No `from __future__ import annotations` here: bpy reads operator property annotations as objects.
"""

import sys
import textwrap
from pathlib import Path
from typing import Any, Optional, Sequence

import bpy

from . import dependencies, jobs
from .dependencies import InstallResult, ModuleStatus, Requirement
from .dependencies import canonical_name as canonical
from .job_operator import JobOperatorMixin
from .jobs import Job, JobFunction

# This module is <addon>.vortx_blender.preferences; AddonPreferences are keyed by the add-on's
# package (bl_ext.<repo>.vortx), which is also what extension_path_user expects.
ADDON_PACKAGE = __package__.rpartition(".")[0]


def install_folder() -> Path:
    """The install folder in the extension's user directory (created)."""
    return Path(bpy.utils.extension_path_user(ADDON_PACKAGE, path=dependencies.SITE_PACKAGES, create=True))


def offline_text(statuses: Sequence[ModuleStatus], folder: Path) -> str:
    """What to do when online access is off: the message with the exact manual command."""
    todo = dependencies.needed(statuses)
    return dependencies.offline_message(todo, dependencies.manual_command(_python(), folder))


def _python() -> str:
    return sys.executable


def _wrapped_labels(layout: Any, text: str, width: int = 90) -> None:
    # Labels do not wrap; long messages (paths, commands) are split over several.
    col = layout.column(align=True)
    for line in textwrap.wrap(text, width, break_long_words=True, break_on_hyphens=False):
        col.label(text=line)


def install_what(pins_apply: Optional[bool] = None) -> str:
    """What the Install button installs: the tested pins, or on another Python the nearest that fit."""
    if pins_apply if pins_apply is not None else dependencies.pins_apply_here():
        return "pinned packages"
    return f"packages (tested versions where Python {dependencies.python_text(_python_version())} has them)"


def _python_version() -> tuple:
    return tuple(sys.version_info[:2])


def draw_dependencies(layout: Any, statuses: Sequence[ModuleStatus], online: bool, job: Optional[Job], folder: Path) -> None:
    box = layout.box()
    box.label(text="Python packages for the VoRTX engine", icon="SCRIPTPLUGINS")
    col = box.column(align=True)
    for status in statuses:
        icon = "CHECKMARK" if not status.needs_install else "ERROR"
        col.label(text=status.describe(), icon=icon)
    todo = dependencies.needed(statuses)
    if job is not None and job.title == VORTX_OT_install_dependencies.job_title:
        box.progress(text=job.status_text(), factor=job.progress.fraction, type="BAR")
    elif not todo:
        box.label(text="All packages found", icon="INFO")
    elif online:
        row = box.row()
        row.operator(VORTX_OT_install_dependencies.bl_idname, icon="IMPORT")
        box.label(text=f"Installs {len(todo)} {install_what()} (and their dependencies, never numpy) into:")
        _wrapped_labels(box, str(folder))
    else:
        _wrapped_labels(box, offline_text(statuses, folder))
        box.operator(VORTX_OT_copy_install_command.bl_idname, icon="COPYDOWN")
    box.operator(VORTX_OT_check_dependencies.bl_idname, icon="FILE_REFRESH")


class VortxPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    def draw(self, context: bpy.types.Context) -> None:
        try:
            statuses = dependencies.status()
        except dependencies.DependencyError as error:
            self.layout.label(text=str(error), icon="ERROR")
            return
        draw_dependencies(self.layout, statuses, bpy.app.online_access, jobs.active_job(), install_folder())


class VORTX_OT_install_dependencies(JobOperatorMixin, bpy.types.Operator):
    """Download and install the engine's missing Python packages (pinned versions) into the extension's user folder (Esc cancels)"""

    bl_idname = "vortx.install_dependencies"
    bl_label = "Install Missing Packages"
    bl_options = {"REGISTER", "INTERNAL"}
    job_title = "Install Packages"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        if not super().poll(context):
            return False
        if not bpy.app.online_access:
            cls.poll_message_set("Online access is disabled in Preferences > System > Network")
            return False
        return True

    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        todo: list[Requirement] = dependencies.needed(dependencies.status(refresh=True))
        if not todo:
            raise dependencies.DependencyError("all required packages are already installed")
        return dependencies.install_job(_python(), install_folder(), todo)

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: InstallResult) -> set[str]:
        dependencies.add_to_sys_path(result.target)
        statuses = dependencies.status(refresh=True)
        # A module imported before the install keeps its old version until Blender restarts.
        stale = [s.requirement.distribution for s in statuses if s.requirement.module in sys.modules and s.needs_install]
        still = [s.requirement.distribution for s in statuses if s.missing]
        message = result.summary()
        left_out = {canonical(m.distribution) for m in result.not_installed}
        unexplained = [name for name in still if canonical(name) not in left_out]
        if unexplained:
            self.report({"ERROR"}, f"{message}; but {', '.join(unexplained)} still cannot be found")
            return {"CANCELLED"}
        if stale:
            message += f"; restart Blender to use the new {', '.join(stale)}"
        # Packages no release of which fits this Blender were said by name and reason in the message.
        self.report({"WARNING"} if result.not_installed else {"INFO"}, message)
        return {"FINISHED"}


class VORTX_OT_copy_install_command(bpy.types.Operator):
    """Copy the command that installs the missing packages, to run it in a terminal"""

    bl_idname = "vortx.copy_install_command"
    bl_label = "Copy Install Command"
    bl_options = {"REGISTER", "INTERNAL"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        command = dependencies.manual_command(_python(), install_folder())
        context.window_manager.clipboard = dependencies.quote_command(command)
        self.report({"INFO"}, "Install command copied to the clipboard")
        return {"FINISHED"}


class VORTX_OT_check_dependencies(bpy.types.Operator):
    """Look for the engine's Python packages again (after installing them by hand)"""

    bl_idname = "vortx.check_dependencies"
    bl_label = "Check Again"
    bl_options = {"REGISTER", "INTERNAL"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        todo = dependencies.needed(dependencies.status(refresh=True))
        self.report({"INFO"}, "All packages found" if not todo else f"Missing: {', '.join(r.distribution for r in todo)}")
        return {"FINISHED"}


classes = (VortxPreferences, VORTX_OT_install_dependencies, VORTX_OT_copy_install_command, VORTX_OT_check_dependencies)


def register() -> None:
    # Before anything can import the engine's packages (they are imported inside jobs only).
    dependencies.add_to_sys_path(install_folder())
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    # Modules already imported from the folder stay loaded; new imports no longer find it.
    dependencies.remove_from_sys_path(install_folder())
