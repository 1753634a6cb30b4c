"""Weights files: safetensors tensors + the `VortxConfig` as JSON. Never a pickle.

The config is stored twice: in the safetensors header metadata (authoritative; the file is
self-contained) and in a sidecar `<name>.json` for people to read. The sidecar is only used when
the header has no config (a file written by another tool).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file, save_file

from ..errors import WeightsError
from .config import VortxConfig
from .vortx import VortxNet

# The weights the extension ships with (trained by engine.train); absent until a training run
# produces them. The path is relative to the extension root, so it holds from the CLI and Blender.
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[2] / "weights" / "vortx-default.safetensors"

CONFIG_KEY = "vortx_config"
FORMAT_KEY = "format"
FORMAT = "vortx-blender-weights/1"


def sidecar_path(path: str | Path) -> Path:
    return Path(path).with_suffix(".json")


def save_weights(model: torch.nn.Module, config: VortxConfig, path: str | Path) -> Path:
    """Write model.state_dict() to `path` (.safetensors) and the config to the header and a sidecar."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    save_file(state, str(path), metadata={FORMAT_KEY: FORMAT, CONFIG_KEY: config.to_json()})
    sidecar_path(path).write_text(config.to_json() + "\n")
    return path


def read_config(path: str | Path) -> VortxConfig:
    """The config of a weights file (header metadata, else the sidecar JSON)."""
    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"weights file {path} does not exist; pass an existing .safetensors file")
    try:
        with safe_open(str(path), framework="pt") as f:
            metadata = f.metadata() or {}
    except (SafetensorError, OSError) as error:
        raise WeightsError(f"{path} is not a readable safetensors file ({error})") from error
    text = metadata.get(CONFIG_KEY)
    source = f"the header of {path}"
    if text is None:
        sidecar = sidecar_path(path)
        if not sidecar.is_file():
            raise WeightsError(f"{path} has no model config in its header and no {sidecar.name} beside it")
        text, source = sidecar.read_text(), str(sidecar)
    try:
        return VortxConfig.from_dict(json.loads(text))
    except (ValueError, TypeError) as error:
        raise WeightsError(f"invalid model config in {source}: {error}") from error


def load_state_into(model: torch.nn.Module, state: dict[str, torch.Tensor], source: str) -> None:
    """Strict load with a message that names the file and the first offending keys."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    wrong = sorted(k for k in set(own) & set(state) if own[k].shape != state[k].shape)
    if missing or unexpected or wrong:
        details = []
        if missing:
            details.append(f"{len(missing)} missing (e.g. {missing[:3]})")
        if unexpected:
            details.append(f"{len(unexpected)} unexpected (e.g. {unexpected[:3]})")
        if wrong:
            k = wrong[0]
            details.append(f"{len(wrong)} with wrong shapes (e.g. {k}: file {tuple(state[k].shape)}, model {tuple(own[k].shape)})")
        raise WeightsError(f"{source} does not match the model built from its config: " + "; ".join(details))
    model.load_state_dict(state, strict=True)


def load_weights(path: str | Path, device: str | torch.device = "cpu"):
    """-> (VortxNet in eval mode on `device`, VortxConfig)."""

    config = read_config(path)
    state = load_file(str(path), device="cpu")
    model = VortxNet(config)
    load_state_into(model, state, str(path))
    return model.to(device).eval(), config


def ship_weights(src: Path, dst: Path, half: bool = True, config_changes: dict | None = None) -> Path:
    """Copy trained weights to the shipped location (safetensors + JSON sidecar), optionally with
    floating-point tensors stored as float16 (half the size; they load back into float32) and
    inference-only config fields changed (e.g. {"sparse_norm_statistics": "scene"})."""
    config = dataclasses.replace(read_config(src), **(config_changes or {}))
    tensors = {}
    with safe_open(str(src), framework="pt") as f:
        for key in f.keys():
            t = f.get_tensor(key)
            tensors[key] = t.half() if half and t.is_floating_point() else t
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(dst), metadata={FORMAT_KEY: FORMAT, CONFIG_KEY: config.to_json()})
    sidecar_path(dst).write_text(config.to_json() + "\n")
    return dst
