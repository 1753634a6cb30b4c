"""Stand-ins for the window manager and workspace a modal operator talks to: headless Blender has no
window, so the interactive path (timers, status text, progress) is driven by hand in the tests."""

from __future__ import annotations


class WindowManager:
    def __init__(self) -> None:
        self.timers: set = set()

    def event_timer_add(self, interval, window=None):
        timer = object()
        self.timers.add(timer)
        return timer

    def event_timer_remove(self, timer) -> None:
        self.timers.remove(timer)

    def modal_handler_add(self, op) -> bool:
        return True

    def progress_begin(self, lo, hi) -> None:
        pass

    def progress_update(self, value) -> None:
        pass

    def progress_end(self) -> None:
        pass


class Workspace:
    """Records every status-bar text it is given."""

    def __init__(self) -> None:
        self.status: list = []

    def status_text_set(self, text) -> None:
        self.status.append(text)
