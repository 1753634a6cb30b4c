"""Which network a reconstruction runs: the default weights, a weights file, or a seeded random init.

"random" exists so the whole pipeline runs end to end before trained weights do (tests, benchmark);
its meshes are meaningless. The default weights' location is owned by engine.model.weights.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import torch

from ..errors import WeightsError

RANDOM = "random"


def default_weights_path() -> Optional[Path]:
    """engine.model.weights.DEFAULT_WEIGHTS, or None while that package defines no default."""
    from ..model import weights

    value = getattr(weights, "DEFAULT_WEIGHTS", None)
    return None if value is None else Path(value)


def load_network(weights: Optional[str], seed: int, device: torch.device):
    """-> (VortxNet in eval mode on `device`, VortxConfig, a label for the sidecar)."""
    from ..model.config import VortxConfig
    from ..model.weights import load_weights

    if weights == RANDOM:
        from ..model.vortx import VortxNet

        # fork_rng: seeding here must not change the caller's global random stream.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            config = VortxConfig()
            model = VortxNet(config)
        return model.to(device).eval(), config, f"random (seed {seed})"
    if weights is None:
        path = default_weights_path()
        if path is None or not path.is_file():
            where = f" (expected at {path})" if path is not None else ""
            raise WeightsError(
                f"the default VoRTX weights are not installed{where}. Pass a weights file "
                "(--weights PATH.safetensors), convert the official checkpoint with "
                "`python -m engine convert-official`, or use --weights random to test the pipeline"
            )
    else:
        path = Path(weights)
    model, config = load_weights(path, device)
    return model, config, str(path)
