"""Which engine modules may import which: the dependency directions that keep one home per concept.

Read from the source by tests/fixtures_import_graph.py (every import counts: module level, inside
functions, under TYPE_CHECKING), so a lazy import cannot hide a cycle.
- engine/stereo (plane-sweep depth, fusion internals) sits below engine/recon (the methods built on
  it): stereo never imports recon. Photo resizing lives in engine/capture/images.py for both.
- The reconstruction dispatch (recon/driver.py) imports the stereo method (recon/stereo_fusion.py),
  never the other way round; what both need (the stage timer, vertex colouring) sits below them.
- Vertex colouring (recon/colour.py) and the texture bake (texture/) share the photo lookups
  (engine/photo_sampling.py) and the mesh helpers (engine/meshops.py), which import neither; texture
  never imports recon: its command line is engine/texture_command.py, an entry point above both, and
  the sidecar's place both commands use is engine/sidecar.py, below both. The reconstruction settings
  (recon/settings.py) read the texture options and presets: settings sits above texture/options.py and
  texture/presets.py, which import no recon module.
- A synthetic room's description (data/room.py) sits below its camera path (data/trajectory.py); the
  walking loop both need is data/path_loop.py.
- The network's input/output dataclasses (model/outputs.py, StereoEvidence among them) sit below the
  stereo-evidence features (model/stereo_evidence.py).
- Reading a capture (engine/capture) sits below everything built on captures (poses, reconstruction,
  finishing, ...): it imports only engine/geometry, engine/errors and engine/jobs, and engine/geometry
  only engine/errors. What a loader and the pose estimation both need lives in engine/capture (the
  Record3D loader levels its world by the photos' vertical lines, capture/vertical_lines.py, which
  the SfM alignment in poses/gravity.py uses too).
"""

from __future__ import annotations

import pytest

from fixtures_import_graph import GRAPH

MODULES = sorted(m for m in GRAPH if m == "engine" or m.startswith("engine."))


def imported_modules(name: str) -> set[str]:
    """The engine modules and packages `name` imports anywhere in its file."""
    return {m for m in GRAPH[name] if m.startswith("engine")}


def test_the_parser_sees_relative_lazy_and_type_checking_imports():
    # The checks below are only as good as this reading of the source: pin it on known imports.
    assert "engine.capture.images" in imported_modules("engine.stereo.depth_maps")
    assert "engine.recon.stereo_fusion" in imported_modules("engine.recon.driver")  # `from . import stereo_fusion`
    assert "engine.recon.driver" in imported_modules("engine.recon")  # lazy, inside __getattr__
    assert "engine.recon.plan" in imported_modules("engine.recon.colour")  # under TYPE_CHECKING
    assert "engine.model.outputs" in imported_modules("engine.model.stereo_evidence")


def test_stereo_never_imports_recon():
    stereo = [m for m in MODULES if m == "engine.stereo" or m.startswith("engine.stereo.")]
    assert len(stereo) > 3
    offending = {m: sorted(i for i in imported_modules(m) if i == "engine.recon" or i.startswith("engine.recon."))
                 for m in stereo}
    assert not {m: i for m, i in offending.items() if i}, \
        "engine/stereo must not import engine/recon: move what both need below them (engine/capture, engine/geometry)"


@pytest.mark.parametrize("upper, lower", [
    ("engine.recon.driver", "engine.recon.stereo_fusion"),
    ("engine.model.stereo_evidence", "engine.model.outputs"),
    ("engine.data.trajectory", "engine.data.room"),  # the walking loop both need: data/path_loop.py
])
def test_dependency_goes_one_way(upper, lower):
    assert lower in imported_modules(upper)
    assert upper not in imported_modules(lower), f"{lower} imports {upper}, which imports it: a cycle"


def _in(package: str) -> list[str]:
    return [m for m in MODULES if m == package or m.startswith(package + ".")]


@pytest.mark.parametrize("lower", ["engine.photo_sampling", "engine.meshops"])
def test_photo_sampling_and_mesh_helpers_sit_below_recon_and_texture(lower):
    above = {i for i in imported_modules(lower) if i.startswith(("engine.recon", "engine.texture"))}
    assert not above, f"{lower} imports {sorted(above)}: it must stay below recon and texture"


@pytest.mark.parametrize("user", ["engine.recon.colour", "engine.texture.bake", "engine.stereo.vertex_evidence"])
def test_colours_the_bake_and_the_evidence_look_up_points_in_one_home(user):
    assert "engine.photo_sampling" in imported_modules(user)


def test_texture_never_imports_recon():
    offending = {m: sorted(i for i in imported_modules(m) if i == "engine.recon" or i.startswith("engine.recon."))
                 for m in _in("engine.texture")}
    assert not {m: i for m, i in offending.items() if i}, \
        "engine/texture must not import engine/recon: what both need lives in engine/photo_sampling.py, engine/meshops.py"
    assert "engine.texture.options" in imported_modules("engine.recon.settings")  # settings sits above the texture options
    # The texture command is above both; what it shares with `engine reconstruct` sits below both.
    assert {"engine.recon.settings", "engine.texture.vr"} <= imported_modules("engine.texture_command")
    assert "engine.sidecar" in imported_modules("engine.recon.cli") & imported_modules("engine.texture_command")


# The floors below everything built on captures, and what each may import besides its own modules.
BELOW = {
    "engine.capture": {"engine.geometry", "engine.errors", "engine.jobs"},
    "engine.geometry": {"engine.errors"},
}


@pytest.mark.parametrize("package", sorted(BELOW))
def test_capture_and_geometry_never_import_up_a_floor(package):
    modules = _in(package)
    assert len(modules) > 3
    allowed = BELOW[package]
    offending = {m: sorted(i for i in imported_modules(m)
                           if not any(i == p or i.startswith(p + ".") for p in allowed | {package}))
                 for m in modules}
    offending = {m: i for m, i in offending.items() if i}
    assert not offending, \
        f"{package} may import only {sorted(allowed)}, but {offending}: move what it needs down to it"


def test_the_loader_and_the_pose_alignment_level_by_one_vertical_line_search():
    assert "engine.capture.vertical_lines" in imported_modules("engine.capture.record3d")
    assert "engine.capture.vertical_lines" in imported_modules("engine.poses.gravity")
