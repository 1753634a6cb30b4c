"""Quality presets of a reconstruction: Preview, Standard and High, each a few ReconSettings values.

The one place the presets are defined. `python -m engine reconstruct --quality NAME`,
`scripts/vortx_batch.py --quality NAME` and Blender's Reconstruction > Quality all read them.

A preset sets every field in QUALITY_FIELDS: the fields it names to its own values and the others to
their defaults, so Standard after Preview gives back the defaults. Flags given explicitly on the
command line win over the preset (`--quality preview --stereo-views 40` keeps Preview's other values).
No bpy and no torch here.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Mapping, Optional

from ..errors import VortxError
from ..finish.modes import FINISH_ROOM
from ..stereo.options import MATCHER_FAST, MATCHER_PATCHMATCH
from .settings import (ReconSettings, cli_flag, field_default, given_settings, methods_using, refuse_ignored_settings,
                       setting_fields, settings_from_arguments)

# The demo room (samples/demo_room, 36 photos of 320 x 240) posed as `make demo` poses it
# (`python -m engine poses samples/demo_room/images`), then
# `python -m engine reconstruct <posed> --quality NAME --out room.ply`: wall seconds on this project's
# 2-core machine, idle, PatchMatch matching two references at once with one torch thread each. Measured
# with the window grid written contiguous: Preview 11 s (18 CPU s), Standard 63 s (118 CPU s), High 92 s
# (173 CPU s); the code before took 10, 67 and 115 s the same hour (earlier, on a machine 10-30 %
# slower: 13, 76 and 131 s). Before PatchMatch ran references in parallel,
# Standard took 598 s beside other jobs: torch's own thread pool stalled whenever another process held a core.
DEMO_MACHINE = "the demo room's 36 photos, 2 CPU cores"


@dataclass(frozen=True)
class QualityPreset:
    name: str  # the CLI name (lower case); Blender's enum id is its upper case
    label: str  # the name Blender shows
    overrides: Mapping[str, Any] = field(default_factory=dict)  # ReconSettings field -> value
    summary: str = ""  # what the preset does, a few words
    demo_seconds: Optional[float] = None  # measured on the demo room (DEMO_MACHINE); None: not measured yet
    not_measured: str = ""  # why demo_seconds is None

    def time_text(self) -> str:
        """The measured time as people read it: "50 s", "3.2 min", "15 min", or "not measured yet"."""
        if self.demo_seconds is None:
            return "not measured yet"
        if self.demo_seconds < 90:
            return f"{self.demo_seconds:.0f} s"
        minutes = round(self.demo_seconds / 60, 1)  # rounded first: 598 s reads "10 min", not "10.0 min"
        return f"{minutes:.1f} min" if minutes < 10 else f"{minutes:.0f} min"

    def description(self) -> str:
        """One sentence: what it does and its measured time (the CLI help and Blender's tooltip)."""
        timing = (f"{self.time_text()} on {DEMO_MACHINE}" if self.demo_seconds is not None
                  else f"time not measured yet ({self.not_measured})" if self.not_measured else "time not measured yet")
        return f"{self.summary}: {timing}"


PRESETS: tuple[QualityPreset, ...] = (
    QualityPreset(
        "preview", "Preview",
        # Finish Room on every preset: on the demo room it lifts F by 0.09 with Preview's maps too
        # (docs/experiments.md, "A finished room"), and costs about a CPU second.
        {"stereo_matcher": MATCHER_FAST, "stereo_image_size": 160, "stereo_views": 16, "finish": FINISH_ROOM},
        "Fast matcher, 160 px stereo photos, 16 depth maps: a quick look at the room",
        demo_seconds=11),
    QualityPreset(
        "standard", "Standard", {},
        "The default settings: PatchMatch matcher (slanted planes per pixel), 240 px stereo photos, clean walls and floors",
        demo_seconds=63),
    QualityPreset(
        "high", "High",
        {"stereo_matcher": MATCHER_PATCHMATCH, "stereo_image_size": 320, "finish": FINISH_ROOM},
        "PatchMatch matcher at 320 px stereo photos: finer depth on sharp photos, about 1.5x Standard's time",
        demo_seconds=92),
)
QUALITY_NAMES: tuple[str, ...] = tuple(p.name for p in PRESETS)
DEFAULT_QUALITY = "standard"
# Every field some preset sets: choosing a preset sets all of them (its own values, the others' defaults).
QUALITY_FIELDS: tuple[str, ...] = tuple(f.name for f in setting_fields() if any(f.name in p.overrides for p in PRESETS))


def preset(name: str) -> QualityPreset:
    """The preset called `name` (lower case); VortxError naming the presets otherwise."""
    for candidate in PRESETS:
        if candidate.name == name:
            return candidate
    raise VortxError(f"unknown quality {name!r}: use one of {', '.join(QUALITY_NAMES)}")


def preset_values(name: str) -> dict[str, Any]:
    """The value of every QUALITY_FIELDS field under preset `name`."""
    chosen = preset(name)
    fields_by_name = {f.name: f for f in setting_fields()}
    return {key: chosen.overrides.get(key, field_default(fields_by_name[key])) for key in QUALITY_FIELDS}


def apply_quality(settings: ReconSettings, name: str, given: Iterable[str] = ()) -> ReconSettings:
    """`settings` with preset `name`'s values, except the fields in `given` (set explicitly: they win)."""
    given = set(given)
    return replace(settings, **{key: value for key, value in preset_values(name).items() if key not in given})


def quality_of(values: Mapping[str, Any] | ReconSettings) -> Optional[str]:
    """The preset whose values `values` (a ReconSettings, or field name -> value) hold, or None (custom)."""
    get = (lambda key: getattr(values, key)) if isinstance(values, ReconSettings) else values.__getitem__
    for candidate in PRESETS:
        if all(get(key) == value for key, value in preset_values(candidate.name).items()):
            return candidate.name
    return None


def quality_help() -> str:
    """The --quality help: each preset with what it does and its measured time, and who wins."""
    presets = "; ".join(f"{p.name} = {p.description()}" for p in PRESETS)
    return (f"quality preset: {presets}. It sets {', '.join(cli_flag(f) for f in setting_fields() if f.name in QUALITY_FIELDS)}; "
            "flags given explicitly win over the preset (default: %(default)s)")


def add_quality_argument(parser: argparse.ArgumentParser) -> None:
    """--quality NAME, for `engine reconstruct` and the batch script."""
    parser.add_argument("--quality", choices=QUALITY_NAMES, default=DEFAULT_QUALITY, help=quality_help())


def refuse_unused_quality(settings: ReconSettings, name: str, given: Iterable[str] = ()) -> None:
    """VortxError when preset `name` changes settings that `settings.method` does not read (e.g. High
    for --method vortx, whose weights take no stereo depth): a preset is never silently ignored."""
    set_by_preset = {key for key in preset(name).overrides if key not in set(given)}
    if not set_by_preset:
        return
    try:
        refuse_ignored_settings(settings, set_by_preset)
    except VortxError:
        flags = ", ".join(cli_flag(f) for f in setting_fields()  # only those the method does not read
                          if f.name in set_by_preset and settings.method not in methods_using(f))
        raise VortxError(f"--quality {name} sets {flags}, which --method {settings.method} does not use here: leave "
                         f"--quality out (or use --quality {DEFAULT_QUALITY}), or use --method stereo") from None


def settings_from_quality_arguments(args: argparse.Namespace) -> ReconSettings:
    """ReconSettings from the setting flags and --quality (explicit flags win over the preset)."""
    return apply_quality(settings_from_arguments(args), args.quality, given_settings(args))
