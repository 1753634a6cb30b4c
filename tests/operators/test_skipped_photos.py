"""Import Capture in Blender with one corrupt photo among good ones: the capture imports without it
and the operator's warning report names it (issue 12: skip, warn, go on)."""

from __future__ import annotations

from pathlib import Path

from fixtures_capture import ring_poses, write_photo_folder, write_transforms_json


def test_transforms_json_with_a_truncated_photo_imports_without_it(blender, empty_scene, tmp_path: Path, capfd) -> None:
    import bpy

    photos = write_photo_folder(tmp_path / "cap" / "images", 4, (64, 48), suffix=".jpg")
    data = photos[2].read_bytes()
    photos[2].write_bytes(data[: len(data) // 2])
    path = write_transforms_json(tmp_path / "cap" / "transforms.json",
                                 [(f"images/{p.name}", pose) for p, pose in zip(photos, ring_poses(4))],
                                 fl_x=60.0, w=64, h=48)
    assert bpy.ops.vortx.import_capture(filepath=str(path)) == {"FINISHED"}
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o),
                     key=lambda o: o["vortx_frame"])
    assert [Path(o["vortx_image"]).name for o in cameras] == ["frame0.jpg", "frame1.jpg", "frame3.jpg"]
    assert (empty_scene.vortx.frame_count, empty_scene.vortx.posed_frame_count) == (3, 3)
    out = capfd.readouterr().out
    assert "1 photo(s) skipped, the capture goes on without them: frame2.jpg (corrupt, truncated" in out
