"""The batch's captures as tasks on a Ray cluster: `scripts/vortx_batch.py ... --ray HOST:PORT` (an
existing cluster) or `--ray local` (one started on this machine for the run, then shut down).

One Ray task per capture. The task runs the batch script itself for that one capture, as a child
process of the same interpreter (the bpy module's Python, or Blender with --background), exactly as
a sequential run would: bpy keeps one scene per process and the extension's operators, SfM
subprocess and torch threads assume they own it, so Blender state never lives inside a long-lived
Ray worker, a crash or an out-of-memory kill takes down only that capture's process, and the
capture's .blend, mesh file and JSON report are written by the code the sequential batch runs.

Each task declares the memory its capture needs (`recon.memory_estimate.estimate_capture_memory`:
the capture's keyframes, scene bounds and image size under this run's settings, plus the Blender
process and, with --vr, the texture bake; the driver loads each capture for it, which extracts a
video's frames into its cache), so Ray starts no more captures on a machine than its
memory holds; a capture needing more than the largest machine offers fails at once with the
numbers. A failed capture (the script failed, its process or worker died, its machine left the
cluster) is run once more, then reported: its report says so under "cluster" (address, node,
attempts, the memory declared, each failed attempt's error). The task also hands the report's text
back, so the driver writes every report into --out even when the machines share no disk.

Every machine needs this checkout and the same interpreter at the same paths, and the captures and
--out at the same paths (a shared disk): the command a task runs is the driver's own.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from argparse import ArgumentParser, Namespace
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Optional, Sequence

from ..capture import load_capture
from ..recon.memory_estimate import BASELINE_BYTES, BLENDER_PROCESS_BYTES, estimate_capture_memory
from .plan import CaptureJob
from .report import CaptureReport, write_json_atomically
from .runner import batch_summary

# The report of a capture not yet run (report.blank_report with the run's settings).
NewReport = Callable[[CaptureJob], CaptureReport]

LOCAL = "local"  # --ray local: a cluster of this machine alone, for this run
ATTEMPTS = 2  # a failed capture runs once more, then is reported
LOCAL_OBJECT_STORE_BYTES = 100 * 2**20  # tasks pass only a command and a report's text
OUTPUT_TAIL_CHARS = 4000  # of a failed capture's console output, kept for the driver's message
# The batch's own options that --ray sets per capture (or that only the driver reads): not forwarded.
DRIVER_ONLY = ("captures", "out", "export", "ray", "ray_cpus", "help")
GIB = 2**30


@dataclass
class CaptureTask:
    """One capture as the driver schedules it."""

    job: CaptureJob
    command: list[str]
    memory_bytes: int
    memory: dict[str, Any] = field(default_factory=dict)  # the estimate's parts, or why there is none
    attempts: int = 0
    errors: list[str] = field(default_factory=list)  # each failed attempt's reason
    submitted: Optional[float] = None  # perf_counter() at the first submission


# --- the command of one capture --------------------------------------------------------------------

def interpreter_command(script: Path, blender_binary: str = "") -> list[str]:
    """How this process was started, to start the same for one capture: Blender (bpy.app.binary_path,
    set only inside Blender) with the script after `--`, else this Python with the bpy module."""
    if blender_binary:
        return [blender_binary, "--background", "--python-exit-code", "1", "--python", str(script), "--"]
    return [sys.executable, str(script)]


def forwarded_options(parser: ArgumentParser, args: Namespace) -> list[str]:
    """The options the user gave that every capture's run repeats (reconstruction settings, --vr,
    --camera-height, ...), rebuilt from the parsed values: every option the batch script defines,
    except the driver's own (DRIVER_ONLY); those still at their default are left out."""
    options: list[str] = []
    for action in parser._actions:  # argparse offers no public list of its actions
        if action.dest in DRIVER_ONLY or not action.option_strings:
            continue
        value, flag = getattr(args, action.dest), action.option_strings[0]
        if value == action.default or value is None:
            continue
        if action.nargs == 0:  # store_true / BooleanOptionalAction
            if len(action.option_strings) > 1 and not value:  # --x / --no-x
                flag = next(s for s in action.option_strings if s.startswith("--no-"))
            options.append(flag)
        elif isinstance(value, (list, tuple)):
            options += [flag, *map(str, value)]
        else:
            options += [flag, str(value)]
    return options


def capture_command(interpreter: list[str], forwarded: list[str], job: CaptureJob) -> list[str]:
    """One capture's batch run: the capture, `--out NAME.blend` (the report lands beside it as the
    sequential batch names it), its --export path, and the forwarded options. Absolute paths: the
    task may run in another folder or on another machine."""
    command = [*interpreter, str(job.capture.absolute()), "--out", str(job.blend.absolute())]
    if job.export is not None:
        command += ["--export", str(job.export.absolute())]
    return command + forwarded


# --- the Ray task ----------------------------------------------------------------------------------

