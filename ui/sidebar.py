"""How much text the default 3D View sidebar shows, in Blender's own text width (blf).

Blender cuts a label that does not fit with "..." in its middle ("Min Match Sc..."). The numbers below
were measured in the real window (Debian 13's Blender 4.3 under Xvfb, scripts/gui_workflow.py; its
report records the sidebar's size and the window's own text widths). That window runs at UI scale
1.0417 (the screen's DPI), so widths here are that window's pixels and `text_width` measures at its
font size, 11 pt x 1.0417: the bpy module's blf then gives exactly the widths the window reported
("Max room size X" 89 px, "Min Match Score" 92, "Source Views" 75, "Clean Up Result" 87).

- the sidebar region is 291 px wide by default, a panel's content 234 px (x 18-252; the tab strip and
  the margins take the other 57 px);
- with `use_property_split` a label gets 0.4 of that (93.6 px): "Max room size X" (89 px) and "Min
  Piece Faces" (90 px) showed whole, "Min Match Score" (92 px) as "Min Match Sc...": 3 px are margin;
- a label's icon puts its text 26 px further right; inside a box the text starts 5 px further in on
  both sides;
- a button's text keeps 4 px from both edges, and its icon takes 22 px more: "Clean Up Result"
  (87 px) showed whole in a 117 px button with an icon (half a row).

The panels wrap their long text with `text_width` (`wrap`), and tests/ui/test_label_widths.py checks
every label of every panel against these budgets.
"""

from __future__ import annotations

from typing import Any

import blf
import bpy

SIDEBAR_PX = 291  # the sidebar region's default width
CONTENT_PX = 234  # a panel's content at that width
MARGIN_PX = SIDEBAR_PX - CONTENT_PX  # tab strip and panel margins
SPLIT_FACTOR = 0.4  # use_property_split: the label column's share (Blender's UI_ITEM_PROP_SEP_DIVIDE)
LABEL_PAD_PX = 3  # 0.4 * 234 - 3 = 90.6 px of label text: 90 px showed whole, 92 px did not
ICON_PX = 26  # a label's icon before its text
BOX_PX = 10  # a box's inner margins, both sides
BUTTON_PAD_PX = 8  # a button's text keeps 4 px from both edges
BUTTON_ICON_PX = 22  # a button's icon before its text
DROPDOWN_PX = 20  # an enum field's arrow
CHECKBOX_PX = 22  # a checkbox before its text
FONT_POINTS = 11  # the UI font size at UI scale 1 (Blender's default widget text)
WINDOW_SCALE = 1.0416667  # the measured window's UI scale (preferences.system.ui_scale: its screen's DPI)

# Heights, measured in the same window on a 1600 x 1000 screen (docs/gui_03_posed.png): the sidebar is
# 822 px high in Blender's default Layout workspace; a panel header takes 30 px, a sub-panel's 26, a
# row (button, setting, label) 25.5, a line of an aligned column in a box 20.5 and the box 12 more.
SIDEBAR_HEIGHT_PX = 822
HEADER_PX = 30
SUB_HEADER_PX = 26
ROW_PX = 25.5
BOX_LINE_PX = 20.5
BOX_PAD_PX = 12


def text_width(text: str) -> float:
    """`text`'s width in pixels as the measured window draws it in a panel (the UI font, 11 pt at its scale)."""
    blf.size(0, FONT_POINTS * WINDOW_SCALE)
    return blf.dimensions(0, text)[0]


def content_px(context: Any) -> float:
    """The width of a panel's content in the sidebar `context` draws into, in the measured window's
    pixels (the units of `text_width`; CONTENT_PX without a region: tests, scripts)."""
    region = getattr(context, "region", None)
    width = getattr(region, "width", 0) or 0
    if width <= MARGIN_PX:  # no region (headless) or collapsed
        return CONTENT_PX
    scale = bpy.context.preferences.system.ui_scale or 1.0  # the resolution scale times the display's DPI
    return width / scale * WINDOW_SCALE - MARGIN_PX


def line_px(content: float = CONTENT_PX, icon: bool = False, boxed: bool = False) -> float:
    """Text width a full-width label has in a panel `content` px wide."""
    return content - LABEL_PAD_PX - (ICON_PX if icon else 0) - (BOX_PX if boxed else 0)


UNITS = ("%", "px", "m", "cm", "deg", "s", "min")  # kept with the number before them


def wrap(text: str, width_px: float) -> list[str]:
    """`text` in lines of at most `width_px` (Blender's text width), broken between words (a word wider
    than a line, such as a long path, is broken inside)."""
    words: list[str] = []
    for word in text.split():
        if words and word in UNITS:  # "+-12 %" stays on one line
            words[-1] = f"{words[-1]} {word}"
        else:
            words.append(word)
    lines: list[str] = []
    for word in words:
        if lines and text_width(f"{lines[-1]} {word}") <= width_px:
            lines[-1] = f"{lines[-1]} {word}"
            continue
        while len(word) > 1 and text_width(word) > width_px:
            cut = max((n for n in range(1, len(word)) if text_width(word[:n]) <= width_px), default=1)
            lines.append(word[:cut])
            word = word[cut:]
        lines.append(word)
    return lines or [""]


def shorten(text: str, width_px: float) -> str:
    """`text`, cut with "..." when wider than `width_px` (names: the tooltip or the details have it whole)."""
    if text_width(text) <= width_px:
        return text
    for cut in range(len(text) - 1, 0, -1):
        candidate = text[:cut].rstrip() + "..."
        if text_width(candidate) <= width_px:
            return candidate
    return "..."
