"""ReconSettings: every knob of a reconstruction run, in one JSON-serialisable dataclass.

Defaults follow the official VoRTX inference (vortx-spec.md section 4): 4 cm finest voxels, 60 views
per tile, 96 x 96 x 48 fine-voxel tiles, seed 0, NeuralRecon keyframe thresholds. The engine-only
knobs (chunk sizes, colour views, room clipping) bound memory and time on a laptop CPU.
"""

from __future__ import annotations

import argparse
import typing
from dataclasses import MISSING, Field, asdict, dataclass, field, fields
from typing import Any, Optional

from ..errors import VortxError
from ..finish.modes import FINISH_MODES, FINISH_ROOM  # the finishing stage's modes live with it
from ..geometry.view_selection import DEFAULT_KEYFRAME_ANGLE_DEG, DEFAULT_KEYFRAME_TRANSLATION_M  # the keyframe rule's
from ..stereo.options import STEREO_MATCHERS, StereoOptions  # the stereo defaults live with the stereo code
from ..texture.options import TEXTURE_SIZES, TextureOptions  # and the texture bake's with the bake
from ..texture.presets import DEFAULT_PRESET, PRESET_NAMES, PRESETS, with_preset  # the headset budgets

# Each level is twice as coarse as the next: coarse / medium / fine = 4x / 2x / 1x the finest voxel.
LEVEL_SCALES: tuple[int, int, int] = (4, 2, 1)
COARSE_FACTOR = LEVEL_SCALES[0]


def level_voxel_sizes(voxel_size: float) -> tuple[float, float, float]:
    """(coarse, medium, fine) voxel sizes in metres for a finest voxel size."""
    return tuple(voxel_size * s for s in LEVEL_SCALES)  # type: ignore[return-value]


def level_label(voxel_size: float) -> str:
    """A level's name as the user reads it: 0.16 -> "16 cm"."""
    return f"{round(voxel_size * 100, 2):g} cm"


# Where a setting is offered to the user. Every field says so explicitly (tests check it), so a new
# field cannot be forgotten by one entry point: `python -m engine reconstruct` and
# scripts/vortx_batch.py generate a flag for each CLI field, Blender a scene property for each
# BLENDER field (vortx_blender/properties.py).
METHODS = ("stereo", "vortx")  # reconstruction methods, the default first
# The coordinates a result is written (and Blender shows the capture) in: engine/recon/output_frame.py.
FRAME_WORLD = "world"  # Z up, floor at z = 0, metres: what the network reconstructs in (the default)
FRAME_CAPTURE = "capture"  # the coordinates (and units) of the capture's own camera poses
FRAMES = (FRAME_WORLD, FRAME_CAPTURE)

CLI = "cli"
BLENDER = "blender"
ENGINE_ONLY: tuple[str, ...] = ()  # tuning knobs of the engine itself; changed in code, not by users


# Which methods read a setting (`setting(methods=...)`): a flag given for a method that does not read
# it is refused (`refuse_unused_settings`), never silently ignored. STEREO_EVIDENCE_WEIGHTS stands for
# "vortx, when its weights take stereo depth as an input" (VortxConfig.stereo_evidence): only then does
# VoRTX run the stereo depth maps.
STEREO_EVIDENCE_WEIGHTS = "vortx with stereo-evidence weights"


