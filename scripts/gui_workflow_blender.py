"""The whole Blender workflow in a real, windowed Blender, driven through the add-on's operators and
panels as a user drives them; runs inside Blender (`blender --python scripts/gui_workflow_blender.py
-- --photos DIR --out DIR`, or --phone-export DIR for the phone-capture variant, devtools/gui_workflow/
phone.py), started by scripts/gui_workflow.py under Xvfb, which copies devtools/ beside this script's
folder as in a checkout.

The steps, checks and screenshots: devtools/gui_workflow/ (its __init__ describes the run). The
outcome is written to <out>/report.json; Blender then quits.
"""

import argparse
import sys
import traceback
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the checkout: Blender does not add it
from devtools.gui_workflow.report import CheckFailed, WorkflowReport  # noqa: E402
from devtools.gui_workflow.phone import phone_workflow  # noqa: E402
from devtools.gui_workflow.steps import workflow  # noqa: E402


def parse_args() -> argparse.Namespace:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser()
    choice = parser.add_mutually_exclusive_group(required=True)
    choice.add_argument("--photos", type=Path)
    choice.add_argument("--phone-export", type=Path)
    parser.add_argument("--quality", help="the phone variant's Quality (default: the panel's)")
    parser.add_argument("--out", type=Path, required=True)
    return parser.parse_args(argv)


ARGS = parse_args()
ARGS.out.mkdir(parents=True, exist_ok=True)
REPORT = WorkflowReport(ARGS.out, bpy.app.version_string, sys.version.split()[0])
STEPS = phone_workflow(ARGS.phone_export, REPORT, ARGS.quality) if ARGS.phone_export else workflow(ARGS.photos, REPORT)


def finish(ok: bool, error: str = "") -> None:
    REPORT.finish(ok, error)
    bpy.ops.wm.quit_blender()


def tick():
    """One timer tick: the workflow's next step; the seconds until the next tick, or None at the end."""
    try:
        return next(STEPS)
    except StopIteration:
        finish(True)
    except CheckFailed as failed:
        finish(False, f"check failed: {failed}")
    except Exception as error:  # a bug in the add-on or here: the report keeps the traceback
        finish(False, "".join(traceback.format_exception(error))[-3000:])
    return None


bpy.app.timers.register(tick, first_interval=1.0)
