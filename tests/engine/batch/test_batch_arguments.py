"""The batch's command line (engine/batch/arguments.py): what scripts/vortx_batch.py accepts and refuses."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.batch.arguments import parse_arguments, script_arguments
from engine.batch.plan import plan_jobs

VR = ["--vr", "--texture-size", "512", "--face-budget", "300"]


def test_several_captures_need_an_output_folder_and_export_takes_a_suffix() -> None:
    with pytest.raises(SystemExit):
        parse_arguments(["a", "b", "--out", "x.blend"])
    with pytest.raises(SystemExit):
        parse_arguments(["a", "--out", "out", "--export", "mesh.fbx"])
    args = parse_arguments(["rooms/kitchen", "rooms/kitchen", "scans/hall/transforms.json", "--out", "out", "--export", "glb"])
    jobs = plan_jobs(args, args.captures)
    assert [(j.blend.name, j.report.name, j.export.name) for j in jobs] == [
        ("kitchen.blend", "kitchen.report.json", "kitchen.glb"), ("kitchen_2.blend", "kitchen_2.report.json", "kitchen_2.glb"),
        ("hall.blend", "hall.report.json", "hall.glb")]  # a transforms.json file: named by its folder
    single = parse_arguments(["cap", "--out", "out/scene.blend"])
    assert single.single and plan_jobs(single, single.captures)[0].report == Path("out/scene.report.json")


def test_arguments_after_double_dash_or_directly() -> None:
    blender_argv = ["blender", "--background", "--python", "scripts/vortx_batch.py", "--", "cap", "--out", "a.blend"]
    python_argv = ["scripts/vortx_batch.py", "cap", "--out", "a.blend"]
    assert script_arguments(blender_argv) == script_arguments(python_argv) == ["cap", "--out", "a.blend"]
    args = parse_arguments(["cap", "--out", "a.blend", "--export", "m.GLB", "--device", "cuda"])
    assert args.export == Path("m.GLB") and args.device == "cuda" and args.weights is None and args.views == 60
    with pytest.raises(SystemExit):
        parse_arguments(["cap", "--out", "a.obj"])


def test_vr_flag_parses_with_the_texture_settings() -> None:
    args = parse_arguments(["cap", "--out", "a.blend", *VR])
    assert args.vr and args.settings.texture_size == 512 and args.settings.face_budget == 300
    assert not parse_arguments(["cap", "--out", "a.blend"]).vr
    standalone = parse_arguments(["cap", "--out", "a.blend", "--vr", "--headset", "standalone"]).settings
    assert standalone.texture_options.texture_format == "ktx2-etc1s"  # what Bake Texture and the export then use
    with pytest.raises(SystemExit):  # a headset without a textured result is refused like the other texture flags
        parse_arguments(["cap", "--out", "a.blend", "--headset", "web"])
    with pytest.raises(SystemExit):  # the engine's own check of the texture size
        parse_arguments(["cap", "--out", "a.blend", "--vr", "--texture-size", "1000"])


def test_ray_cores_must_be_positive_and_the_settings_are_the_preset_under_the_flags() -> None:
    with pytest.raises(SystemExit):
        parse_arguments(["cap", "--out", "out", "--ray", "local", "--ray-cpus", "0"])
    args = parse_arguments(["cap", "--out", "a.blend", "--quality", "preview", "--voxel-size", "0.08"])
    assert args.settings.voxel_size == 0.08 and args.quality == "preview"
    with pytest.raises(SystemExit):  # a flag the chosen method does not read is refused, not ignored
        parse_arguments(["cap", "--out", "a.blend", "--method", "stereo", "--weights", "random"])
