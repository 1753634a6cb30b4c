"""Photos of a room -> a .blend with the capture cameras and the reconstructed mesh, without the UI.

    blender --background --python-exit-code 1 --python scripts/vortx_batch.py -- CAPTURE --out scene.blend [options]
    .venv/bin/python scripts/vortx_batch.py CAPTURE --out scene.blend [options]     (the bpy module)
    .venv/bin/python scripts/vortx_batch.py CAPTURE_A CAPTURE_B ... --out OUT_FOLDER [--export .glb]
    .venv/bin/python scripts/vortx_batch.py FOLDER_OF_CAPTURES --out OUT_FOLDER

Runs the extension's own operators, exactly as a user would click them: Import Capture, Estimate
Poses (only when no frame has a pose), Refine Poses (with --refine-poses), Reconstruct (at --quality
preview|standard|high, the presets of Blender's Reconstruction panel; explicit flags win), Bake Texture
(with --vr: the VR preset, a mesh decimated to --face-budget with a --texture-size photo texture);
then saves the .blend and, with --export, writes the mesh as GLB, PLY or OBJ (metres, Z up for
PLY/OBJ; glTF is Y-up by specification and converts back on import; with --vr, GLB/glTF and OBJ carry
the texture; with --frame capture, the scene and the mesh are in the capture's own coordinates). Uses the `vortx` extension this Blender has
installed; otherwise this checkout is mounted as a temporary local extension repository
(scripts/_extension_dev.py, as the tests do).

One capture and `--out x.blend`: writes x.blend, the mesh at --export's path, and the report
x.report.json. Several captures, or one folder whose sub-folders are captures: `--out` is a folder
and each capture NAME gives NAME.blend, NAME.report.json and, with `--export .glb` (only the
suffix counts), NAME.glb there. A failed capture does not stop the others.

The report (JSON, one per capture, also for a failed one) says: the capture and its format, frames
loaded / posed / used and the photos skipped with the warning giving the reasons, where the poses
came from (given, refined, structure from motion) and the scale (source and how it was found),
seconds per step, mesh size, the texture bake's numbers (with --vr), every warning, and the error with
the step it happened in.

With --ray ADDRESS (or --ray local), each capture runs as a task on a Ray cluster, in a process of
its own as above, the memory its capture needs declared, a failed one run once more
(engine/batch/ray_cluster.py); the reports are the same, with where it ran under "cluster".

Prints one line per finished stage; on failure prints `error: <reason>` and exits with status 1
(after finishing the other captures; 2 for bad arguments), also under `blender --background`
(sys.exit ends Blender with that status; --python-exit-code covers anything that escapes). The
.blend is saved under a temporary name and renamed at the very end, so a failed capture leaves none.

This script only parses the command line and loads the extension: the batch itself is
engine/batch/ (flags, output plan, report, the loop, Ray) and vortx_blender/batch.py (one capture
through the operators).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Optional, Sequence

sys.path.insert(0, str(Path(__file__).resolve().parent))  # Blender does not put the script's folder on sys.path
from _extension_dev import ExtensionLoadError, vortx_extension  # noqa: E402

# The command line is read with this checkout's engine (plain dataclasses, no torch, no Blender)
# before the extension loads, so a bad flag is refused at once (status 2).
sys.path.insert(1, str(Path(__file__).resolve().parent.parent))
from engine.batch.arguments import parse_arguments, script_arguments  # noqa: E402
from engine.batch.plan import plan_jobs  # noqa: E402
from engine.batch.runner import run_jobs  # noqa: E402


def main(argv: Optional[Sequence[str]] = None) -> int:
    arguments = script_arguments(sys.argv if argv is None else argv)
    args = parse_arguments(arguments)
    if args.single and not args.captures[0].exists():  # no need to start the extension for that
        return run_jobs(args, plan_jobs(args, args.captures), None)
    try:
        import bpy  # noqa: F401  (defers bpy: Blender's own, or the bpy module under plain python)

        with vortx_extension() as addon:
            return importlib.import_module(f"{addon.__name__}.vortx_blender.batch").run_command_line(arguments, Path(__file__))
    except ExtensionLoadError as error:
        return run_jobs(args, plan_jobs(args, args.captures), None, load_error=str(error))


if __name__ == "__main__":
    sys.exit(main())
