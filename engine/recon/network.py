"""Which network a reconstruction runs: the default weights, a weights file, or a seeded random init.

"random" exists so the whole pipeline runs end to end before trained weights do (tests, benchmark);
its meshes are meaningless. The default weights' location is owned by engine.model.weights
(DEFAULT_WEIGHTS), read at call time so there is one place that defines it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import torch

from ..errors import WeightsError
from ..model import weights as model_weights
from ..model.config import VortxConfig
from ..model.vortx import VortxNet

RANDOM = "random"


def load_network(weights: Optional[str], seed: int, device: torch.device) -> tuple[VortxNet, VortxConfig, str]:
    """-> (VortxNet in eval mode on `device`, its VortxConfig, a label for the sidecar).

    weights: None = the default weights, "random" = VortxNet(VortxConfig()) initialised from `seed`,
    else a .safetensors path. Raises WeightsError naming the file and what to do.
    """
    if weights == RANDOM:
        # fork_rng: seeding here must not change the caller's global random stream.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            config = VortxConfig()
            model = VortxNet(config)
        return model.to(device).eval(), config, f"random (seed {seed})"
    if weights is None:
        path = Path(model_weights.DEFAULT_WEIGHTS)
        if not path.is_file():
            raise WeightsError(
                f"the default VoRTX weights are not installed (expected at {path}). Pass a weights file "
                "(--weights PATH.safetensors), convert the official checkpoint with "
                "`python -m engine convert-official`, or use --weights random to test the pipeline"
            )
    else:
        path = Path(weights)
    model, config = model_weights.load_weights(path, device)
    return model, config, str(path)


def weights_take_stereo(weights: Optional[str]) -> bool:
    """True when the network `weights` (as in `load_network`) takes stereo depth as an input, read from
    the file's header only; False when the default weights are not installed (loading says so later)."""
    if weights == RANDOM:
        return VortxConfig().stereo_evidence is not None
    path = Path(model_weights.DEFAULT_WEIGHTS) if weights is None else Path(weights)
    if weights is None and not path.is_file():
        return False
    return model_weights.read_config(path).stereo_evidence is not None

