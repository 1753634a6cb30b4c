"""The dual-path operator pattern for long engine jobs (blender-notes.md section 3).

`execute` starts the job, then
- goes modal when the operator was invoked from the UI (`options.is_invoke`, also true for the
  execute that follows a file browser) and Blender is not in background mode: a 0.1 s window timer
  drains progress into the status bar, the window-manager progress cursor and the sidebar (via
  `jobs.active_job()`); Esc cancels. This is the rule Blender's own extension manager uses
  (`_is_modal` in bl_pkg/bl_extension_ops.py);
- otherwise blocks until the job ends: scripts, and `bpy.app.background`, where timers and modal
  handlers never fire.

Either way the result is applied on the main thread only after the engine function returned, so a
cancelled or failed job leaves the scene as it was. Subclasses implement `make_job_function` (read
settings on the main thread, return a bpy-free function) and `apply_result` (build Blender data).
"""

from __future__ import annotations

import traceback
from typing import Any, Callable, ClassVar, Optional

import bpy

from ..engine.errors import Cancelled, VortxError
from . import jobs
from .jobs import Job, JobFunction, Progress

TIMER_INTERVAL_S = 0.1


class JobOperatorMixin:
    """Mix into a bpy.types.Operator before it: `class X(JobOperatorMixin, bpy.types.Operator)`."""

    job_title: ClassVar[str] = "job"
    # Extra status-bar text while the job runs (a plain function, not a method: the job outlives
    # the operator instance when Blender frees it).
    job_detail: ClassVar[Optional[Callable[[], str]]] = None

    # --- to implement ----------------------------------------------------------------------
    def make_job_function(self, context: bpy.types.Context) -> JobFunction:
        """Read everything the job needs from Blender now; return a function that never touches bpy."""
        raise NotImplementedError

    def apply_result(self, context: bpy.types.Context, scene: bpy.types.Scene, result: Any) -> set[str]:
        """Build Blender data from the job's result (main thread). Raise VortxError to report a failure."""
        raise NotImplementedError

    def job_finished(self, context: bpy.types.Context, succeeded: bool) -> None:
        """Called once when the run is over, whatever the outcome (also when it could not start)."""

    # --- shared machinery --------------------------------------------------------------------
    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        if jobs.is_busy():
            cls.poll_message_set("Another VoRTX job is running")
            return False
        return context.scene is not None

    def _start(self, context: bpy.types.Context) -> Optional[Job]:
        # The scene is looked up again by name when the job ends: a Python reference to it could
        # dangle if the user deleted the scene while the job was running.
        self._scene_name = context.scene.name
        try:
            function = self.make_job_function(context)
            return Job(self.job_title, function, detail=type(self).job_detail).start()
        except (VortxError, jobs.JobBusy) as error:
            self.report({"ERROR"}, str(error))
            self.job_finished(context, False)
        except BaseException:
            self.job_finished(context, False)
            raise
        return None

    def _is_modal(self, context: bpy.types.Context) -> bool:
        return not bpy.app.background and self.options.is_invoke and context.window is not None

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        return self.execute(context)

    def execute(self, context: bpy.types.Context) -> set[str]:
        job = self._start(context)
        if job is None:
            return {"CANCELLED"}
        if self._is_modal(context):
            return self._begin_modal(context, job)
        last_stage = [""]

        def log(progress: Progress) -> None:
            # Headless runs have no status bar; one console line per stage keeps logs readable.
            if progress.stage != last_stage[0]:
                last_stage[0] = progress.stage
                print(f"VoRTX {self.job_title}: {progress.stage}")

        try:
            job.wait(on_progress=log)
        except KeyboardInterrupt:
            # Ctrl+C in a blocking run interrupts this loop, not the worker: stop the worker too.
            if not job.finished:
                job.cancel()
            raise
        except Exception:
            pass  # the job's own error: _conclude reports it
        return self._conclude(context, job)

    def _begin_modal(self, context: bpy.types.Context, job: Job) -> set[str]:
        self._job = job
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_INTERVAL_S, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        self._show_progress(context, job)
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        job: Job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            # Keep polling until the worker acknowledges: it may be inside a pycolmap subprocess or
            # a torch op and stops at its next cancel check.
            job.cancel()
            self._show_progress(context, job)
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}  # the user keeps working while the job runs
        if not job.poll():
            self._show_progress(context, job)
            return {"RUNNING_MODAL"}
        self._end_modal(context)
        return self._conclude(context, job)

    def cancel(self, context: bpy.types.Context) -> None:
        # Called by Blender when it drops the modal operator (window closed, file loaded).
        job: Optional[Job] = getattr(self, "_job", None)
        if job is not None:
            job.cancel()
        self._end_modal(context)

    def _show_progress(self, context: bpy.types.Context, job: Job) -> None:
        if context.workspace is not None:
            context.workspace.status_text_set(job.status_text())
        context.window_manager.progress_update(int(job.progress.fraction * 1000))
        _redraw_sidebars(context)

    def _end_modal(self, context: bpy.types.Context) -> None:
        wm = context.window_manager
        timer = getattr(self, "_timer", None)
        if timer is not None:
            wm.event_timer_remove(timer)
            self._timer = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        _redraw_sidebars(context)

    def _conclude(self, context: bpy.types.Context, job: Job) -> set[str]:
        succeeded = False
        try:
            outcome = self._apply_outcome(context, job)
            succeeded = "FINISHED" in outcome
            return outcome
        finally:
            self.job_finished(context, succeeded)

    def _apply_outcome(self, context: bpy.types.Context, job: Job) -> set[str]:
        try:
            result = job.result()
        except Cancelled:
            self.report({"WARNING"}, f"{self.job_title} cancelled; nothing was changed")
            return {"CANCELLED"}
        except VortxError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        except Exception as error:  # a bug, not a user error: keep the traceback for the report
            traceback.print_exception(error)
            self.report({"ERROR"}, f"{self.job_title} failed unexpectedly: {error!r} (traceback in the system console)")
            return {"CANCELLED"}
        scene = bpy.data.scenes.get(self._scene_name)
        if scene is None:
            self.report({"ERROR"}, f"scene '{self._scene_name}' was removed while {self.job_title} was running")
            return {"CANCELLED"}
        try:
            return self.apply_result(context, scene, result)
        except VortxError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}


def _redraw_sidebars(context: bpy.types.Context) -> None:
    screen = context.screen
    if screen is None:
        return
    for area in screen.areas:
        if area.type == "VIEW_3D":
            area.tag_redraw()


@bpy.app.handlers.persistent
def _cancel_on_file_load(*_args: object) -> None:
    # A job's result belongs to the file that started it; loading another file abandons it.
    job = jobs.active_job()
    if job is not None:
        job.cancel()


def register() -> None:
    if _cancel_on_file_load not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_cancel_on_file_load)


def unregister() -> None:
    if _cancel_on_file_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_file_load)
    jobs.cancel_active()
