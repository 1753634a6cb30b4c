"""How much text the default 3D View sidebar shows, in Blender's own text width (blf).

Blender cuts a label that does not fit with "..." in its middle ("Min Match Sc..."). The numbers below
were measured in the real window (Debian 13's Blender 4.3, UI scale 1, the sidebar at its default
291 px, docs/gui_08_sidebar_end.png as retaken for issue 29's first screenshots):

- a panel's content is 234 px wide (x 18-252; the tab strip and the margins take the other 57 px);
- with `use_property_split` a label gets 0.4 of that (93.6 px) and shows 88 px of text in it:
  "Max room size X" (88 px) showed whole, "Min Match Score" (89 px) as "Min Match Sc...";
- a label's icon puts its text 26 px further right; inside a box the text starts 5 px further in on
  both sides;
- a button's text keeps 4 px from both edges, and its icon takes 23 px more: "Clean Up Result"
  (84 px) showed whole in a 117 px button with an icon (half a row).

`text_width` measures with blf at the UI's font size, which gives exactly the widths drawn in the window
(e.g. "Source Views" 72 px in both). The panels wrap their long text with it (`wrap`), and
tests/ui/test_label_widths.py checks every label of every panel against these budgets.
"""

from __future__ import annotations

from typing import Any

SIDEBAR_PX = 291  # the sidebar region's default width
CONTENT_PX = 234  # a panel's content at that width
MARGIN_PX = SIDEBAR_PX - CONTENT_PX  # tab strip and panel margins
SPLIT_FACTOR = 0.4  # use_property_split: the label column's share (Blender's UI_ITEM_PROP_SEP_DIVIDE)
LABEL_PAD_PX = 5.6  # 0.4 * 234 - 5.6 = 88 px of label text: the measured limit
ICON_PX = 26  # a label's icon before its text
BOX_PX = 10  # a box's inner margins, both sides
BUTTON_PAD_PX = 8  # a button's text keeps 4 px from both edges
BUTTON_ICON_PX = 23  # a button's icon before its text
DROPDOWN_PX = 20  # an enum field's arrow
CHECKBOX_PX = 22  # a checkbox before its text
FONT_POINTS = 11  # the UI font size at UI scale 1 (Blender's default widget text)

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
    """`text`'s width in pixels at UI scale 1, as Blender draws it in a panel (the UI font, 11 pt)."""
    import blf

    blf.size(0, FONT_POINTS)
    return blf.dimensions(0, text)[0]


def content_px(context: Any) -> float:
    """The width of a panel's content in the sidebar `context` draws into, in pixels at UI scale 1
    (CONTENT_PX without a region: tests, scripts)."""
    region = getattr(context, "region", None)
    width = getattr(region, "width", 0) or 0
    if width <= MARGIN_PX:  # no region (headless) or collapsed
        return CONTENT_PX
    import bpy

    scale = bpy.context.preferences.system.ui_scale or 1.0  # the resolution scale times the display's DPI
    return width / scale - MARGIN_PX


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
