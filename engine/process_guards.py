"""Guards for running torch in the same process as Blender.

PyPI's Linux torch pulls in Triton, whose `libtriton` bundles its own LLVM. Once Blender has
rendered with Workbench or EEVEE in a process, Mesa's llvmpipe (another LLVM) is loaded, and
importing Triton afterwards crashes the whole process with a segmentation fault (seen when an
optimizer was created after a Workbench render: `torch.optim` imports `torch._dynamo`, which
probes for Triton). The engine never needs Triton (no torch.compile), so processes that host
Blender mark it unavailable: torch then behaves exactly as when Triton is not installed.
"""

from __future__ import annotations

import sys


def keep_triton_out() -> None:
    """Make `import triton` fail cleanly (ImportError) in this process. Call before torch is used."""
    if "triton" not in sys.modules:
        sys.modules["triton"] = None  # type: ignore[assignment]
