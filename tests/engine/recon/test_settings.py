"""ReconSettings is the one source of the reconstruction settings: `python -m engine reconstruct`,
scripts/vortx_batch.py and the Blender scene properties are generated from (or checked against) its
fields. A field added in one place only fails here."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields

import pytest

from conftest import REPO
from engine.batch.arguments import argument_parser as batch_argument_parser, parse_arguments as parse_batch_arguments
from engine.errors import VortxError
from engine.recon import cli
from engine.recon.settings import BLENDER, CLI, ReconSettings, cli_flag, field_default, setting_fields

# Flags of each command that are not reconstruction settings.
# --quality is a preset of several settings (engine/recon/presets.py), not a setting of its own.
RECONSTRUCT_OWN = {"help", "capture", "images_dir", "out", "camera_height", "features", "refine_poses", "keep_poses", "quiet", "quality", "preview"}
BATCH_OWN = {"help", "capture", "captures", "out", "export", "camera_height", "features", "skip_poses", "refine_poses", "keep_poses", "vr", "ray", "ray_cpus",
             "quality"}
# scene.vortx properties that are not ReconSettings fields: the capture summary, pose estimation,
# the weights chooser (-> ReconSettings.weights), the tile overlay and the Blender-side result options.
BLENDER_OWN = {
    "capture_path", "capture_format", "frame_count", "posed_frame_count", "resolution_x", "resolution_y",
    "poses_metric", "pose_status", "pose_source", "scale_source", "scale_description", "scale_uncertainty", "pose_check", "keep_given_poses", "skipped_count", "skipped_names", "sfm_matcher", "sfm_features", "sfm_max_image_side", "camera_height",
    "capture_frame", "weights_source", "weights_path", "show_tiles", "result_mode", "min_piece_faces", "min_piece_fraction",
    "target_faces", "quality",  # quality: the presets over the stereo settings (engine/recon/presets.py)
}


def _actions(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {a.dest: a for a in parser._actions}


def _reconstruct_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return parser


def _batch_parser_actions() -> dict[str, argparse.Action]:
    captured = {}
    real_parse = argparse.ArgumentParser.parse_args

    def grab(self, args=None, namespace=None):
        captured.update(_actions(self))
        return real_parse(self, args, namespace)

    argparse.ArgumentParser.parse_args = grab
    try:
        parse_batch_arguments(["cap", "--out", "a.blend"])
    finally:
        argparse.ArgumentParser.parse_args = real_parse
    return captured


def test_every_field_says_where_it_is_offered() -> None:
    for f in fields(ReconSettings):
        assert "expose" in f.metadata and f.metadata["help"], f"ReconSettings.{f.name}: declare it with setting(...)"
        assert set(f.metadata["expose"]) <= {CLI, BLENDER}, f.name


@pytest.mark.parametrize("which", ["engine reconstruct", "vortx_batch.py"])
def test_cli_flags_are_the_cli_fields(which: str) -> None:
    actions = _actions(_reconstruct_parser()) if which == "engine reconstruct" else _batch_parser_actions()
    own = RECONSTRUCT_OWN if which == "engine reconstruct" else BATCH_OWN
    expected = {f.name for f in setting_fields(CLI)}
    assert set(actions) - own == expected, "a command-line flag without a ReconSettings field, or the reverse"
    for f in setting_fields(CLI):
        action = actions[f.name]
        assert cli_flag(f) in action.option_strings
        default = field_default(f)
        assert action.default == (list(default) if isinstance(default, tuple) else default), f.name
        assert f.metadata["help"] in action.help
        assert action.choices == f.metadata["choices"]


def test_no_flags_give_the_default_settings_and_flags_reach_them() -> None:
    parser = _reconstruct_parser()
    assert cli.settings_from_args(parser.parse_args(["cap", "--out", "m.ply"])) == ReconSettings()
    args = parser.parse_args(["cap", "--out", "m.ply", "--image-size", "320", "--views", "9", "--max-room-size", "4", "5", "3",
                              "--colour-views", "0"])
    settings = cli.settings_from_args(args)
    assert (settings.image_long_side, settings.views, settings.max_room_size) == (320, 9, (4.0, 5.0, 3.0))
    assert settings.colour_views == 0 and not settings.colour  # 0 colour views: a grey mesh


def test_batch_help_states_the_real_image_size_default(capsys) -> None:
    with pytest.raises(SystemExit):
        parse_batch_arguments(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "the size the weights were trained at" in text and "640" not in text


def test_limits_are_checked_with_the_setting_named() -> None:
    with pytest.raises(VortxError, match="colour views must be at least 0 and at most 1000, got 5000"):
        ReconSettings(colour_views=5000).validate()
    with pytest.raises(VortxError, match=r"max room size must be at least 0.5 and at most 1000, got \(4.0, 0.1, 3.0\)"):
        ReconSettings(max_room_size=(4.0, 0.1, 3.0)).validate()


def test_blender_properties_are_the_blender_fields(blender, empty_scene) -> None:
    props = blender.vortx_blender.properties
    recon = blender.vortx_blender.reconstruct
    rna = {p.identifier: p for p in empty_scene.vortx.bl_rna.properties if p.identifier not in ("rna_type", "name")}
    engine_fields = blender.engine.recon.settings.setting_fields(BLENDER)
    names = {props.blender_name(f) for f in engine_fields}
    assert set(rna) - BLENDER_OWN == names, "a scene property without a ReconSettings field, or the reverse"
    for f in engine_fields:
        prop = rna[props.blender_name(f)]
        if f.metadata["unset"] is None and prop.type in ("INT", "FLOAT") and f.metadata["min"] is not None:
            assert prop.hard_min == pytest.approx(f.metadata["min"]), f.name
        if f.metadata["max"] is not None and prop.type in ("INT", "FLOAT"):
            assert prop.hard_max == pytest.approx(f.metadata["max"]), f.name
        assert props.scene_value(f, getattr(empty_scene.vortx, prop.identifier)) == field_default(f), f.name
    # Defaults in the panel are the engine's defaults, through the generic mapping.
    assert recon.recon_settings_from_scene(empty_scene.vortx).to_dict() == ReconSettings().to_dict()


def test_scene_settings_round_trip(blender, empty_scene) -> None:
    recon = blender.vortx_blender.reconstruct
    chosen = blender.engine.recon.ReconSettings(voxel_size=0.08, views=12, tile_size=32, seed=3, image_long_side=256,
                                                colour_views=0, max_room_size=(5.0, 6.0, 2.5), frustum_depth=3.0)
    recon.write_scene_settings(empty_scene.vortx, chosen)
    assert (empty_scene.vortx.view_count, empty_scene.vortx.image_size) == (12, 256)
    assert recon.recon_settings_from_scene(empty_scene.vortx).to_dict() == chosen.to_dict()
    recon.write_scene_settings(empty_scene.vortx, blender.engine.recon.ReconSettings())
    assert empty_scene.vortx.image_size == 0  # None ("the weights' own size") is 0 in the panel
    assert recon.recon_settings_from_scene(empty_scene.vortx).image_long_side is None


# --- options are never ignored: a flag the chosen method does not read is refused -------------------

def _flag_at_default(f) -> list[str]:
    """Field `f`'s CLI flag with a valid value written out (its default; 'random' weights; the lower
    limit for an automatic None): a given flag counts as given whatever its value."""
    from engine.recon.settings import value_type

    value = field_default(f)
    if value_type(f) is bool:
        return [cli_flag(f) if value else "--no-" + cli_flag(f)[2:]]
    if f.name == "weights":
        value = "random"
    elif value is None:
        value = f.metadata["min"]
    values = value if isinstance(value, tuple) else (value,)
    return [cli_flag(f), *(str(v) for v in values)]


def _stereo_weights(tmp_path) -> str:
    """A weights file whose network takes stereo depth (a seeded random init is enough: only its header is read)."""
    import torch

    from engine.model.config import StereoEvidenceConfig, VortxConfig
    from engine.model.vortx import VortxNet
    from engine.model.weights import save_weights

    torch.manual_seed(0)
    config = VortxConfig(stereo_evidence=StereoEvidenceConfig())
    return str(save_weights(VortxNet(config), config, tmp_path / "stereo.safetensors"))


@pytest.mark.parametrize("method", ["stereo", "vortx", "vortx with stereo weights"])
def test_each_method_refuses_every_flag_it_does_not_read(method: str, tmp_path, capsys) -> None:
    """Walks every CLI setting (a new one is covered as soon as it exists): each is either read by the
    method, so `engine reconstruct` goes on to load the capture, or refused before anything runs with
    a message naming the flag and the method that reads it; scripts/vortx_batch.py says the same."""
    from engine.__main__ import main
    from engine.recon.settings import methods_using
    name, extra, stereo_weights = method, [], False
    if method == "vortx with stereo weights":
        name, stereo_weights = "vortx", True
        extra = ["--weights", _stereo_weights(tmp_path)]
    missing = tmp_path / "no_capture_here"
    checked = {"read": 0, "refused": 0}
    for f in setting_fields(CLI):
        if f.name == "method" or (extra and f.name == "weights"):
            continue
        flags = ["--method", name, *extra, *_flag_at_default(f)]
        # A textured result (.glb; the batch's --vr), which reads the texture settings too.
        assert main(["reconstruct", str(missing), "--out", str(tmp_path / "room.glb"), *flags]) == 1
        err = capsys.readouterr().err
        if name in methods_using(f, stereo_weights):
            assert "capture not found" in err, f"{cli_flag(f)} with --method {name}: {err}"
            parse_batch_arguments([str(missing), "--out", str(tmp_path / "room.blend"), "--vr", *flags])
            checked["read"] += 1
            continue
        users = " / ".join(methods_using(f))
        assert err.startswith(f"error: --method {name} does not use {cli_flag(f)}: "), err
        assert f"{cli_flag(f)} is used only by --method {users}" in err and "Leave it out" in err
        with pytest.raises(SystemExit):
            parse_batch_arguments([str(missing), "--out", str(tmp_path / "room.blend"), "--vr", *flags])
        assert f"does not use {cli_flag(f)}" in capsys.readouterr().err
        checked["refused"] += 1
    # Each method reads some flags and not others (--weights, --views ... are VoRTX's; the stereo knobs stereo's).
    assert checked["read"] >= 5 and (checked["refused"] >= 1 or stereo_weights), checked


def test_texture_settings_are_refused_without_a_textured_result(tmp_path, capsys) -> None:
    from engine.__main__ import main
    texture = [f for f in setting_fields(CLI) if f.metadata["textured"]]
    assert {f.name for f in texture} == {"texture_size", "face_budget", "headset"}
    for f in texture:
        flags = _flag_at_default(f)
        assert main(["reconstruct", "nowhere", "--out", str(tmp_path / "room.ply"), *flags]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: {cli_flag(f)} is used only by a textured result (--out room.glb, room.obj or "
                              "room.usdz)")
        with pytest.raises(SystemExit):
            parse_batch_arguments(["nowhere", "--out", str(tmp_path / "room.blend"), *flags])
        assert f"{cli_flag(f)} is used only by a textured result (--vr)" in capsys.readouterr().err


def test_the_refusal_names_every_ignored_flag_at_once(capsys) -> None:
    from engine.__main__ import main

    assert main(["reconstruct", "nowhere", "--out", "room.ply", "--weights", "w.safetensors", "--views", "8",
                 "--voxel-size", "0.05"]) == 1
    err = capsys.readouterr().err
    assert "--method stereo does not use --weights, --views:" in err and "Leave them out" in err
    assert "--voxel-size" not in err  # stereo reads the voxel size
