"""Native steps in a child process: a crash or a hang there costs the step, never the process.

Native libraries (xatlas, fast-simplification, COLMAP) can segfault or abort, and that ends the
whole process: inside Blender the engine runs in a thread of Blender's own process, so the artist's
unsaved scene would go with it (xatlas crashed once in ~15-20 runs of the batch VR test). So such a
step runs as `run_in_child(...)`: a fresh interpreter (`python_executable`) runs native_child.py,
arrays go in and out as .npz files (no pickle), and the parent waits with a time limit and the job's
CancelToken. A crash (killed by a signal, or an exit without a result) or a hang raises
`NativeStepError` naming the step and what to do; a VortxError raised in the child is raised again
here with its message. pycolmap's worker (poses/process.py) uses the same interpreter and
environment.

Why not multiprocessing: its spawn start re-imports the parent's `__main__` and pickles functions by
their module name; inside Blender neither is importable by a fresh interpreter (the engine is
`bl_ext.<repo>.vortx.engine`). A script started by path, told where the engine is, works in both.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Optional

import numpy as np

from . import errors
from .errors import Cancelled, NativeStepError, VortxError
from .jobs import CancelToken

CHILD_SCRIPT = Path(__file__).with_name("native_child.py")
ENGINE_PACKAGE = __name__.rpartition(".")[0]  # "engine", or "bl_ext.<repo>.vortx.engine" inside Blender
POLL_S = 0.05  # how often the parent looks at the child, the cancel flag and the clock
LOG_LINES = 12  # of the child's output quoted in a crash message


def python_executable() -> str:
    """The Python interpreter for child processes: ours, also inside Blender.

    Blender since 2.91 sets sys.executable to its bundled Python (python/bin/python3.x), so that is
    normally the answer. Should it name Blender itself (older builds, or an embedding that does), the
    bundled interpreter is looked up under sys.prefix instead: Blender would start a second Blender.
    """
    executable = Path(sys.executable)
    if executable.name and not executable.stem.lower().startswith("blender"):
        return str(executable)
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    for candidate in (Path(sys.prefix) / "bin" / f"python{version}", Path(sys.prefix) / "bin" / "python3",
                      Path(sys.prefix) / "bin" / "python.exe", Path(sys.prefix) / "python.exe"):
        if candidate.is_file():
            return str(candidate)
    raise NativeStepError(f"no Python interpreter found to run native steps in: sys.executable is {executable} and "
                          f"{Path(sys.prefix) / 'bin'} has no python{version}; reinstall Blender or run the engine "
                          "from a Python installation")


def child_environment() -> dict[str, str]:
    """Our environment plus our sys.path as PYTHONPATH.

    Inside Blender the extension's wheels (pycolmap, xatlas, cv2) sit in a folder Blender adds to
    sys.path at start-up; a bare interpreter would not find them without this.
    """
    env = dict(os.environ)
    paths = [os.path.abspath(p or os.curdir) for p in sys.path if os.path.isdir(p or os.curdir)]  # "": the cwd
    if env.get("PYTHONPATH"):
        paths.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def describe_exit(returncode: int) -> str:
    """'was killed by SIGSEGV' for a negative return code (POSIX signal), else 'exited with status N'."""
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"was killed by {name}"
    return f"exited with status {returncode}"


def run_in_child(step: str, function: Callable[..., Mapping[str, Any]], arrays: Mapping[str, np.ndarray],
                 params: Optional[Mapping[str, Any]] = None, *, time_limit_s: float,
                 cancel: Optional[CancelToken] = None, advice: str = "", tries: int = 1) -> dict[str, np.ndarray]:
    """`function(**arrays, **params)` in a fresh child process -> the dict it returns, as arrays.

    step: what the user knows the step as ("texture atlas (xatlas)"), used in every message.
    function: a module-level function of the engine (or of any module the child can import from our
    sys.path); it takes the arrays and the JSON-able params as keyword arguments and returns a dict of
    arrays and numbers (numbers come back as 0-d arrays). advice: what the user can do when the step
    crashes or hangs, appended to the message. tries: how many fresh processes a crash may take (a
    crash that depends on the library's thread timing passes on a second try; a hang is not retried).
    Raises Cancelled (the child is killed), NativeStepError (crash, hang, no result), the VortxError
    the function raised, or RuntimeError carrying the child's traceback for any other exception.
    """
    module, qualname = _importable_name(function)
    for attempt in range(1, tries + 1):
        folder = Path(tempfile.mkdtemp(prefix="vortx-native-"))
        keep = False
        try:
            (folder / "job.json").write_text(json.dumps({
                "step": step, "module": module, "function": qualname,
                "engine_parent": str(Path(__file__).resolve().parent.parent), "params": dict(params or {})}),
                encoding="utf-8")
            np.savez(folder / "in.npz", **{key: np.asarray(value) for key, value in arrays.items()})
            returncode = _wait(step, folder, time_limit_s, cancel, advice)
            if (folder / "out.npz").is_file() and returncode == 0:
                with np.load(folder / "out.npz", allow_pickle=False) as npz:
                    return {key: npz[key] for key in npz.files}
            if (folder / "error.json").is_file():
                _raise_child_error(step, json.loads((folder / "error.json").read_text(encoding="utf-8")))
            if attempt < tries:
                continue
            keep = True  # the input that crashed it and the log, for a bug report
            each = f" on each of {tries} tries" if tries > 1 else ""
            raise NativeStepError(
                f"{step} crashed{each}: its worker process {describe_exit(returncode)}. Nothing was changed."
                f"{_sentence(advice)} Its input and log are kept in {folder} for a bug report.{_log_tail(folder)}")
        finally:
            if not keep:
                shutil.rmtree(folder, ignore_errors=True)
    raise ValueError(f"run_in_child needs tries >= 1, got {tries}")


def _wait(step: str, folder: Path, time_limit_s: float, cancel: Optional[CancelToken], advice: str) -> int:
    """Run the child to its end; kill it on cancel, on our own failure, or past the time limit."""
    with open(folder / "log.txt", "w", encoding="utf-8") as log:
        process = subprocess.Popen([python_executable(), "-u", str(CHILD_SCRIPT), str(folder)], stdout=log,
                                   stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=child_environment())
        try:
            deadline = time.monotonic() + time_limit_s
            while True:
                try:
                    return process.wait(timeout=POLL_S)
                except subprocess.TimeoutExpired:
                    pass
                if cancel is not None and cancel.cancelled:
                    raise Cancelled()
                if time.monotonic() > deadline:
                    raise NativeStepError(f"{step} did not finish within {time_limit_s:.0f} s and was stopped. "
                                          f"Nothing was changed.{_sentence(advice)}")
        except BaseException:
            # Cancel, the time limit, KeyboardInterrupt or a bug here: never leave the child running.
            process.kill()
            process.wait()
            raise


def _importable_name(function: Callable[..., Any]) -> tuple[str, str]:
    """(module, qualified name) as the child imports them: the engine as `engine`, others as they are."""
    module, qualname = function.__module__, function.__qualname__
    if "<locals>" in qualname or "<lambda>" in qualname or module == "__main__":
        raise TypeError(f"run_in_child needs a module-level function, got {module}.{qualname}")
    if module == ENGINE_PACKAGE or module.startswith(ENGINE_PACKAGE + "."):
        module = "engine" + module[len(ENGINE_PACKAGE):]
    return module, qualname


def _raise_child_error(step: str, error: dict[str, Any]) -> None:
    if error.get("user_error"):
        cls = getattr(errors, str(error.get("class")), None)
        if not (isinstance(cls, type) and issubclass(cls, VortxError)):
            cls = VortxError
        raise cls(error.get("message", ""))
    raise RuntimeError(f"{step} failed in its worker process: {error.get('class')}: {error.get('message')}\n"
                       f"{error.get('traceback', '')}")


def _sentence(advice: str) -> str:
    return f" {advice}" if advice else ""


def _log_tail(folder: Path) -> str:
    try:
        lines = (folder / "log.txt").read_text(encoding="utf-8", errors="replace").strip().splitlines()
    except OSError:
        return ""
    return ("\nLast lines of its log:\n" + "\n".join(lines[-LOG_LINES:])) if lines else ""
