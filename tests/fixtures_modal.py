"""Stand-ins for the window manager and workspace a modal operator talks to: headless Blender has no
window, so the interactive path (timers, status text, progress) is driven by hand in the tests."""

from __future__ import annotations

import time
from types import SimpleNamespace


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


def modal_operator(blender, operator_name: str, methods: tuple[str, ...]):
    """The JobOperatorMixin with the named operator's own `methods` (taken as defined, staticmethods
    included), held as Blender holds a modal operator: invoked, modal, reports kept in `.reports`."""
    import bpy

    operator = getattr(bpy.types, operator_name)

    def __init__(self) -> None:
        self.reports = []

    def report(self, kind, message) -> None:
        self.reports.append((set(kind), message))

    members = {name: operator.__dict__[name] for name in methods}
    members.update(options=SimpleNamespace(is_invoke=True), __init__=__init__, report=report,
                   _is_modal=lambda self, context: True)
    return type("Modal", (blender.vortx_blender.job_operator.JobOperatorMixin,), members)()


def tick_until_done(op, context, limit_s: float) -> set:
    """Timer events to a modal operator until it stops running; -> its last return value."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        result = op.modal(context, SimpleNamespace(type="TIMER", value="NOTHING"))
        if result != {"RUNNING_MODAL"}:
            return result
        time.sleep(0.01)
    raise AssertionError(f"the modal {op.job_title} never finished")
