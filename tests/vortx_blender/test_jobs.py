"""The job runner (worker thread + progress queue + cancel) and the dual-path job operator, headless."""

from __future__ import annotations

import threading
import time

import pytest

from conftest import scene_state


@pytest.fixture
def jobs(blender):
    module = blender.vortx_blender.jobs
    yield module
    # A failing test must not leave a job that blocks the next one.
    module.cancel_active(timeout=5.0)


def test_result_and_progress_in_order(jobs) -> None:
    def work(progress, cancel):
        for i in range(5):
            progress("counting", i + 1, 5)
        progress("summing", 1, 1)
        return 42

    seen = []
    job = jobs.Job("test", work).start()
    assert job.wait(on_progress=seen.append) == 42
    assert [(p.stage, p.done, p.total) for p in seen] == [("counting", i, 5) for i in range(1, 6)] + [("summing", 1, 1)]
    assert job.progress.fraction == 1.0
    assert not jobs.is_busy()


def test_worker_error_is_raised_on_main_thread(blender, jobs) -> None:
    errors = blender.engine.errors

    def work(progress, cancel):
        raise errors.PoseError("only 1 of 12 photos registered")

    job = jobs.Job("test", work).start()
    with pytest.raises(errors.PoseError, match="only 1 of 12"):
        job.wait()
    assert job.finished and not jobs.is_busy()


def test_poll_does_not_block_and_one_job_at_a_time(jobs) -> None:
    release = threading.Event()

    def work(progress, cancel):
        progress("waiting", 0, 1)
        release.wait(10)
        return "done"

    job = jobs.Job("first", work).start()
    assert jobs.is_busy() and jobs.active_job() is job
    started = time.monotonic()
    assert job.poll() is False
    assert time.monotonic() - started < 0.5
    with pytest.raises(jobs.JobBusy, match="first"):
        jobs.Job("second", lambda progress, cancel: None).start()
    release.set()
    job.join(5)
    assert job.poll() is True and job.result() == "done"
    assert jobs.Job("second", lambda progress, cancel: 1).start().wait() == 1


def test_cancel_stops_a_looping_engine_function(blender, jobs) -> None:
    steps = []

    def work(progress, cancel):
        for i in range(10_000):
            cancel.check()
            steps.append(i)
            progress("looping", i, 10_000)
            time.sleep(0.001)
        return "not cancelled"

    job = jobs.Job("test", work).start()

    def cancel_on_first_progress(progress) -> None:
        job.cancel()

    with pytest.raises(blender.engine.errors.Cancelled):
        job.wait(on_progress=cancel_on_first_progress)
    assert job.cancel_requested and job.finished
    assert len(steps) < 10_000
    assert not jobs.is_busy()


# --- the operator side: JobOperatorMixin through bpy.ops, blocking because bpy.app.background ---


@pytest.fixture
def job_operator(blender, jobs):
    """A registered operator whose engine function is set per test; on success it adds an empty object."""
    import bpy

    Mixin = blender.vortx_blender.job_operator.JobOperatorMixin
    state = {"function": None, "applied": 0}

    class VORTX_TEST_OT_job(Mixin, bpy.types.Operator):
        bl_idname = "vortx_test.job"
        bl_label = "Test Job"
        job_title = "Test Job"

        def make_job_function(self, context):
            return state["function"]

        def apply_result(self, context, scene, result):
            state["applied"] += 1
            scene.collection.objects.link(bpy.data.objects.new(f"result {result}", None))
            return {"FINISHED"}

    bpy.utils.register_class(VORTX_TEST_OT_job)
    yield state
    bpy.utils.unregister_class(VORTX_TEST_OT_job)


def test_operator_blocks_headless_and_applies_result(blender, empty_scene, job_operator) -> None:
    import bpy

    assert bpy.app.background
    job_operator["function"] = lambda progress, cancel: (progress("work", 1, 1), 7)[1]
    # INVOKE_DEFAULT would go modal with a UI; headless it must block like execute (timers never fire).
    assert bpy.ops.vortx_test.job("INVOKE_DEFAULT") == {"FINISHED"}
    assert "result 7" in bpy.data.objects
    assert job_operator["applied"] == 1


def test_operator_cancelled_mid_run_changes_nothing(blender, empty_scene, job_operator) -> None:
    import bpy

    jobs = blender.vortx_blender.jobs
    started = threading.Event()

    def work(progress, cancel):
        started.set()
        while True:  # an engine loop that only ends through its cancel checks
            cancel.check()
            progress("looping", 0, 0)
            time.sleep(0.005)

    def press_escape() -> None:
        # Stands in for Esc in the modal path: cancel whatever job is running, from another thread.
        started.wait(10)
        jobs.active_job().cancel()

    before = scene_state(empty_scene)
    job_operator["function"] = work
    canceller = threading.Thread(target=press_escape)
    canceller.start()
    assert bpy.ops.vortx_test.job() == {"CANCELLED"}
    canceller.join(5)
    assert job_operator["applied"] == 0
    assert scene_state(empty_scene) == before
    assert not jobs.is_busy()


def test_operator_reports_engine_error_and_changes_nothing(blender, empty_scene, job_operator) -> None:
    import bpy

    errors = blender.engine.errors

    def work(progress, cancel):
        raise errors.CaptureError("folder /nowhere has no photos")

    before = scene_state(empty_scene)
    job_operator["function"] = work
    # bpy.ops turns an ERROR report into RuntimeError carrying the message.
    with pytest.raises(RuntimeError, match="folder /nowhere has no photos"):
        bpy.ops.vortx_test.job()
    assert scene_state(empty_scene) == before and job_operator["applied"] == 0


