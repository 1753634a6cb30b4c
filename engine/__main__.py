"""`python -m engine COMMAND ...`: the command-line interface.

Each command lives in the package that owns it, as a module exposing
`add_arguments(parser)` and `run(args) -> int`. Modules are imported only when their command
runs, so `python -m engine info` does not pay for importing torch.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .errors import VortxError

COMMANDS: dict[str, tuple[str, str]] = {
    "info": (".capture.cli_info", "describe a capture: format, frames, resolution, poses"),
    "poses": (".poses.cli", "estimate camera poses with pycolmap and write the posed capture"),
    "reconstruct": (".recon.cli", "reconstruct a mesh from a capture"),
    "texture": (".texture_command", "bake a texture from the photos for a reconstructed mesh (GLB or OBJ)"),
    "convert-official": (".model.convert_official", "convert the authors' VoRTX checkpoint to safetensors"),
    "bench": (".bench", "benchmark the pipeline and its parts"),
    "synth": (".data.cli", "render synthetic rooms with Blender (ScanNet layout + ground truth)"),
    "train": (".train.cli", "train VoRTX from a config file"),
    "eval": (".eval.cli", "evaluate a predicted mesh against ground truth (Atlas and surface metrics)"),
    "eval-depth": (".eval.stereo_depth", "stereo depth maps against the rooms' true depth (errors, normals, confidence)"),
    "eval-scale": (".eval.scale_eval", "metric scale from the photos alone against rooms' true poses"),
    "eval-weights": (".eval.heldout", "reconstruct held-out rendered rooms with trained weights and score them"),
    "eval-texture": (".eval.texture_cli", "texture vs vertex colours from held-out photos (PSNR, SSIM)"),
    "eval-sensor": (".eval.sensor_heldout", "a phone capture's result against its own held-out LiDAR depth"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m engine", description="VoRTX for Blender engine")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, add_help=False)
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        parser.print_help()
        return 0 if not argv or argv[0] in ("-h", "--help") else 2

    module_name, help_text = COMMANDS[argv[0]]
    module = importlib.import_module(module_name, package=__package__)
    command_parser = argparse.ArgumentParser(prog=f"python -m engine {argv[0]}", description=help_text)
    module.add_arguments(command_parser)
    args = command_parser.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except VortxError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("cancelled", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
