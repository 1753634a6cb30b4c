"""Which captures a batch runs and where each one's outputs go (engine/batch/plan.py)."""

from __future__ import annotations

from pathlib import Path

from engine.batch.arguments import parse_arguments
from engine.batch.plan import capture_name, expand_captures, plan_jobs
from fixtures_capture import write_photo_folder


def test_a_capture_is_named_by_its_folder_a_video_by_its_stem(tmp_path: Path) -> None:
    video = tmp_path / "walk.mp4"
    video.write_bytes(b"")
    assert capture_name(tmp_path / "kitchen") == "kitchen"
    assert capture_name(tmp_path / "hall" / "transforms.json") == "hall"
    assert capture_name(video) == "walk"


def test_a_folder_of_captures_runs_each_of_them_and_leaves_out_the_output_folder(tmp_path: Path) -> None:
    rooms = tmp_path / "rooms"
    for name in ("kitchen", "hall"):
        write_photo_folder(rooms / name, 3)
    (rooms / "notes").mkdir()  # no capture: still run, so that its report says why
    (rooms / "readme.txt").write_text("not a capture")
    (rooms / ".cache").mkdir()
    write_photo_folder(rooms / "out", 3)  # the batch's own --out folder inside it
    captures = expand_captures([rooms], rooms / "out")
    assert [p.name for p in captures] == ["hall", "kitchen", "notes"]
    args = parse_arguments([str(rooms), "--out", str(rooms / "out"), "--export", ".glb"])
    assert [(j.blend.name, j.export.name) for j in plan_jobs(args, captures)] == [
        ("hall.blend", "hall.glb"), ("kitchen.blend", "kitchen.glb"), ("notes.blend", "notes.glb")]


def test_a_capture_or_a_folder_without_captures_is_run_as_given(tmp_path: Path) -> None:
    photos = tmp_path / "photos"
    write_photo_folder(photos, 3)
    assert expand_captures([photos], tmp_path / "out") == [photos]
    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)
    assert expand_captures([empty], tmp_path / "out") == [empty]  # the import then says why it is no capture
    assert expand_captures([photos, empty], tmp_path / "out") == [photos, empty]