def run_capture_process(command: list[str], report_path: str, cwd: str) -> dict[str, Any]:
    """The body of one capture's Ray task: run `command`, hand back its exit status, the report it
    wrote and where it ran. Never raises for a failed capture; a dead worker raises in the driver."""
    import ray  # defers ray: an optional package, needed only with --ray

    where = {"node": ray.get_runtime_context().get_node_id(), "host": socket.gethostname()}
    if not Path(command[0]).exists():
        return {**where, "returncode": None, "report": None, "output_tail": "",
                "error": f"{command[0]} does not exist on {where['host']}: every machine of the cluster needs "
                         "the same Blender (or Python with the bpy module) and checkout at the same paths"}
    report = Path(report_path)
    report.unlink(missing_ok=True)  # a report left by an earlier attempt or run is not this run's
    started = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True, cwd=cwd if Path(cwd).is_dir() else None)
    output = run.stdout + run.stderr
    return {**where, "returncode": run.returncode, "seconds": round(time.perf_counter() - started, 3),
            "report": report.read_text() if report.is_file() else None, "output_tail": output[-OUTPUT_TAIL_CHARS:],
            "error": None}


def attempt_error(result: dict[str, Any]) -> Optional[str]:
    """Why one attempt failed (None when the capture is done)."""
    if result.get("error"):
        return result["error"]
    report = json.loads(result["report"]) if result.get("report") else None
    if result["returncode"] == 0 and report is not None and report.get("status") == "ok":
        return None
    if report is not None and report.get("error"):
        return report["error"]
    lines = [line for line in result.get("output_tail", "").splitlines() if line.strip()]
    last = next((line for line in reversed(lines) if line.startswith("error: ")), lines[-1] if lines else "")
    code = result["returncode"]
    if code < 0:
        how = f"was killed by {signal.Signals(-code).name}" + (
            " (often the system's out-of-memory killer)" if -code == signal.SIGKILL else "")
    else:
        how = f"exited with status {code}"
    return f"the capture's process {how} and wrote no report" + (f"; its last output: {last}" if last else "")


# --- the memory need --------------------------------------------------------------------------------

def memory_need(job: CaptureJob, args: Namespace) -> tuple[int, dict[str, Any]]:
    """Bytes to declare for `job`, and the estimate's parts. A capture the engine cannot load or
    plan gets the Blender process and the engine's baseline: its run then fails early with the
    loader's own message."""
    floor = BLENDER_PROCESS_BYTES + BASELINE_BYTES
    try:
        capture = load_capture(job.capture)
        estimate = estimate_capture_memory(capture, args.settings, texture=args.vr, camera_height=args.camera_height)
    except Exception as error:  # engine.errors.VortxError (its run reports it), or a capture that does not exist
        return floor, {"declared_bytes": floor, "estimate": None,
                       "note": f"no estimate ({type(error).__name__}): declared the Blender process and the engine alone"}
    return estimate.total, {"declared_bytes": estimate.total, "estimate": estimate.to_dict()}


def largest_node_memory(ray: ModuleType) -> int:
    """The most memory (Ray's `memory` resource, bytes) any live machine of the cluster offers."""
    return int(max((node["Resources"].get("memory", 0) for node in ray.nodes() if node.get("Alive")), default=0))


# --- the driver -------------------------------------------------------------------------------------

def connect(ray: ModuleType, address: str) -> None:
    """Join the cluster at `address`, or start one of this machine alone (`local`): every core, a
    small object store (tasks pass only a command line and a report), no dashboard."""
    if address == LOCAL:
        ray.init(num_cpus=len(os.sched_getaffinity(0)), object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                 include_dashboard=False, logging_level="WARNING")
    else:
        check_reachable(address)
        try:
            ray.init(address=address, logging_level="WARNING")
        except ConnectionError as error:
            raise ClusterError(f"--ray {address}: no Ray cluster answers there ({error}); start one with "
                               "`ray start --head` and pass the address it prints, or use --ray local") from None


def check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """ClusterError unless something listens at HOST:PORT (`ray://` client addresses too): ray.init
    itself retries a wrong address for minutes without a word."""
    if address == "auto":  # the cluster this machine belongs to, found by Ray
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"--ray {address}: give the cluster's HOST:PORT (`ray start --head` prints it), "
                           "'auto' on a machine of the cluster, or 'local'")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as error:
        raise ClusterError(f"--ray {address}: nothing answers there ({error}); start the cluster with "
                           "`ray start --head` on its first machine and pass the address it prints, or use --ray local") from None


class ClusterError(Exception):
    """The cluster cannot be used at all; printed as `error: <message>`."""


def final_report(task: CaptureTask, result: Optional[dict[str, Any]], new_report: NewReport,
                 cluster: dict[str, Any]) -> dict[str, Any]:
    """The capture's own report (from its last attempt) with "cluster" filled in; when no attempt
    left one (its process or machine died, or it never ran), a failed report that says why."""
    report = json.loads(result["report"]) if result and result.get("report") else None
    if report is None:
        blank = new_report(task.job)
        blank.error, blank.failed_step = task.errors[-1], "cluster"
        report = asdict(blank)
    elif task.errors and report.get("status") != "ok" and not report.get("error"):
        report["error"] = task.errors[-1]
    report["cluster"] = cluster
    return report