def setting(default: Any, help: str, expose: tuple[str, ...], *, methods: tuple[str, ...] = METHODS,
            min: Optional[float] = None,
            max: Optional[float] = None, choices: Optional[tuple[str, ...]] = None, flag: Optional[str] = None,
            blender_name: Optional[str] = None, label: Optional[str] = None, unset: Optional[int] = None,
            default_text: Optional[str] = None, metavar: Optional[tuple[str, ...]] = None,
            textured: bool = False, choice_help: Optional[tuple[str, ...]] = None) -> Any:
    """A ReconSettings field with what every entry point needs to offer it.

    help: one sentence for the CLI help and the Blender tooltip. expose: (CLI, BLENDER), a subset, or
    ENGINE_ONLY. min / max: inclusive limits (checked by `validate`, Blender's property limits).
    choices: the allowed strings of a text setting (CLI choices, a Blender enum with upper-case ids).
    flag: the CLI flag when not --<name-with-dashes>. blender_name / label: the scene property's
    identifier (default: the field name, kept stable for saved .blend files) and its label.
    unset: for an Optional[int] whose None means "automatic", the Blender value that stands for
    None (e.g. 0). default_text: the CLI help's default when the default is not a plain value.
    methods: the reconstruction methods (METHODS, or STEREO_EVIDENCE_WEIGHTS) that read the setting.
    textured: read only when a textured result is made (a .glb / .obj, the batch's --vr, Bake Texture).
    choice_help: one sentence per choice (in the order of `choices`), the tooltips of Blender's enum items.
    """
    if choice_help is not None and (choices is None or len(choice_help) != len(choices)):
        raise ValueError("setting(choice_help=...): one sentence per choice")
    unknown = set(methods) - set(METHODS) - {STEREO_EVIDENCE_WEIGHTS}
    if unknown:
        raise ValueError(f"setting(methods=...): unknown methods {sorted(unknown)}")
    metadata = {"help": help, "expose": tuple(expose), "methods": tuple(methods), "min": min, "max": max, "choices": choices, "flag": flag,
                "blender_name": blender_name, "label": label, "unset": unset, "default_text": default_text,
                "metavar": metavar, "textured": textured, "choice_help": choice_help}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass
