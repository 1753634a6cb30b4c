"""The batch's Ray driver without a cluster (engine/batch/ray_cluster.py): each capture's command,
why an attempt failed, the memory declared and the report a capture gets when no attempt left one.
tests/scripts/test_vortx_batch_ray.py runs real clusters."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from conftest import REPO
from engine.batch.arguments import argument_parser, parse_arguments, script_arguments
from engine.batch.plan import plan_jobs
from engine.batch.ray_cluster import (CaptureTask, attempt_error, capture_command, fail_all, final_report,
                                      forwarded_options, interpreter_command, memory_need)
from engine.batch.report import blank_report
from engine.recon.memory_estimate import BASELINE_BYTES, BLENDER_PROCESS_BYTES

BATCH = REPO / "scripts" / "vortx_batch.py"
# tests/scripts/test_vortx_batch.py's tiny settings: 16 cm voxels, 3 views, 160 px, a 2 m room.
TINY = ["--method", "vortx", "--weights", "random", "--voxel-size", "0.16", "--tile-size", "8", "--views", "3", "--image-size", "160",
        "--colour-views", "3", "--max-room-size", "2", "2", "2"]


def test_each_capture_runs_the_batch_script_with_the_users_options() -> None:
    """The command of one capture's task is the batch script on that capture alone, with --out and
    --export made its own and every other option repeated: parsed back, the same run."""
    args = parse_arguments(["rooms", "--out", "out", "--export", ".ply", "--ray", "local", "--ray-cpus", "2", *TINY,
                            "--vr", "--camera-height", "1.3"])
    (job,) = plan_jobs(args, [Path("rooms/kitchen")])
    command = capture_command(interpreter_command(BATCH), forwarded_options(argument_parser(), args), job)
    assert command[:2] == [sys.executable, str(BATCH)]
    assert "--ray" not in command and "--ray-cpus" not in command
    again = parse_arguments(script_arguments(command[1:]))
    assert again.captures == [Path("rooms/kitchen").absolute()] and again.single
    assert again.out == (Path("out") / "kitchen.blend").absolute() and again.export == (Path("out") / "kitchen.ply").absolute()
    assert again.settings == args.settings and again.vr and again.camera_height == 1.3 and again.ray is None
    assert "--views" in command and "--seed" not in command  # options left at their default are not repeated

    # Under Blender the capture runs in Blender again, its arguments after `--`.
    blender = capture_command(interpreter_command(BATCH, "/opt/blender/blender"), [], job)
    assert blender[:6] == ["/opt/blender/blender", "--background", "--python-exit-code", "1", "--python", str(BATCH)]
    assert parse_arguments(script_arguments(blender)).out == again.out


def test_a_capture_process_that_died_without_a_report_says_so() -> None:
    killed = {"returncode": -9, "report": None, "output_tail": "vortx [3/4] reconstruct: ...\n", "error": None}
    assert attempt_error(killed) == ("the capture's process was killed by SIGKILL (often the system's out-of-memory "
                                     "killer) and wrote no report; its last output: vortx [3/4] reconstruct: ...")
    crashed = {**killed, "returncode": 1, "output_tail": "Traceback ...\nerror: Blender quit\nvortx bye\n"}
    assert attempt_error(crashed) == "the capture's process exited with status 1 and wrote no report; its last output: error: Blender quit"
    done = {"returncode": 0, "report": json.dumps({"status": "ok", "error": None}), "output_tail": "", "error": None}
    assert attempt_error(done) is None


def test_a_capture_that_cannot_be_loaded_declares_the_blender_process_and_the_engine(tmp_path: Path) -> None:
    args = parse_arguments([str(tmp_path / "missing"), "--out", str(tmp_path / "scene.blend"), "--ray", "local"])
    (job,) = plan_jobs(args, args.captures)
    need, memory = memory_need(job, args)
    assert need == BLENDER_PROCESS_BYTES + BASELINE_BYTES == memory["declared_bytes"] and memory["estimate"] is None
    assert memory["note"].startswith("no estimate (CaptureError)")


def test_a_capture_without_a_report_gets_one_that_says_why(tmp_path: Path) -> None:
    args = parse_arguments([str(tmp_path / "kitchen"), "--out", str(tmp_path / "out"), "--ray", "local"])
    (job,) = plan_jobs(args, args.captures)
    task = CaptureTask(job, ["blender"], 2**30, errors=["its Ray task died: OutOfMemoryError"])
    report = final_report(task, None, lambda j: blank_report(j, args.settings), {"attempts": 2})
    assert report["status"] == "failed" and report["failed_step"] == "cluster" and report["cluster"] == {"attempts": 2}
    assert report["error"] == "its Ray task died: OutOfMemoryError" and report["settings"]["voxel_size"] == args.settings.voxel_size
    own = {"returncode": 1, "report": json.dumps({"status": "failed", "error": None, "failed_step": "poses"})}
    assert final_report(task, own, None, {})["error"] == "its Ray task died: OutOfMemoryError"  # its own report, the reason added


def test_no_cluster_fails_every_capture_with_the_reason(tmp_path: Path, capsys) -> None:
    args = parse_arguments([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "out"), "--ray", "nowhere"])
    jobs = plan_jobs(args, args.captures)
    assert fail_all(jobs, "--ray nowhere: give the cluster's HOST:PORT", lambda j: blank_report(j, args.settings)) == 1
    reports = [json.loads(job.report.read_text()) for job in jobs]
    assert all(r["failed_step"] == "cluster" and r["error"].startswith("--ray nowhere") for r in reports)
    assert capsys.readouterr().err == "error: --ray nowhere: give the cluster's HOST:PORT\n"