def test_operator_reports_unexpected_exception(blender, empty_scene, job_operator, capsys) -> None:
    import bpy

    def work(progress, cancel):
        raise ZeroDivisionError("bug in the engine")

    job_operator["function"] = work
    with pytest.raises(RuntimeError, match="failed unexpectedly.*bug in the engine"):
        bpy.ops.vortx_test.job()
    assert "ZeroDivisionError" in capsys.readouterr().err  # the traceback went to the console


def test_operator_poll_refuses_while_a_job_runs(blender, empty_scene, job_operator) -> None:
    import bpy

    jobs = blender.vortx_blender.jobs
    release = threading.Event()
    job = jobs.Job("background work", lambda progress, cancel: release.wait(10)).start()
    try:
        assert not bpy.ops.vortx_test.job.poll()
        assert not bpy.ops.vortx.import_capture.poll()
    finally:
        release.set()
        job.wait()
    assert bpy.ops.vortx_test.job.poll()


# --- the interactive (modal) path, driven with stand-ins: headless Blender never delivers events ---


class _FakeWindowManager:
    def __init__(self) -> None:
        self.calls: list = []
        self.timers: set = set()

    def event_timer_add(self, interval, window=None):
        timer = object()
        self.timers.add(timer)
        self.calls.append(("timer_add", interval))
        return timer

    def event_timer_remove(self, timer) -> None:
        self.timers.remove(timer)

    def modal_handler_add(self, op) -> bool:
        self.calls.append(("modal_handler_add", op))
        return True

    def progress_begin(self, lo, hi) -> None:
        self.calls.append(("progress_begin", lo, hi))

    def progress_update(self, value) -> None:
        self.calls.append(("progress_update", value))

    def progress_end(self) -> None:
        self.calls.append(("progress_end",))


class _FakeWorkspace:
    def __init__(self) -> None:
        self.status: list = []

    def status_text_set(self, text) -> None:
        self.status.append(text)


def _modal_operator(blender, function):
    """A plain-Python instance of the mixin, as Blender would hold it while modal."""
    from types import SimpleNamespace

    Mixin = blender.vortx_blender.job_operator.JobOperatorMixin

    class FakeOperator(Mixin):
        job_title = "Modal Test"
        options = SimpleNamespace(is_invoke=True)

        def __init__(self) -> None:
            self.reports: list = []
            self.applied: list = []

        def _is_modal(self, context) -> bool:
            return True  # what a UI session decides; headless it is always False

        def report(self, kind, message) -> None:
            self.reports.append((set(kind), message))

        def make_job_function(self, context):
            return function

        def apply_result(self, context, scene, result):
            self.applied.append(result)
            return {"FINISHED"}

    return FakeOperator()


def _modal_context(scene):
    from types import SimpleNamespace

    return SimpleNamespace(scene=scene, window=object(), window_manager=_FakeWindowManager(), workspace=_FakeWorkspace(), screen=None)


def _event(kind: str, value: str = "NOTHING"):
    from types import SimpleNamespace

    return SimpleNamespace(type=kind, value=value)


def _run_timer_until_done(op, context, limit_s: float = 5.0) -> set:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        result = op.modal(context, _event("TIMER"))
        if result != {"RUNNING_MODAL"}:
            return result
        time.sleep(0.01)
    raise AssertionError("the modal operator never finished")


def test_modal_path_shows_progress_and_applies_result(blender, empty_scene, jobs) -> None:
    release = threading.Event()

    def work(progress, cancel):
        progress("matching", 1, 4)
        release.wait(5)
        progress("matching", 4, 4)
        return "posed"

    op = _modal_operator(blender, work)
    context = _modal_context(empty_scene)
    assert op.execute(context) == {"RUNNING_MODAL"}
    wm = context.window_manager
    assert ("timer_add", 0.1) in wm.calls and ("modal_handler_add", op) in wm.calls
    assert op.modal(context, _event("MOUSEMOVE")) == {"PASS_THROUGH"}  # the UI stays usable
    time.sleep(0.05)
    assert op.modal(context, _event("TIMER")) == {"RUNNING_MODAL"}
    assert context.workspace.status[-1] == "VoRTX Modal Test: matching 1/4  (Esc to cancel)"
    assert ("progress_update", 250) in wm.calls
    release.set()
    assert _run_timer_until_done(op, context) == {"FINISHED"}
    assert op.applied == ["posed"]
    assert wm.timers == set() and context.workspace.status[-1] is None and wm.calls[-1] == ("progress_end",)


def test_modal_escape_cancels_and_changes_nothing(blender, empty_scene, jobs) -> None:
    def work(progress, cancel):
        while True:
            cancel.check()
            progress("looping", 0, 0)
            time.sleep(0.005)

    op = _modal_operator(blender, work)
    context = _modal_context(empty_scene)
    before = scene_state(empty_scene)
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert op.modal(context, _event("ESC", "PRESS")) == {"RUNNING_MODAL"}  # consumed; waits for the worker
    assert context.workspace.status[-1] == "VoRTX Modal Test: cancelling..."
    assert _run_timer_until_done(op, context) == {"CANCELLED"}
    assert op.applied == []
    assert op.reports == [({"WARNING"}, "Modal Test cancelled; nothing was changed")]
    assert context.window_manager.timers == set() and context.workspace.status[-1] is None
    assert scene_state(empty_scene) == before
    assert not jobs.is_busy()
