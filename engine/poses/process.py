"""Run the SfM worker process: forward its progress, honour cancel, turn its failures into PoseError.

The worker (`sfm_worker.py`) writes one merged stdout/stderr stream: our `@vortx ...` protocol
lines plus COLMAP's glog lines. COLMAP's own lines ("Processed file [3/50]", "Processing image
[7/50]", "num_reg_frames=12") give finer progress than the worker could report itself, because
each pycolmap call is one long blocking call.
"""

from __future__ import annotations

import json
import shutil
import queue
import re
import subprocess
import threading
from collections import deque
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ..errors import Cancelled, PoseError
from ..jobs import CancelToken, ProgressCallback, report
from ..native_worker import child_environment, describe_exit, python_executable

WORKER_SCRIPT = Path(__file__).with_name("sfm_worker.py")

STAGE_LABELS = {
    "prepare": "poses: downscale photos",
    "extract": "poses: SIFT features",
    "features": "poses: learned features",
    "match": "poses: matching",
    "verify": "poses: verify matches",
    "map": "poses: mapping",
    "triangulate": "poses: triangulate with the given poses",
    "adjust": "poses: bundle adjustment",
}

_EXTRACTED = re.compile(r"Processed file \[(\d+)/(\d+)\]")
_MATCHED_IMAGE = re.compile(r"Processing image \[(\d+)/(\d+)\]")
_MATCHED_BLOCK = re.compile(r"Processing block \[(\d+)/(\d+), (\d+)/(\d+)\]")
_REGISTERED = re.compile(r"num_reg_frames=(\d+)")


def worker_command(job_path: Path) -> list[str]:
    """The command line that runs the worker with our Python (Blender's bundled one inside Blender)."""
    return [python_executable(), "-u", str(WORKER_SCRIPT), str(job_path)]


class _Progress:
    """Translates stream lines into progress(stage, done, total) calls."""

    def __init__(self, progress: Optional[ProgressCallback]) -> None:
        self._progress = progress
        self._totals: dict[str, int] = {}
        self._stage: Optional[str] = None

    def _emit(self, stage: str, done: int, total: int) -> None:
        self._stage = stage
        report(self._progress, STAGE_LABELS.get(stage, stage), min(done, total), total)

    def protocol(self, words: list[str]) -> None:
        if words[0] == "stage" and len(words) == 3:
            self._totals[words[1]] = int(words[2])
            self._emit(words[1], 0, int(words[2]))
        elif words[0] == "progress" and len(words) == 4:
            self._emit(words[1], int(words[2]), int(words[3]))

    def colmap(self, line: str) -> None:
        if (m := _EXTRACTED.search(line)) is not None:
            self._emit("extract", int(m[1]), int(m[2]))
        elif (m := _MATCHED_IMAGE.search(line)) is not None:
            self._emit("match", int(m[1]) - 1, int(m[2]))
        elif (m := _MATCHED_BLOCK.search(line)) is not None:
            rows, cols = int(m[2]), int(m[4])
            self._emit("match", (int(m[1]) - 1) * cols + int(m[3]) - 1, rows * cols)
        elif (m := _REGISTERED.search(line)) is not None and self._stage == "map":
            self._emit("map", int(m[1]), self._totals.get("map", int(m[1])))


def run_worker(
    command: Sequence[str],
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    env: Optional[dict[str, str]] = None,
    log_path: Optional[Path] = None,
    task: str = "structure from motion",
) -> None:
    """Run `command` to completion, reporting progress; raise Cancelled or PoseError.

    On cancel the process is killed (COLMAP has no safe stop point we could wait for) and
    `Cancelled` is raised. A non-zero exit raises PoseError with the worker's own error message
    when it sent one, else the last lines of its log. `log_path`, when given, receives the whole log.
    `task` names the work in those messages ("structure from motion", "pose refinement").
    """
    tail: deque[str] = deque(maxlen=25)
    worker_error: Optional[str] = None
    translator = _Progress(progress)
    lines: "queue.Queue[Optional[str]]" = queue.Queue()
    log_file = open(log_path, "w", encoding="utf-8") if log_path is not None else None
    process = subprocess.Popen(
        list(command),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
        encoding="utf-8",
        errors="replace",
        env=env if env is not None else child_environment(),
    )

    def pump() -> None:
        assert process.stdout is not None
        for raw in process.stdout:
            lines.put(raw.rstrip("\n"))
        lines.put(None)

    reader = threading.Thread(target=pump, name="sfm-worker-output", daemon=True)
    reader.start()
    try:
        finished = False
        while not finished:
            if cancel is not None and cancel.cancelled:
                raise Cancelled()
            try:
                line = lines.get(timeout=0.1)
            except queue.Empty:
                continue
            if line is None:
                finished = True
                continue
            if log_file is not None:
                log_file.write(line + "\n")
            if line.startswith("@vortx "):
                words = line.split()[1:]
                if words and words[0] == "error":
                    worker_error = line.split(" ", 2)[2] if len(words) > 1 else "unknown error"
                elif words:
                    translator.protocol(words)
            else:
                tail.append(line)
                translator.colmap(line)
        returncode = process.wait()
    except BaseException:
        # Cancel, KeyboardInterrupt or a bug on our side: never leave COLMAP running behind us.
        process.kill()
        process.wait()
        raise
    finally:
        reader.join(timeout=5)
        if log_file is not None:
            log_file.close()

    if returncode != 0:
        if worker_error is not None:
            raise PoseError(f"{task} failed: {worker_error}")
        last = "\n".join(tail) or "(no output)"
        raise PoseError(
            f"{task} crashed: the COLMAP process {describe_exit(returncode)}. "
            f"Last log lines:\n{last}"
        )


MATCH_ARRAYS = ("keypoints_uv", "keypoints_start", "match_image", "match_keypoint")


def run_pose_job(
    job: dict[str, Any],
    work: Path,
    keep_work: bool,
    task: str,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """Run one sfm_worker job in `work` (job.json in, result.json + points.npz out) and read its
    result: (result, points (N, 3), colours (N, 3)). `work` is removed afterwards unless keep_work.
    A refine job's tracks (points.npz's obs_* arrays) come in result["tracks"] as arrays, its keypoints
    and verified matches in result["matches"] (keypoints_uv, keypoints_start, match_image, match_keypoint).

    Raises Cancelled, or PoseError naming the task when the process fails or leaves no result.
    """
    try:
        job_path = work / "job.json"
        job_path.write_text(json.dumps(job, indent=1))
        run_worker(worker_command(job_path), progress=progress, cancel=cancel, log_path=work / "colmap.log", task=task)
        try:
            result = json.loads((work / "result.json").read_text())
            with np.load(work / "points.npz") as npz:
                if "obs_image" in npz:
                    result["tracks"] = {key: npz[key] for key in ("obs_image", "obs_point", "obs_uv")}
                if "match_image" in npz:
                    result["tracks"]["obs_keypoint"] = npz["obs_keypoint"]
                    result["matches"] = {key: npz[key] for key in MATCH_ARRAYS}
                return result, npz["xyz"], npz["rgb"]
        except (OSError, ValueError) as error:
            raise PoseError(f"the {task} process ended without a usable result ({error}); "
                            "run again with a work_dir to keep its log (colmap.log)") from error
    finally:
        if not keep_work:
            shutil.rmtree(work, ignore_errors=True)
