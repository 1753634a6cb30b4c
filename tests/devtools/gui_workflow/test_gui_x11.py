"""The GUI workflow's X commands (devtools/gui_workflow/x11.py): Blender's regions measure from the
window's bottom left, X from its top left."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from devtools.gui_workflow.x11 import escape_command, screenshot_command, scroll_down_command, tab_strip_points, top_in_x

SIDEBAR = SimpleNamespace(x=1300, y=40, width=300, height=900)  # a 1600 x 1000 window's sidebar


def test_the_sidebar_shot_is_cropped_where_x_sees_it_and_the_window_shot_scaled() -> None:
    assert top_in_x(1000, SIDEBAR) == 60
    assert screenshot_command(Path("s.png"), 1600, 1000, SIDEBAR) == [
        "import", "-window", "root", "-crop", "300x900+1300+60", "+repage", "s.png"]
    assert screenshot_command(Path("w.jpg"), 1600, 1000) == [
        "import", "-window", "root", "-crop", "1600x1000+0+0", "+repage", "-resize", "1200x", "-quality", "82", "w.jpg"]


def test_the_tab_strip_is_clicked_down_the_sidebars_right_edge() -> None:
    points = list(tab_strip_points(1000, SIDEBAR))
    assert points[0] == (1588, 68) and points[1] == (1588, 84) and points[-1][1] < 60 + 600
    assert {x for x, _ in points} == {1588}


def test_keys_and_scrolls_park_the_mouse_after() -> None:
    assert escape_command(400, 500) == ["xdotool", "mousemove", "400", "500", "key", "Escape", "mousemove", "5", "5"]
    scroll = scroll_down_command(1450, 490)
    assert scroll[:8] == ["xdotool", "mousemove", "1450", "490", "click", "--repeat", "40", "--delay"]
    assert scroll[-3:] == ["mousemove", "5", "5"]
