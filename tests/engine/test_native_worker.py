"""engine/native_worker.py: a native step in a child process. What it returns, and that a crash, an
abort or a hang of the step becomes an error naming the step and what to do, while this process
(Blender, inside Blender) goes on; cancel kills the step."""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import fixtures_native
from engine.errors import Cancelled, CaptureError, NativeStepError
from engine.jobs import CancelToken
from engine.native_worker import python_executable, run_in_child

STEP = "texture atlas (xatlas)"
ADVICE = "Bake with another face budget."


def kept_folder(message: str) -> Path:
    """The folder a crash message names (its input and log, kept for a bug report)."""
    match = re.search(r"kept in (\S+) for a bug report", message)
    assert match, message
    return Path(match[1])


def test_arrays_and_params_go_in_and_results_come_back():
    values, labels = np.arange(6, dtype=np.float32).reshape(2, 3), np.array([3, 1, 2], np.int64)
    out = run_in_child(STEP, fixtures_native.scaled, {"values": values, "labels": labels}, {"factor": 2.5},
                       time_limit_s=60)
    np.testing.assert_array_equal(out["values"], values * 2.5)
    assert out["values"].dtype == np.float32 and out["labels"].tolist() == [2, 1, 3] and int(out["count"]) == 2
    assert int(out["pid"]) != __import__("os").getpid()  # it ran in another process


@pytest.mark.parametrize("crash, signal_name", [(fixtures_native.segfault, "SIGSEGV"), (fixtures_native.abort, "SIGABRT")])
def test_a_crash_is_an_error_naming_the_step_the_signal_and_what_to_do(crash, signal_name):
    with pytest.raises(NativeStepError) as caught:
        run_in_child(STEP, crash, {"faces": np.zeros((4, 3), np.int64)}, time_limit_s=60, advice=ADVICE)
    message = str(caught.value)
    assert message.startswith(f"{STEP} crashed: its worker process was killed by {signal_name}. Nothing was changed.")
    assert ADVICE in message
    folder = kept_folder(message)
    try:
        with np.load(folder / "in.npz") as npz:  # the input that crashed it, for the bug report
            assert npz["faces"].shape == (4, 3)
        if signal_name == "SIGSEGV":  # faulthandler's report: where the child was
            assert "Segmentation fault" in message and "segfault" in message
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_a_crash_gets_a_fresh_process_when_tries_allow(tmp_path):
    marker = str(tmp_path / "crashed")
    assert int(run_in_child(STEP, fixtures_native.segfault_once, {}, {"marker": marker}, time_limit_s=60, tries=2)["ok"]) == 1
    with pytest.raises(NativeStepError, match=re.escape(f"{STEP} crashed on each of 2 tries: its worker process was "
                                                        "killed by SIGSEGV")) as caught:
        run_in_child(STEP, fixtures_native.segfault, {}, time_limit_s=60, tries=2)
    shutil.rmtree(kept_folder(str(caught.value)))


@pytest.fixture
def children(monkeypatch) -> list:
    """The child processes run_in_child starts (to check they were stopped)."""
    import engine.native_worker as native_worker

    started = []

    class Recorded(subprocess.Popen):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(self)

    monkeypatch.setattr(native_worker.subprocess, "Popen", Recorded)
    return started


def test_a_hang_hits_the_time_limit_and_the_child_is_stopped(tmp_path, children):
    with pytest.raises(NativeStepError, match=re.escape(f"{STEP} did not finish within 2 s and was stopped. "
                                                        f"Nothing was changed. {ADVICE}")):
        run_in_child(STEP, fixtures_native.hang, {}, {"pid_file": str(tmp_path / "pid")}, time_limit_s=2, advice=ADVICE)
    (child,) = children
    assert child.returncode == -signal.SIGKILL  # killed and reaped, not left running


def test_cancel_stops_the_child(tmp_path, children):
    pid_file, token = tmp_path / "pid", CancelToken()

    def cancel_once_hanging():  # Esc while the step runs
        while not pid_file.is_file():
            if children and children[0].poll() is not None:
                break  # ended on its own: run_in_child says so
            time.sleep(0.05)
        token.cancel()

    canceller = threading.Thread(target=cancel_once_hanging)
    canceller.start()
    with pytest.raises(Cancelled):
        run_in_child(STEP, fixtures_native.hang, {}, {"pid_file": str(pid_file)}, time_limit_s=600, cancel=token)
    canceller.join()
    (child,) = children
    assert child.returncode == -signal.SIGKILL and fixtures_native.process_is_gone(int(pid_file.read_text()))


def test_the_steps_own_errors_come_back_as_they_were_raised():
    with pytest.raises(CaptureError, match="photo 7.jpg is not an image: replace it"):
        run_in_child(STEP, fixtures_native.refuses, {}, time_limit_s=60)
    with pytest.raises(RuntimeError, match=r"(?s)texture atlas \(xatlas\) failed in its worker process: IndexError.*has_a_bug"):
        run_in_child(STEP, fixtures_native.has_a_bug, {}, time_limit_s=60)


def test_functions_the_child_cannot_import_are_refused():
    def local(**_):
        return {}

    with pytest.raises(TypeError, match="module-level function"):
        run_in_child(STEP, local, {}, time_limit_s=60)


def test_the_interpreter_is_python_also_when_sys_executable_is_blender(tmp_path, monkeypatch):
    """Inside Blender: its bundled Python under sys.prefix, never Blender itself (a second Blender)."""
    assert python_executable() == sys.executable  # a plain Python (and Blender 2.91+) names itself
    bundled = tmp_path / "python" / "bin" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    bundled.parent.mkdir(parents=True)
    bundled.write_text("")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "blender"))
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "python"))
    assert python_executable() == str(bundled)
    bundled.unlink()
    with pytest.raises(NativeStepError, match="no Python interpreter found"):
        python_executable()
