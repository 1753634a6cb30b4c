"""The X commands of the GUI workflow: ImageMagick's screenshots and xdotool's clicks, keys and
scrolls. Blender measures regions from the window's bottom left, X from the top left."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional, Protocol


class Region(Protocol):
    """A Blender region's rectangle in window pixels (bpy.types.Region has these)."""

    x: int
    y: int
    width: int
    height: int


def top_in_x(window_height: int, region: Region) -> int:
    """The region's top edge in X coordinates."""
    return window_height - (region.y + region.height)


def screenshot_command(path: Path, window_width: int, window_height: int, sidebar: Optional[Region] = None,
                       width: int = 1200, quality: int = 82) -> list[str]:
    """`import` of the X display: cropped to `sidebar` (a PNG), or the whole window scaled to `width` px
    wide (the format `path`'s suffix says, a JPEG at `quality`)."""
    command = ["import", "-window", "root"]
    if sidebar is not None:
        command += ["-crop", f"{sidebar.width}x{sidebar.height}+{sidebar.x}+{top_in_x(window_height, sidebar)}", "+repage"]
    else:
        command += ["-crop", f"{window_width}x{window_height}+0+0", "+repage", "-resize", f"{width}x", "-quality", str(quality)]
    return command + [str(path)]


def tab_strip_points(window_height: int, sidebar: Region) -> Iterator[tuple[int, int]]:
    """Where to click down the sidebar's tab strip (its right edge), top to bottom: Python cannot read
    the tabs' positions, so the workflow clicks until the VoRTX tab is active."""
    top = top_in_x(window_height, sidebar)
    for y in range(top + 8, top + 600, 16):
        yield sidebar.x + sidebar.width - 12, y


def click_command(x: int, y: int) -> list[str]:
    return ["xdotool", "mousemove", str(x), str(y), "click", "1"]


# The mouse parked in the corner: no hover highlight in the screenshots.
PARK_MOUSE = ["xdotool", "mousemove", "5", "5"]


def escape_command(x: int, y: int) -> list[str]:
    """The Esc key over the viewport at (x, y), the mouse parked after."""
    return ["xdotool", "mousemove", str(x), str(y), "key", "Escape", "mousemove", "5", "5"]


def scroll_down_command(x: int, y: int, clicks: int = 40) -> list[str]:
    """The mouse wheel turned down `clicks` times at (x, y), as a user scrolls, the mouse parked after."""
    return ["xdotool", "mousemove", str(x), str(y), "click", "--repeat", str(clicks), "--delay", "30", "5",
            "mousemove", "5", "5"]