class ReconSettings:
    method: str = setting(
        "stereo", "how the room is reconstructed: 'stereo' = multi-view stereo depth fused into a TSDF (no network, "
        "the default: it beats the shipped weights); 'vortx' = the VoRTX network with the chosen weights",
        (CLI, BLENDER), choices=METHODS, label="Method")
    weights: Optional[str] = setting(
        None, "weights .safetensors file, or 'random' (seeded random network: tests the pipeline, meaningless mesh)",
        (CLI,), methods=("vortx",), default_text="the weights shipped with the extension")  # Blender: Weights source + file (reconstruct.py)
    voxel_size: float = setting(
        0.04, "finest voxel edge in metres; the coarser levels are 2x and 4x this (VoRTX was trained at 4 cm)",
        (CLI, BLENDER), min=0.005, max=0.5, label="Voxel Size")
    views: int = setting(
        60, "keyframes fused into each tile (more: better detail, more memory and time)",
        (CLI, BLENDER), methods=("vortx",), min=1, max=500, blender_name="view_count", label="Views per Tile")
    tile_size: int = setting(
        96, f"tile width and depth in fine voxels, a multiple of {COARSE_FACTOR} (smaller: less memory per step)",
        (CLI, BLENDER), methods=("vortx",), min=COARSE_FACTOR, max=512, label="Tile Size")
    tile_height: int = setting(48, "tile height in fine voxels (the training crop's height)", ENGINE_ONLY, methods=("vortx",))
    device: str = setting("cpu", "where the network runs: cpu, cuda or cuda:<index>", (CLI, BLENDER))
    seed: int = setting(
        0, "seed of the per-tile view sampling (and of random weights); the same seed gives the same mesh",
        (CLI, BLENDER), methods=("vortx",), min=0)
    keyframe_translation: float = setting(DEFAULT_KEYFRAME_TRANSLATION_M, "metres since the last kept keyframe", ENGINE_ONLY,
                                          min=0.0)
    keyframe_angle_deg: float = setting(DEFAULT_KEYFRAME_ANGLE_DEG, "optical-axis angle since the last kept keyframe",
                                        ENGINE_ONLY, min=0.0)
    frustum_depth: float = setting(
        4.0, "scene bounds = the camera frusta cut at this depth in metres (official: 4 m)",
        (CLI, BLENDER), min=0.1, max=100.0, label="Frustum Depth")
    # Where only the camera frusta say how large the space is (no sparse points, no depth), bounds larger
    # than this (metres, x/y/z) are clipped around the median camera centre, so a camera looking down a
    # corridor cannot blow the voxel grid up to city size. Surfaces the evidence shows are never cut.
    max_room_size: tuple[float, float, float] = setting(
        (20.0, 20.0, 6.0), "where nothing but the camera frusta says how large the space is, clip it to this box "
        "in metres around the median camera (surfaces seen in the photos are kept whole, however large)",
        (CLI, BLENDER), min=0.5, max=1000.0, metavar=("X", "Y", "Z"))
    # None = the size the weights were trained at (VortxConfig.image_long_side: 640 for the official model).
    image_long_side: Optional[int] = setting(
        None, "long side in pixels the photos are resized to for the network", (CLI, BLENDER), methods=("vortx",), min=32, max=4096,
        flag="--image-size", blender_name="image_size", label="Image Size", unset=0,
        default_text="the size the weights were trained at")
    feature_chunk: int = setting(
        4, "images per 2D CNN call (measured fastest on CPU, platform-notes section 4)", ENGINE_ONLY, methods=("vortx",), min=1)
    fusion_chunk: int = setting(
        2048, "voxels per fusion call: fusion memory is O(chunk x views^2)", ENGINE_ONLY, methods=("vortx",), min=1)
    fp16_features: bool = setting(
        True, "cache 2D features as fp16 on the CPU (halves the cache; official does this)", ENGINE_ONLY, methods=("vortx",))
    colour_views: int = setting(
        40, "keyframes (evenly spaced) that colour the mesh vertices; 0 leaves the mesh grey",
        (CLI, BLENDER), min=0, max=1000, label="Colour Views")

    # Multi-view stereo (engine/stereo), the 'stereo' method's depth maps.
    stereo_matcher: str = setting(
        StereoOptions.matcher, "how depth maps are matched: 'patchmatch' = a depth and a slanted plane per pixel "
        "(PatchMatch with per-pixel view selection and geometric consistency: right on slanted floors and walls, "
        "slower); 'fast' = fronto-parallel plane sweep (about 0.5 s per keyframe, crumpled surfaces)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), choices=STEREO_MATCHERS, flag="--stereo",
        label="Matcher", choice_help=(
            "Per-pixel slanted planes with view selection and geometric consistency: smooth walls and floors",
            "Fronto-parallel plane sweep: several times faster, crumpled surfaces"))
    stereo_image_size: int = setting(
        StereoOptions.long_side, "long side in pixels of the photos matched by stereo (larger: finer depth, ~4x the time per 2x)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=32, max=2048, label="Image Size")
    stereo_views: int = setting(
        StereoOptions.max_references, "keyframes that get a stereo depth map (evenly spaced when there are more)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=1, max=2000, label="Views")
    stereo_planes: int = setting(
        StereoOptions.planes, "depth hypotheses per pixel, uniform in inverse depth (a finer second sweep refines each pixel)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=8, max=512, label="Depth Planes")
    stereo_sources: int = setting(
        StereoOptions.sources, "photos each depth map is matched against (the best half of them vote at each pixel)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=1, max=16, label="Source Views")
    stereo_min_ncc: float = setting(
        StereoOptions.min_ncc, "minimum matching score (normalised cross-correlation) for a depth to be kept",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=-1.0, max=0.99, flag="--stereo-min-ncc", label="Min Score")
    stereo_consistency: int = setting(
        StereoOptions.consistency_views, "keep a depth only if this many other depth maps agree within 2 percent (0 = off; fusion already "
        "filters most outliers, and a strict check loses more surface than noise)",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), min=0, max=10, label="Consistency")

    sensor_depth: bool = setting(
        StereoOptions.sensor_depth, "use the depth maps a phone's LiDAR recorded with the photos (3D Scanner App, Stray "
        "Scanner, Record3D, Polycam exports) in place of stereo for the photos that have them: metric, right on plain "
        "walls and glossy floors, and minutes faster; off: stereo alone. Captures without sensor depth are unaffected",
        (CLI, BLENDER), methods=("stereo", STEREO_EVIDENCE_WEIGHTS), label="Sensor Depth")

    # The finishing stage (engine/finish): planes found, flattened and closed, unsupported pieces dropped.
    finish: str = setting(
        FINISH_ROOM, "how the mesh is finished for VR: 'room' = floor, ceiling and walls found, flattened onto their "
        "planes and closed where no photo saw through them (added faces marked with the 'added' attribute), pieces few "
        "photos support dropped, furniture kept; 'clean' = the same without adding faces; 'off' = the fused surface as "
        "it is", (CLI, BLENDER), choices=FINISH_MODES, label="Finish", choice_help=(
            "The fused surface as it is: every piece, crumpled walls, holes",
            "Pieces few photos support dropped, surface on the floor, ceiling and walls flattened onto them; nothing added",
            "As Clean, and the floor, ceiling and walls closed where no photo saw through them; added faces are marked"))

    # The textured result (engine/texture): GLB / OBJ files, Blender's Bake Texture, the VR preset.
    texture_size: int = setting(
        TextureOptions.texture_size, "side of the baked texture in texels: 4096 for desktop VR, 2048 for mobile "
        "headsets (one of " + ", ".join(map(str, TEXTURE_SIZES)) + ")", (CLI, BLENDER), min=min(TEXTURE_SIZES),
        max=max(TEXTURE_SIZES), label="Texture Size", textured=True)
    face_budget: int = setting(
        TextureOptions.face_budget, "a textured result is decimated to at most this many faces before the bake "
        "(0 = keep every face)", (CLI, BLENDER), min=0, max=10_000_000, label="Face Budget", textured=True)
    headset: str = setting(
        DEFAULT_PRESET, "the headset the textured result is for: caps the texture size and face budget and picks how the "
        "GLB stores texture (PNG or KTX2) and geometry (Draco); engine/texture/presets.py", (CLI, BLENDER),
        choices=PRESET_NAMES, label="Headset", textured=True,
        choice_help=tuple(f"{p.device}: up to {p.texture_size} px" + (f", {p.face_budget:,} faces" if p.face_budget else "")
                          + f", texture {p.texture_format}, geometry {p.geometry}" for p in PRESETS.values()))

    # Where the result is written: the engine always reconstructs in the world (output_frame.py).
    frame: str = setting(
        FRAME_WORLD, "coordinates of the result: 'world' = Z up, floor at z = 0, metres (as the engine reconstructs); "
        "'capture' = the coordinates and units of the capture's own camera poses (transforms.json, COLMAP), so the mesh "
        "lies over those cameras without alignment (refused when structure from motion made the poses). The similarity "
        "between the two is recorded both ways", (CLI, BLENDER), choices=FRAMES, blender_name="output_frame",
        label="Coordinates", choice_help=(
            "Z up, floor at 0, metres: the world VoRTX reconstructs in",
            "The coordinates and units the capture's own poses are given in (a NeRF transforms.json, a COLMAP model), "
            "so the cameras, points and mesh lie over the pipeline's own cameras; not for poses from Estimate Poses"))

    @property
    def texture_options(self) -> TextureOptions:
        """The bake's options: this run's texture size and face budget, the occlusion tolerance of its
        vertex colours (two voxels), the rest at their defaults."""
        return with_preset(TextureOptions(texture_size=self.texture_size, face_budget=self.face_budget,
                                          occlusion_tolerance=2 * self.voxel_size), self.headset)

    @property
    def colour(self) -> bool:
        """Colour the vertices from the photos (colour_views 0 = a grey mesh)."""
        return self.colour_views > 0

    @property
    def level_voxel_sizes(self) -> tuple[float, float, float]:
        return level_voxel_sizes(self.voxel_size)

    def validate(self) -> None:
        """Raise VortxError naming the setting at fault."""
        if not self.voxel_size > 0:
            raise VortxError(f"voxel size must be positive, got {self.voxel_size}")
        if self.views < 1:
            raise VortxError(f"views per tile must be at least 1, got {self.views}")
        for name in ("tile_size", "tile_height"):
            value = getattr(self, name)
            # Tiles must hold whole coarse voxels, so the coarse grid and every tile stay aligned.
            if value < COARSE_FACTOR or value % COARSE_FACTOR:
                raise VortxError(f"{name.replace('_', ' ')} must be a positive multiple of {COARSE_FACTOR} voxels, got {value}")
        if self.device not in ("cpu", "cuda") and not self.device.startswith("cuda:"):
            raise VortxError(f"device must be 'cpu' or 'cuda', got {self.device!r}")
        if self.image_long_side is not None and self.image_long_side < 32:
            raise VortxError(f"image long side must be at least 32 pixels, got {self.image_long_side}")
        if self.feature_chunk < 1 or self.fusion_chunk < 1:
            raise VortxError("feature and fusion chunk sizes must be at least 1")
        if self.keyframe_translation < 0 or self.keyframe_angle_deg < 0:
            raise VortxError("keyframe thresholds cannot be negative")
        if min(self.max_room_size) <= 0 or self.frustum_depth <= 0:
            raise VortxError("maximum room size and frustum depth must be positive")
        for f in fields(self):  # the limits and choices every entry point offers
            _check_limits(f, getattr(self, f.name))
        self.texture_options.validate()

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["max_room_size"] = list(self.max_room_size)
        return data


# --- the fields as entry points see them ------------------------------------------------------------

def setting_fields(expose: Optional[str] = None) -> list[Field]:
    """ReconSettings' fields in declaration order; only those offered to `expose` (CLI / BLENDER) if given."""
    return [f for f in fields(ReconSettings) if expose is None or expose in f.metadata["expose"]]


def value_type(f: Field) -> type:
    """The field's value type with Optional removed: float, int, bool, str or tuple."""
    hint = typing.get_type_hints(ReconSettings)[f.name]
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) is typing.Union:
        hint = args[0]
    return typing.get_origin(hint) or hint


def tuple_length(f: Field) -> int:
    return len(typing.get_args(typing.get_type_hints(ReconSettings)[f.name]))


def field_default(f: Field) -> Any:
    return f.default_factory() if f.default_factory is not MISSING else f.default


def setting_label(f: Field) -> str:
    return f.metadata["label"] or f.name.replace("_", " ").capitalize()


def _check_limits(f: Field, value: Any) -> None:
    meta = f.metadata
    if value is None:
        return
    if meta["choices"] is not None and value not in meta["choices"]:
        raise VortxError(f"{f.name.replace('_', ' ')} must be one of {', '.join(meta['choices'])}, got {value!r}")
    values = value if isinstance(value, tuple) else (value,)
    for v in values:
        if meta["min"] is not None and v < meta["min"] or meta["max"] is not None and v > meta["max"]:
            low = "" if meta["min"] is None else f"at least {meta['min']:g}"
            high = "" if meta["max"] is None else f"at most {meta['max']:g}"
            raise VortxError(f"{f.name.replace('_', ' ')} must be {' and '.join(t for t in (low, high) if t)}, got {value}")


def cli_flag(f: Field) -> str:
    return f.metadata["flag"] or "--" + f.name.replace("_", "-")


def add_setting_arguments(parser: argparse.ArgumentParser, only: Optional[tuple[str, ...]] = None) -> None:
    """One flag per CLI field of ReconSettings (or of the fields named in `only`), with its help,
    default, type, choices and nargs."""
    for f in setting_fields(CLI):
        if only is not None and f.name not in only:
            continue
        meta, kind, default = f.metadata, value_type(f), field_default(f)
        shown = meta["default_text"] or "%(default)s"
        help_text = meta["help"].replace("%", "%%")  # argparse formats help with %
        options: dict[str, Any] = {"dest": f.name, "default": default, "help": f"{help_text} (default: {shown})"}
        if kind is bool:
            options["action"] = argparse.BooleanOptionalAction
        elif kind is tuple:
            options.update(type=float, nargs=tuple_length(f), metavar=meta["metavar"])
            options["default"] = list(default)
        else:
            options["type"] = kind
            if meta["choices"] is not None:
                options["choices"] = meta["choices"]  # argparse shows them as {a,b}
            else:
                options["metavar"] = cli_flag(f)[2:].upper().replace("-", "_")
        options["action"] = _recording_action(options.get("action", "store"))
        parser.add_argument(cli_flag(f), **options)


GIVEN_SETTINGS = "given_settings"  # the Namespace attribute listing the setting flags on the command line


def _recording_action(action: Any) -> type:
    """`action` (an argparse action class or "store") that also notes its field in the namespace's
    GIVEN_SETTINGS, so an explicit flag can be told from a default (even one given at its default value)."""
    base = argparse._StoreAction if action == "store" else action

    class Recorded(base):  # type: ignore[misc, valid-type]
        def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                     option_string: Optional[str] = None) -> None:
            super().__call__(parser, namespace, values, option_string)
            given = set(getattr(namespace, GIVEN_SETTINGS, ()))
            setattr(namespace, GIVEN_SETTINGS, given | {self.dest})

    return Recorded


def given_settings(args: argparse.Namespace) -> set[str]:
    """The ReconSettings fields whose flags were on the command line (see `add_setting_arguments`)."""
    return set(getattr(args, GIVEN_SETTINGS, ()))


def methods_using(f: Field, stereo_weights: bool = False) -> tuple[str, ...]:
    """The methods that read field `f`; with `stereo_weights` (VoRTX weights that take stereo depth)
    the stereo knobs count as read by 'vortx' too."""
    methods = f.metadata["methods"]
    extra = ("vortx",) if stereo_weights and STEREO_EVIDENCE_WEIGHTS in methods else ()
    return tuple(m for m in METHODS if m in methods or m in extra)


def refuse_unused_settings(method: str, given: set[str], stereo_weights: bool = False,
                           name_of: Any = None) -> None:
    """Raise VortxError when a setting in `given` (field names the user set) is not read by `method`,
    naming the option, the method that uses it and what to do: an option is never silently ignored.

    stereo_weights: the chosen VoRTX weights take stereo depth (then VoRTX reads the stereo knobs).
    name_of: how the entry point names a field (default: its CLI flag).
    """
    name_of = name_of or cli_flag
    unused = [f for f in setting_fields() if f.name in given and method not in methods_using(f, stereo_weights)]
    if not unused:
        return
    reasons = []
    for f in unused:
        users = methods_using(f)
        where = f"--method {' / '.join(users)}" if users else "no method"
        if STEREO_EVIDENCE_WEIGHTS in f.metadata["methods"] and method == "vortx":
            where += " (and VoRTX weights that take stereo depth; these weights do not)"
        reasons.append(f"{name_of(f)} is used only by {where}")
    raise VortxError(f"--method {method} does not use {', '.join(name_of(f) for f in unused)}: "
                     f"{'; '.join(reasons)}. Leave {'it' if len(unused) == 1 else 'them'} out, or choose the method "
                     f"that uses {'it' if len(unused) == 1 else 'them'}")


def settings_from_arguments(args: argparse.Namespace, **overrides: Any) -> ReconSettings:
    """ReconSettings from the flags `add_setting_arguments` made (engine-only fields keep their defaults)."""
    values = {f.name: getattr(args, f.name) for f in setting_fields(CLI)}
    for f in setting_fields(CLI):
        if value_type(f) is tuple:
            values[f.name] = tuple(values[f.name])
    values.update(overrides)
    return ReconSettings(**values)


def refuse_untextured_settings(given: set[str], textured: bool, how: str) -> None:
    """Raise VortxError when a texture setting in `given` is set for a run that makes no textured result;
    `how` says what makes one at this entry point (e.g. "--out room.glb or room.obj")."""
    unused = [cli_flag(f) for f in setting_fields() if f.name in given and f.metadata["textured"]]
    if unused and not textured:
        raise VortxError(f"{', '.join(unused)} {'is' if len(unused) == 1 else 'are'} used only by a textured result "
                         f"({how}), and this run makes none. Leave {'it' if len(unused) == 1 else 'them'} out, "
                         "or ask for a textured result")


def refuse_ignored_settings(settings: ReconSettings, given: set[str], name_of: Any = None) -> None:
    """`refuse_unused_settings` for a run's settings: every setting named in `given` (set by the user)
    must be read by `settings.method`. VoRTX reads the stereo knobs only when its weights take stereo
    depth, so only then (a stereo knob given to vortx) is the weights file's header read."""
    stereo_knobs = {f.name for f in setting_fields() if STEREO_EVIDENCE_WEIGHTS in f.metadata["methods"]}
    stereo_weights = False
    if settings.method == "vortx" and given & stereo_knobs:
        from .network import weights_take_stereo  # defers torch: only when it matters

        stereo_weights = weights_take_stereo(settings.weights)
    refuse_unused_settings(settings.method, given, stereo_weights, name_of)
