"""`python -m engine convert-official vortx.ckpt --out official.safetensors`

Maps the authors' PyTorch Lightning checkpoint onto `VortxNet(VortxConfig.official())`. Our module
names are the official ones, so the mapping is: take `state_dict`, drop the `vortx.` prefix, and
reorder the columns of the upsampler's constant offset tables from the official `[x, y, z, batch]`
to our `[batch, x, y, z]`. torchsparse kernels are (K, Cin, Cout) in both and copy unchanged.

The checkpoint is read with `torch.load(weights_only=True)`: only tensors, containers and
primitives are unpickled. A Lightning 1.5 checkpoint normally passes; if the file carries other
pickled objects (callbacks, custom hyper-parameter classes), it is refused rather than executed -
see the error message for how to re-save just the weights.
"""

from __future__ import annotations

import argparse
import pickle
from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import WeightsError
from .config import VortxConfig
from .vortx import VortxNet
from .weights import load_state_into, save_weights

PREFIX = "vortx."
# Official column order [x, y, z, batch] -> ours [batch, x, y, z].
UPSAMPLER_COLUMNS = [3, 0, 1, 2]
UPSAMPLER_KEYS = ("upsampler.upsample_offsets", "upsampler.upsample_mul")

RESAVE_HINT = (
    "In an environment you trust, re-save only the weights and convert that file:\n"
    "  python -c \"import torch; c = torch.load('vortx.ckpt', map_location='cpu', weights_only=False); "
    "torch.save({'state_dict': c['state_dict']}, 'vortx-weights.ckpt')\""
)


@dataclass
class ConversionReport:
    source: Path
    output: Path
    num_tensors: int
    num_parameters: int
    config: VortxConfig


def read_official_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """The checkpoint's `state_dict` with the `vortx.` prefix removed."""
    if not path.is_file():
        raise WeightsError(f"checkpoint {path} does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        raise WeightsError(
            f"{path} contains pickled objects other than tensors, so torch.load(weights_only=True) "
            f"refused it ({str(error).splitlines()[0]}). It is not unpickled further because that could "
            f"run arbitrary code.\n{RESAVE_HINT}"
        ) from error
    except (RuntimeError, OSError, EOFError) as error:
        raise WeightsError(f"{path} is not a readable PyTorch checkpoint ({error})") from error
    state = checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise WeightsError(f"{path} has no `state_dict` of tensors; is it the VoRTX Lightning checkpoint?")
    prefixed = [k for k in state if k.startswith(PREFIX)]
    if not prefixed:
        raise WeightsError(f"{path}: no key starts with '{PREFIX}'; is it the VoRTX Lightning checkpoint?")
    return {k[len(PREFIX):]: v for k, v in state.items() if k.startswith(PREFIX)}


def official_to_engine(state: dict[str, torch.Tensor], model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """Official names/layouts -> `model`'s state dict (same names; upsampler columns reordered).

    Floating tensors become float32 (Lightning AMP checkpoints may mix dtypes); integer buffers keep
    their dtype. The upsampler tables are constants of the architecture, so they must equal ours.
    """
    own = model.state_dict()
    converted = {}
    for key, value in state.items():
        if key in UPSAMPLER_KEYS:
            value = value[..., UPSAMPLER_COLUMNS]
            if key in own and not torch.equal(value.to(own[key].dtype), own[key]):
                raise WeightsError(
                    f"checkpoint tensor vortx.{key} = {value.tolist()} is not VoRTX's constant child-offset "
                    "table; this is not the official VoRTX architecture"
                )
        target = own.get(key)
        if target is not None:
            value = value.to(target.dtype)
        elif value.is_floating_point():
            value = value.float()
        converted[key] = value.contiguous()
    return converted


def convert_checkpoint(source: Path, output: Path) -> ConversionReport:
    config = VortxConfig.official()
    model = VortxNet(config)
    state = official_to_engine(read_official_state_dict(source), model)
    load_state_into(model, state, f"{source} (official checkpoint)")
    save_weights(model, config, output)
    return ConversionReport(
        source=source,
        output=output,
        num_tensors=len(state),
        num_parameters=sum(p.numel() for p in model.parameters()),
        config=config,
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="the authors' VoRTX Lightning checkpoint (.ckpt)")
    parser.add_argument("--out", type=Path, required=True, help="output .safetensors (config written beside it as .json)")


def run(args: argparse.Namespace) -> int:
    report = convert_checkpoint(args.checkpoint, args.out)
    print(
        f"converted {report.num_tensors} tensors ({report.num_parameters / 1e6:.2f} M parameters) "
        f"from {report.source} to {report.output} (+ {report.output.with_suffix('.json').name}); "
        f"config: backbone={report.config.backbone}, use_proj_occ={report.config.use_proj_occ}"
    )
    return 0