def run_on_ray(args: Namespace, parser: ArgumentParser, jobs: Sequence[CaptureJob], new_report: NewReport,
               script: Path, blender_binary: str = "") -> int:
    """Every capture of `jobs` as a Ray task on the cluster at args.ray (see module doc); each report
    written as soon as its capture is finished or given up; 1 when any failed, else 0."""
    try:
        # defers ray: an optional package, needed only with --ray
        import ray
        from ray import cloudpickle
    except ImportError:
        return fail_all(jobs, f"--ray needs the ray package in {sys.executable}: pip install ray (the version pinned "
                              "in requirements.txt)", new_report)
    try:
        connect(ray, args.ray)
    except ClusterError as error:
        return fail_all(jobs, str(error), new_report)
    try:
        # Workers cannot import this module (the checkout or the extension is not on their path): send
        # the task's code itself.
        cloudpickle.register_pickle_by_value(sys.modules[__name__])
        interpreter = interpreter_command(script.resolve(), blender_binary)
        forwarded = forwarded_options(parser, args)

        def plan(job: CaptureJob) -> CaptureTask:
            need, estimate = memory_need(job, args)
            return CaptureTask(job, capture_command(interpreter, forwarded, job), need, estimate)

        return _run_tasks(ray, args, jobs, plan, new_report)
    finally:
        ray.shutdown()  # disconnects; a `local` cluster is stopped with it


def fail_all(jobs: Sequence[CaptureJob], message: str, new_report: NewReport) -> int:
    """No cluster to run on: every capture's report says why (step "cluster"); the error printed once."""
    for job in jobs:
        report = new_report(job)
        report.error, report.failed_step = message, "cluster"
        write_json_atomically(job.report, asdict(report))
    print(f"error: {message}", file=sys.stderr, flush=True)
    return 1


def _run_tasks(ray: ModuleType, args: Namespace, jobs: Sequence[CaptureJob], plan: Callable[[CaptureJob], CaptureTask],
               new_report: NewReport) -> int:
    """Plan (estimate) and submit each capture in turn, so the first run while later ones are estimated;
    then collect, run a failed one once more, and report each as it finishes."""
    remote = ray.remote(run_capture_process)
    largest = largest_node_memory(ray)
    cwd = os.getcwd()
    address = args.ray if args.ray == LOCAL else ray.get_runtime_context().gcs_address
    print(f"vortx batch on Ray ({address}): {len(jobs)} capture(s), {len(ray.nodes())} machine(s), "
          f"largest {largest / GIB:.1f} GiB", flush=True)
    pending: dict[Any, CaptureTask] = {}
    failed: list[str] = []
    finished = 0

    def submit(task: CaptureTask) -> None:
        task.attempts += 1
        task.submitted = task.submitted or time.perf_counter()
        ref = remote.options(num_cpus=args.ray_cpus, memory=task.memory_bytes, max_retries=0).remote(
            task.command, str(task.job.report.absolute()), cwd)
        pending[ref] = task

    def finish(task: CaptureTask, result: Optional[dict[str, Any]]) -> None:
        nonlocal finished
        finished += 1
        cluster = {"address": address, "attempts": task.attempts, "memory": task.memory,
                   "node": result.get("node") if result else None, "host": result.get("host") if result else None,
                   "errors": list(task.errors),
                   "wall_s": round(time.perf_counter() - task.submitted, 3) if task.submitted else 0.0}  # queue + runs
        report = final_report(task, result, new_report, cluster)
        write_json_atomically(task.job.report, report)
        if report.get("status") == "ok":
            print(f"vortx capture {finished}/{len(jobs)} done: {task.job.capture} on {cluster['host']} "
                  f"(attempt {task.attempts})", flush=True)
        else:
            failed.append(str(task.job.capture))
            print(f"error: {task.job.capture}: {report.get('error')}", file=sys.stderr, flush=True)

    for job in jobs:
        task = plan(job)
        if task.memory_bytes > largest:
            task.errors.append(
                f"needs an estimated {task.memory_bytes / GIB:.1f} GiB of memory, more than the largest machine of the "
                f"Ray cluster offers ({largest / GIB:.1f} GiB): raise --voxel-size, lower --views or --max-room-size "
                "(or --texture-size with --vr), or add a machine with more memory")
            finish(task, None)
        else:
            submit(task)
    while pending:
        (ref,), _ = ray.wait(list(pending), num_returns=1)
        task = pending.pop(ref)
        try:
            result = ray.get(ref)
            error = attempt_error(result)
        except Exception as crash:  # the worker or its machine died (out of memory, node lost)
            result, error = None, f"its Ray task died: {type(crash).__name__}: {' '.join(str(crash).split())[:500]}"
        if error is None:
            finish(task, result)
            continue
        task.errors.append(error)
        if task.attempts < ATTEMPTS:
            print(f"vortx capture {task.job.capture} failed (attempt {task.attempts} of {ATTEMPTS}): {error}; "
                  "running it again", flush=True)
            submit(task)
        else:
            finish(task, result)
    folder = args.out.parent if args.single else args.out
    print(batch_summary(len(jobs), failed, folder), flush=True)
    return 1 if failed else 0
