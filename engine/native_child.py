"""The child side of native_worker.py, run by file path: `python native_child.py JOB_FOLDER`.

Started by path, not as a module, for the reason sfm_worker.py gives: inside Blender the engine is
`bl_ext.<repo>.vortx.engine`, which a fresh interpreter cannot import. So this file imports only the
standard library and numpy at the top; it puts the engine's parent folder first on sys.path, imports
the job's function from its module (engine functions as `engine.<...>`), and calls it.

JOB_FOLDER/job.json: {"step", "module", "function", "engine_parent", "params"}; JOB_FOLDER/in.npz:
the array arguments. The function is called with the arrays and params as keyword arguments and
returns a dict of arrays and numbers, written to JOB_FOLDER/out.npz. A Python exception is written
to JOB_FOLDER/error.json ({"class", "message", "user_error", "traceback"}) and the exit status is 1;
a native crash leaves neither file and the parent reads the signal from the exit status.
"""

from __future__ import annotations

import faulthandler
import importlib
import json
import sys
import traceback
from pathlib import Path

import numpy as np


def _is_user_error(error: BaseException) -> bool:
    # engine.errors.VortxError and its subclasses, matched by name: this file cannot import the engine
    # before the job says where it is, and the parent re-raises it as its own class of that name.
    return any(cls.__name__ == "VortxError" for cls in type(error).__mro__)


def run(folder: Path) -> int:
    job = json.loads((folder / "job.json").read_text(encoding="utf-8"))
    try:
        sys.path.insert(0, job["engine_parent"])
        target = importlib.import_module(job["module"])
        for name in job["function"].split("."):
            target = getattr(target, name)
        with np.load(folder / "in.npz", allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
        result = target(**arrays, **job["params"])
        np.savez(folder / "out.partial.npz", **{key: np.asarray(value) for key, value in result.items()})
        (folder / "out.partial.npz").replace(folder / "out.npz")  # whole or absent, never half written
        return 0
    except Exception as error:  # reported to the parent, which raises it there
        (folder / "error.json").write_text(json.dumps({
            "class": type(error).__name__, "message": str(error), "user_error": _is_user_error(error),
            "traceback": traceback.format_exc()}), encoding="utf-8")
        return 1


if __name__ == "__main__":
    # A segfault or abort still prints where Python was (into the log the parent quotes).
    faulthandler.enable()
    sys.exit(run(Path(sys.argv[1])))
