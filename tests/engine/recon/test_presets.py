"""Quality presets (engine/recon/presets.py): the same names and values from `engine reconstruct
--quality`, the batch's --quality and Blender's Quality (tests/vortx_blender/test_quality_menu.py); explicit
flags win over a preset; a preset a method would not read is refused, never ignored."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import pytest

from conftest import REPO
from engine.batch.arguments import argument_parser as batch_argument_parser, parse_arguments as parse_batch_arguments
from engine.errors import VortxError
from engine.recon import cli
from engine.recon.presets import (DEFAULT_QUALITY, PRESETS, QUALITY_FIELDS, QUALITY_NAMES, apply_quality, preset,
                                  preset_values, quality_of)
from engine.recon.settings import ReconSettings
from engine.stereo.options import MATCHER_FAST, MATCHER_PATCHMATCH, StereoOptions


def _reconstruct(argv: list[str]) -> tuple[argparse.Namespace, ReconSettings]:
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args(["cap", "--out", "m.ply", *argv])
    return args, cli.settings_from_args(args)


def _batch(argv: list[str]) -> argparse.Namespace:
    return parse_batch_arguments(["cap", "--out", "a.blend", *argv])


def test_the_presets_go_from_fast_to_careful() -> None:
    assert QUALITY_NAMES == ("preview", "standard", "high") and DEFAULT_QUALITY == "standard"
    preview, standard, high = (preset_values(name) for name in QUALITY_NAMES)
    assert standard == {key: getattr(ReconSettings(), key) for key in QUALITY_FIELDS}  # Standard is the defaults
    assert preview["stereo_matcher"] == MATCHER_FAST and high["stereo_matcher"] == MATCHER_PATCHMATCH
    assert preview["stereo_image_size"] < StereoOptions.long_side < high["stereo_image_size"]
    assert preview["stereo_views"] < standard["stereo_views"]
    with pytest.raises(VortxError, match="use one of preview, standard, high"):
        preset("ultra")


def test_each_preset_says_its_measured_time_or_why_not() -> None:
    for chosen in PRESETS:
        text = chosen.description()
        if chosen.demo_seconds is not None:
            assert f"{chosen.time_text()} on the demo room" in text
        else:
            assert "not measured" in text and chosen.not_measured, chosen.name


@pytest.mark.parametrize("name", QUALITY_NAMES)
def test_cli_and_batch_give_the_same_settings_for_a_preset(name: str) -> None:
    _, settings = _reconstruct(["--quality", name])
    assert settings == apply_quality(ReconSettings(), name)
    assert _batch(["--quality", name]).settings == settings
    assert quality_of(settings) == name


def test_explicit_flags_win_over_the_preset() -> None:
    _, settings = _reconstruct(["--quality", "preview", "--stereo-views", "40"])
    expected = replace(apply_quality(ReconSettings(), "preview"), stereo_views=40)
    assert settings == expected and settings.stereo_image_size == preset_values("preview")["stereo_image_size"]
    assert quality_of(settings) is None  # no preset any more: the sidecar and the report say "custom"
    # Even a flag given at its default value wins: it was asked for.
    _, settings = _reconstruct(["--stereo-image-size", str(StereoOptions.long_side), "--quality", "high"])
    assert settings.stereo_image_size == StereoOptions.long_side and settings.stereo_matcher == MATCHER_PATCHMATCH
    assert _batch(["--quality", "preview", "--stereo-views", "40"]).settings == expected
    for help_text in (_help(cli.add_arguments), _batch_help()):
        assert "flags given explicitly win over the preset" in help_text
        assert all(f"{p.name} = {p.description()}" in help_text for p in PRESETS)


def _help(add_arguments) -> str:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return " ".join(parser.format_help().split())


def _batch_help() -> str:
    return " ".join(batch_argument_parser().format_help().split())


def test_a_preset_the_method_does_not_read_is_refused(capsys) -> None:
    args, settings = _reconstruct(["--method", "vortx", "--weights", "random", "--quality", "high"])
    with pytest.raises(VortxError, match="--quality high sets --stereo, --stereo-image-size, which --method vortx does not use"):
        cli.refuse_unused_quality(settings, args.quality, cli.given_settings(args))
    with pytest.raises(SystemExit):
        _batch(["--method", "vortx", "--weights", "random", "--quality", "preview"])
    assert "--quality preview sets" in capsys.readouterr().err
    # Standard sets nothing of its own: fine with any method.
    args, settings = _reconstruct(["--method", "vortx", "--weights", "random", "--quality", "standard"])
    cli.refuse_unused_quality(settings, args.quality, cli.given_settings(args))


def test_times_read_as_people_say_them() -> None:
    times = {seconds: replace(PRESETS[0], demo_seconds=seconds).time_text() for seconds in (50, 132, 594, 598, 898)}
    assert times == {50: "50 s", 132: "2.2 min", 594: "9.9 min", 598: "10 min", 898: "15 min"}
