"""The Blender window of the GUI workflow (runs inside Blender): its viewport and sidebar, redraws,
screenshots, the VoRTX tab, the sub-panels shown open, the add-on's jobs waited for."""

from __future__ import annotations

import importlib
import subprocess
import time
from types import ModuleType
from typing import Any, Iterator, Optional, Sequence

import blf
import bpy

from .panels import panel_classes
from .report import CheckFailed, WorkflowReport
from .x11 import PARK_MOUSE, click_command, screenshot_command, tab_strip_points

ADDON = "bl_ext.user_default.vortx"  # the extension as `blender --command extension install-file -r user_default` installs it
JOB_TIMEOUT_S = 1200


def addon(module: str) -> ModuleType:
    return importlib.import_module(f"{ADDON}.{module}")


def x_command(command: Sequence[str], timeout: float = 30) -> None:
    subprocess.run(list(command), check=True, timeout=timeout)


def view3d() -> tuple[Any, Any, Any]:
    window = bpy.context.window_manager.windows[0]
    area = next(a for a in window.screen.areas if a.type == "VIEW_3D")
    region = next(r for r in area.regions if r.type == "WINDOW")
    return window, area, region


def sidebar() -> Any:
    _, area, _ = view3d()
    return next(r for r in area.regions if r.type == "UI")


def override() -> Any:
    window, area, region = view3d()
    return bpy.context.temp_override(window=window, screen=window.screen, area=area, region=region)


def redraw() -> None:
    for area in bpy.context.window_manager.windows[0].screen.areas:
        area.tag_redraw()


def settle() -> Iterator[float]:
    """Draw the window a few times: panels slide to their new places over several redraws when their
    contents change, and with no mouse moving nothing else asks for those redraws."""
    for _ in range(4):
        redraw()
        with override():
            bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=3)
        yield 0.3


def shot(report: WorkflowReport, name: str, what: str, crop_sidebar: bool, png: Optional[bool] = None,
         width: int = 1200, quality: int = 82) -> None:  # after `yield from settle()`
    """Screenshot of the X display: the VoRTX sidebar (PNG) or the whole window (JPEG, or PNG when `png`),
    the whole window scaled to `width` px."""
    window, _, _ = view3d()
    path = report.out / (f"{name}.png" if (crop_sidebar if png is None else png) else f"{name}.jpg")
    x_command(screenshot_command(path, window.width, window.height, sidebar() if crop_sidebar else None, width, quality),
              timeout=60)
    report.add_shot(path, what)


def show_vortx_tab() -> Iterator[float]:
    """Click the sidebar's VoRTX tab, as a user does (the active tab is read-only in Python)."""
    window, _, _ = view3d()
    for x, y in tab_strip_points(window.height, sidebar()):
        if sidebar().active_panel_category == "VoRTX":
            break
        x_command(click_command(x, y))
        yield 0.4
    x_command(PARK_MOUSE)


class PanelLayout:
    """Which of the add-on's sub-panels are shown open (panels.py says how)."""

    def __init__(self) -> None:
        self.registered: list[type] = []  # the panel classes registered in their place

    def open(self, names: Sequence[str]) -> None:
        """Show the sub-panels `names` open and every other one as it was; all the add-on's panels are
        registered again, parents first, so they keep their order."""
        panels = addon("ui.panels")
        for cls in reversed(self.registered or panels.classes):
            bpy.utils.unregister_class(cls)
        self.registered = []
        for cls in panel_classes(panels.classes, set(names)):
            bpy.utils.register_class(cls)
            self.registered.append(cls)


def measure_sidebar(texts: Sequence[str]) -> dict:
    """The sidebar's size and the UI's text widths in this window (blf at the UI font's size)."""
    region = sidebar()
    style = bpy.context.preferences.ui_styles[0]
    points = getattr(getattr(style, "widget", None), "points", 11)  # the widgets' text (ThemeStyle.widget)
    blf.size(0, points * bpy.context.preferences.system.ui_scale)
    return {"width": region.width, "height": region.height, "ui_scale": bpy.context.preferences.system.ui_scale,
            "font_points": points, "text_widths": {t: blf.dimensions(0, t)[0] for t in texts}}


def wait_for_job(title: str) -> Iterator[float]:
    """Yield until the add-on's job is over (the modal operator applies the result on its last tick)."""
    jobs = addon("vortx_blender.jobs")
    started = time.time()
    yield 0.5
    while jobs.active_job() is not None:
        if time.time() - started > JOB_TIMEOUT_S:
            raise CheckFailed(f"{title} still running after {JOB_TIMEOUT_S} s")
        yield 0.5
    yield 0.5  # the modal operator's last timer tick has run; let the window draw the outcome
