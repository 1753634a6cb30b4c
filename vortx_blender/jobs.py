"""Run one engine function off Blender's main thread, with progress and cancel.

The engine reports `progress(stage, done, total)` and checks a `CancelToken` (engine.jobs). Here a
worker thread runs the function; progress goes through a queue that the main thread drains either
from a modal operator's timer (interactive) or in a blocking loop (`Job.wait`, used when
bpy.app.background is True because timers never fire headless). The worker must not touch bpy: the
function gets plain data in and returns plain data; Blender objects are built by the caller on the
main thread afterwards, which is also what makes a cancelled or failed job change nothing.

This module does not import bpy, so it is testable with fake engine functions.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass
from typing import Callable, Generic, Optional, TypeVar

from ..engine.errors import Cancelled
from ..engine.jobs import CancelToken, ProgressCallback

T = TypeVar("T")
JobFunction = Callable[[ProgressCallback, CancelToken], T]


@dataclass(frozen=True)
class Progress:
    stage: str = "starting"
    done: int = 0
    total: int = 0

    @property
    def fraction(self) -> float:
        """Completed part of the current stage, 0..1 (0 while the stage's size is unknown)."""
        return min(max(self.done / self.total, 0.0), 1.0) if self.total > 0 else 0.0


class _Outcome:
    """Queue sentinel the worker puts last: the function's result or the exception it raised."""

    __slots__ = ("value", "error")

    def __init__(self, value: object = None, error: Optional[BaseException] = None) -> None:
        self.value = value
        self.error = error


class JobBusy(RuntimeError):
    """Another VoRTX job is still running (one at a time, see `_active`)."""


# The job currently running, if any. Blender runs one VoRTX job at a time: two SfM or reconstruction
# runs would fight over the two CPU cores / the GPU and over the same scene collection.
_active: Optional["Job"] = None
_active_lock = threading.Lock()


def active_job() -> Optional["Job"]:
    """The running job, if any (for progress display)."""
    job = _active
    return job if job is not None and job.running else None


def is_busy() -> bool:
    return active_job() is not None


class Job(Generic[T]):
    """One run of `function(progress, cancel)` in a daemon worker thread."""

    def __init__(self, title: str, function: JobFunction, detail: Optional[Callable[[], str]] = None) -> None:
        """detail: called on the main thread for extra status text (e.g. tile counts); bpy-free."""
        self.title = title
        self._function = function
        self._detail = detail
        self._queue: "queue.Queue[object]" = queue.Queue()
        self._cancel = CancelToken()
        self._thread: Optional[threading.Thread] = None
        self._outcome: Optional[_Outcome] = None
        self.progress = Progress()

    # --- lifecycle ------------------------------------------------------------------------
    def start(self) -> "Job[T]":
        global _active
        with _active_lock:
            # A job whose thread has ended but whose owner never collected it (its modal operator was
            # killed by loading another file) no longer blocks new work.
            if _active is not None and _active.running:
                raise JobBusy(f"'{_active.title}' is still running; wait for it or press Esc to cancel it")
            _active = self
        self._thread = threading.Thread(target=self._run, name=f"vortx: {self.title}", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        def progress(stage: str, done: int, total: int) -> None:
            self._queue.put(Progress(stage, int(done), int(total)))

        try:
            self._queue.put(_Outcome(value=self._function(progress, self._cancel)))
        except BaseException as error:  # handed to the main thread, which decides how to report it
            self._queue.put(_Outcome(error=error))

    def cancel(self) -> None:
        """Ask the function to stop at its next `cancel.check()`; it then finishes with Cancelled."""
        self._cancel.cancel()

    @property
    def cancel_requested(self) -> bool:
        return self._cancel.cancelled

    @property
    def running(self) -> bool:
        """True from start() until the worker thread has returned (whether or not it was collected)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def finished(self) -> bool:
        return self._outcome is not None

    # --- draining (main thread only) ------------------------------------------------------
    def _take(self, item: object) -> None:
        global _active
        if isinstance(item, Progress):
            self.progress = item
            return
        assert isinstance(item, _Outcome)
        self._outcome = item
        with _active_lock:
            if _active is self:
                _active = None

    def poll(self) -> bool:
        """Apply queued progress without blocking; True once the function has returned or raised."""
        while not self.finished:
            try:
                self._take(self._queue.get_nowait())
            except queue.Empty:
                break
        return self.finished

    def wait(self, on_progress: Optional[Callable[[Progress], None]] = None, poll_interval: float = 0.05) -> T:
        """Block until the function ends, passing each progress update to `on_progress`; return `result()`."""
        if self._thread is None:
            raise RuntimeError("Job.wait() before Job.start()")
        while not self.finished:
            try:
                item = self._queue.get(timeout=poll_interval)
            except queue.Empty:
                continue
            self._take(item)
            if isinstance(item, Progress) and on_progress is not None:
                on_progress(item)
        return self.result()

    def result(self) -> T:
        """The function's return value; re-raises its exception (Cancelled when it was cancelled)."""
        if self._outcome is None:
            raise RuntimeError("the job has not finished yet")
        if self._outcome.error is not None:
            raise self._outcome.error
        return self._outcome.value  # type: ignore[return-value]

    def join(self, timeout: Optional[float] = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def status_text(self) -> str:
        if self.cancel_requested and not self.finished:
            return f"VoRTX {self.title}: cancelling..."
        p = self.progress
        steps = f" {p.done}/{p.total}" if p.total > 0 else ""
        detail = self._detail() if self._detail is not None else ""
        detail = f", {detail}" if detail else ""
        return f"VoRTX {self.title}: {p.stage}{steps}{detail}  (Esc to cancel)"

    def panel_text(self, detail: bool = True) -> str:
        """The progress bar's text in the sidebar: the stage and counts, and with `detail` the job's
        detail (tiles done); the panel and the button say which job it is, the status bar has
        `status_text` with how to cancel."""
        if self.cancel_requested and not self.finished:
            return "Cancelling..."
        p = self.progress
        steps = f" {p.done}/{p.total}" if p.total > 0 else ""
        extra = self._detail() if detail and self._detail is not None else ""
        return f"{p.stage}{steps}" + (f", {extra}" if extra else "")


def cancel_active(timeout: float = 5.0) -> None:
    """Cancel the running job and give it `timeout` s to stop (used when the add-on is disabled)."""
    job = _active
    if job is None:
        return
    job.cancel()
    job.join(timeout)
    job.poll()


__all__ = ["Cancelled", "Job", "JobBusy", "JobFunction", "Progress", "active_job", "cancel_active", "is_busy"]
