"""vortx.reconstruct headless (blocking): the real engine with random weights on a tiny synthetic room,
settings reaching the engine, REPLACE / ADD, and failures or cancel leaving the scene as it was.

Two real engine runs happen once per module (`real_runs`, ~10 s on 2 CPU cores); the other tests
replace `engine.recon.driver.reconstruct` with a stand-in returning a hand-made mesh, which pins down
the Blender side independently of the network.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import scene_state
from fixtures_modal import WindowManager, Workspace, modal_operator, tick_until_done

# Tiny run: 16 cm voxels in a 2 m clipped room, 96 px images, 3 views per tile, 2 colour views.
TINY = {"voxel_size": 0.16, "tile_size": 8, "view_count": 3, "image_size": 96, "colour_views": 2,
        "max_room_size": (2.0, 2.0, 2.0), "weights_source": "RANDOM", "method": "VORTX"}
# The second real run: every setting that the engine sees differs.
OTHER = {"voxel_size": 0.2, "view_count": 1, "seed": 3, "image_size": 64, "result_mode": "ADD"}


def full_state(scene) -> dict:
    """scene_state plus the datablocks a result brings (meshes, materials)."""
    import bpy

    return {**scene_state(scene), "meshes": sorted(m.name for m in bpy.data.meshes),
            "materials": sorted(m.name for m in bpy.data.materials)}


def driver(blender):
    return importlib.import_module(f"{blender.__name__}.engine.recon.driver")  # loaded lazily by the extension


@pytest.fixture(scope="module")
def capture_dir(blender, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("room") / "living_room"
    synthetic = importlib.import_module(f"{blender.__name__}.engine.recon.synthetic")
    synthetic.make_synthetic_capture(path, room_size=(3.0, 3.0, 2.5), frames=6, image_size=(96, 72))
    return path


def posed_scene(blender, capture_dir: Path, **settings):
    """A fresh scene with the synthetic capture's cameras (as Import Capture makes them) and `settings`."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    capture = blender.engine.capture.load_capture(capture_dir)
    blender.vortx_blender.capture.apply_capture(scene, capture, capture_dir)
    for name, value in {**TINY, **settings}.items():
        setattr(scene.vortx, name, value)
    # Evaluate once now: the first depsgraph update recomputes matrix_world from loc/rot/scale, which
    # can move the last rounded digit that full_state compares.
    bpy.context.view_layer.update()
    return scene


def snapshot(obj) -> dict:
    """What a test needs of a result object after the scene is gone."""
    mesh = obj.data
    n = len(mesh.vertices)
    positions = np.empty(3 * n, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", positions)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    colour = mesh.color_attributes["Color"]
    linear, srgb = np.empty(4 * n, np.float32), np.empty(4 * n, np.float32)
    colour.data.foreach_get("color", linear)
    colour.data.foreach_get("color_srgb", srgb)
    return {
        "name": obj.name, "collections": [c.name for c in obj.users_collection],
        "vertices": positions.reshape(-1, 3), "faces": corners.reshape(-1, 3),
        "colour": (colour.data_type, colour.domain, mesh.color_attributes.active_color_name),
        "linear": linear.reshape(-1, 4), "srgb": srgb.reshape(-1, 4),
        "props": {key: obj[key] for key in obj.keys() if key.startswith("vortx_")},
        "material": obj.active_material,
        "material_links": [(link.from_node.bl_idname, link.from_node.layer_name, link.to_socket.name)
                           for link in obj.active_material.node_tree.links
                           if link.from_node.bl_idname == "ShaderNodeVertexColor"],
    }


@pytest.fixture(scope="module")
def real_runs(blender, capture_dir):
    """Reconstruct twice through the operator with the real engine: TINY, then OTHER (ADD mode).

    A spy around engine.recon.driver.reconstruct records the ReconSettings and result of each run
    and, on every fusion progress report, the overlay's tile states and the status-bar text.
    """
    import bpy

    recon = driver(blender)
    real = recon.reconstruct
    jobs, overlay = blender.vortx_blender.jobs, blender.vortx_blender.tile_overlay
    real_fuse = recon.fuse_tile
    calls: list[SimpleNamespace] = []

    def spy(capture, settings, progress=None, cancel=None, plan=None):
        call = SimpleNamespace(settings=dataclasses.replace(settings), plan=plan, states=[], status=[], result=None)
        calls.append(call)

        def watch(stage, done, total):
            progress(stage, done, total)
            if stage.startswith("fusion"):
                call.status.append(jobs.active_job().status_text())

        call.result = real(capture, settings, watch, cancel, plan=plan)
        return call.result

    def fuse_spy(*args, **kwargs):
        # What the overlay would draw while the engine fuses a tile.
        calls[-1].states.append(tuple(overlay.current().states()))
        return real_fuse(*args, **kwargs)

    recon.reconstruct, recon.fuse_tile = spy, fuse_spy
    try:
        scene = posed_scene(blender, capture_dir)
        assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
        first = snapshot(bpy.data.objects["living_room"])
        for name, value in OTHER.items():
            setattr(scene.vortx, name, value)
        assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
        results = blender.vortx_blender.result.result_objects(scene)
        second = snapshot(results[-1])
        names = [o.name for o in results]
        final_states = overlay.current(scene).states()
    finally:
        recon.reconstruct, recon.fuse_tile = real, real_fuse
    return SimpleNamespace(calls=calls, first=first, second=second, names=names, final_states=final_states)


def test_result_mesh_is_the_engine_mesh(blender, real_runs) -> None:
    engine_mesh = real_runs.calls[0].result.mesh
    got = real_runs.first
    assert got["name"] == "living_room" and got["collections"] == ["VoRTX Result"]
    assert len(got["vertices"]) == len(engine_mesh.vertices) > 0
    assert len(got["faces"]) == len(engine_mesh.faces) > 0
    np.testing.assert_array_equal(got["vertices"], engine_mesh.vertices)  # metres, exactly
    np.testing.assert_array_equal(got["faces"], engine_mesh.faces)
    assert got["colour"] == ("FLOAT_COLOR", "POINT", "Color")
    # Stored linear, read back by Blender's own sRGB conversion as the engine's photo colours.
    np.testing.assert_allclose(got["srgb"][:, :3], engine_mesh.colors, atol=2e-4)  # Blender converts with a LUT
    srgb_to_linear = blender.vortx_blender.result.srgb_to_linear
    np.testing.assert_allclose(got["linear"][:, :3], srgb_to_linear(engine_mesh.colors), atol=1e-6)
    assert np.all(got["linear"][:, 3] == 1.0)
    assert got["material_links"] == [("ShaderNodeVertexColor", "Color", "Base Color")]


def test_settings_reach_the_engine(blender, real_runs) -> None:
    first, second = (call.settings for call in real_runs.calls)
    assert (first.weights, first.voxel_size, first.views, first.tile_size, first.seed) == ("random", 0.16, 3, 8, 0)
    assert (first.image_long_side, first.colour_views, first.max_room_size, first.device) == (96, 2, (2.0, 2.0, 2.0), "cpu")
    assert (second.voxel_size, second.views, second.seed, second.image_long_side) == (0.2, 1, 3, 64)
    # Everything not set in the panel is the engine's default.
    defaults = blender.engine.recon.ReconSettings()
    for field in ("tile_height", "keyframe_translation", "keyframe_angle_deg", "frustum_depth", "fusion_chunk"):
        assert getattr(first, field) == getattr(defaults, field), field


def test_voxel_size_and_view_count_change_what_the_engine_does(real_runs) -> None:
    first, second = (json.loads(run["props"]["vortx_stats"]) for run in (real_runs.first, real_runs.second))
    assert [lv["label"] for lv in first["levels"]] == ["64 cm", "32 cm", "16 cm"]
    assert [lv["label"] for lv in second["levels"]] == ["80 cm", "40 cm", "20 cm"]
    assert [lv["voxels"] for lv in first["levels"]] != [lv["voxels"] for lv in second["levels"]]
    assert max(second["tiles"]["views_per_tile"]) == 1 < max(first["tiles"]["views_per_tile"]) <= 3
    assert first["image_size"] != second["image_size"] and max(second["image_size"]) == 64


def test_add_mode_keeps_the_previous_result(real_runs) -> None:
    assert real_runs.names == ["living_room", "living_room.001"]
    assert real_runs.second["collections"] == ["VoRTX Result"]


def test_tiles_follow_the_run_live(real_runs) -> None:
    call = real_runs.calls[0]
    seen = {state for states in call.states for state in states}
    assert "running" in seen and "pending" in seen  # a tile in work while others wait
    assert any("tiles " in text and " done" in text for text in call.status), call.status[:3]
    assert set(real_runs.final_states) <= {"done", "empty"} and "done" in real_runs.final_states
    assert len(real_runs.final_states) == len(real_runs.calls[1].plan.tiles)


def test_result_records_how_it_was_made(blender, real_runs, capture_dir) -> None:
    props = real_runs.first["props"]
    settings = json.loads(props["vortx_settings"])
    assert settings["voxel_size"] == 0.16 and settings["views"] == 3 and settings["weights"] == "random"
    assert settings["blender"] == {"weights_source": "RANDOM", "result_mode": "REPLACE", "min_piece_faces": 0,
                                   "min_piece_fraction": 0.0, "target_faces": 0}
    assert props["vortx_capture"] == str(capture_dir)
    assert props["vortx_weights"] == "random (seed 0)"
    assert props["vortx_version"] == blender.vortx_blender.result.extension_version() != "unknown"
    assert props["vortx_engine_version"] == blender.engine.__version__
    created = datetime.datetime.fromisoformat(props["vortx_created"])
    assert abs((datetime.datetime.now(datetime.timezone.utc) - created).total_seconds()) < 3600
    stats = json.loads(props["vortx_stats"])
    assert stats["mesh"]["faces"] == len(real_runs.first["faces"]) and stats["pieces"]["removed_faces"] == 0


# --- the Blender side with a stand-in engine ------------------------------------------------------------


def box_room_mesh(blender, extra_piece: bool = False):
    """A closed box (12 triangles, 2 x 3 x 2.5 m at (1, 1, 0)) with colours, optionally plus a
    far-away single triangle (a floating piece)."""
    Mesh = blender.engine.mesh_io.Mesh
    corners = np.array([[x, y, z] for z in (0, 2.5) for y in (1, 4) for x in (1, 3)], np.float32)
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                      [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    colors = np.linspace(0.05, 0.95, 3 * len(corners), dtype=np.float32).reshape(-1, 3)
    if extra_piece:
        corners = np.concatenate([corners, np.float32([[9, 9, 1], [9.1, 9, 1], [9, 9.1, 1]])])
        faces = np.concatenate([faces, np.int32([[8, 9, 10]])])
        colors = np.concatenate([colors, np.full((3, 3), 0.5, np.float32)])
    return Mesh(vertices=corners, faces=faces, normals=None, colors=colors)


@pytest.fixture
def fake_engine(blender, monkeypatch):
    """driver.reconstruct returns outcome["mesh"] (or raises outcome["error"]); records its calls."""
    ReconResult = importlib.import_module(f"{blender.__name__}.engine.recon.recon_result").ReconResult
    TileState = blender.engine.recon.TileState
    outcome: dict = {"mesh": box_room_mesh(blender)}
    calls: list = []

    def reconstruct(capture, settings, progress=None, cancel=None, plan=None):
        calls.append(settings)
        progress("fusion 16 cm", 0, 1)
        if "error" in outcome:
            raise outcome["error"]
        for tile in plan.tiles:
            tile.state = TileState.DONE if len(tile.views) else TileState.EMPTY
        stats = {"model": {"weights": "stand-in"}, "mesh": {"faces": len(outcome["mesh"].faces)}}
        return ReconResult(outcome["mesh"], plan.tiles, stats, outcome.get("message"))

    monkeypatch.setattr(driver(blender), "reconstruct", reconstruct)
    return outcome, calls


def results_in(blender, scene) -> list[str]:
    return [obj.name for obj in blender.vortx_blender.result.result_objects(scene)]


def test_replace_and_add(blender, capture_dir, fake_engine) -> None:
    import bpy

    scene = posed_scene(blender, capture_dir)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    first_mesh = bpy.data.objects["living_room"].data
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}  # REPLACE (the default)
    assert results_in(blender, scene) == ["living_room"]
    assert bpy.data.objects["living_room"].data != first_mesh
    assert "living_room.001" not in bpy.data.meshes and len(bpy.data.meshes) == 1  # the old mesh went too
    scene.vortx.result_mode = "ADD"
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    assert results_in(blender, scene) == ["living_room", "living_room.001", "living_room.002"]
    assert len(bpy.data.materials) == 1  # one shared vertex-colour material
    scene.vortx.result_mode = "REPLACE"
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    assert results_in(blender, scene) == ["living_room"]
    # Objects the user put into the result collection stay.
    assert [o.name for o in bpy.data.collections["VoRTX Result"].objects] == ["living_room"]


def test_operator_is_registered_with_undo(blender) -> None:
    import bpy

    # Headless Blender has no undo stack (ed.undo's poll fails), so undo itself is not exercised;
    # the result is built in one operator call, which Blender records as one undo step.
    assert bpy.types.VORTX_OT_reconstruct.bl_options == {"REGISTER", "UNDO"}


def test_no_posed_cameras_reports_and_changes_nothing(blender, empty_scene, fake_engine) -> None:
    import bpy

    _, calls = fake_engine
    empty_scene.vortx.capture_path = "/captures/unposed"
    before = full_state(empty_scene)
    with pytest.raises(RuntimeError, match="no posed capture cameras"):
        bpy.ops.vortx.reconstruct()
    assert full_state(empty_scene) == before and calls == []


@pytest.mark.parametrize(
    "breakage, message",
    [
        ("engine error", "default VoRTX weights are not installed"),
        ("empty mesh", "No mesh: nothing was occupied"),
        ("all pieces too small", "smaller than the minimum piece size"),
        ("missing weights file", "does not exist"),
        ("checkpoint weights", "convert-official"),
    ],
)
def test_failures_report_and_change_nothing(blender, capture_dir, fake_engine, breakage: str, message: str) -> None:
    import bpy

    outcome, _ = fake_engine
    scene = posed_scene(blender, capture_dir)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}  # a previous result the failure must not touch
    overlay = blender.vortx_blender.tile_overlay
    shown = overlay.current(scene)
    before = full_state(scene)
    if breakage == "engine error":
        outcome["error"] = blender.engine.errors.WeightsError("the default VoRTX weights are not installed")
    elif breakage == "empty mesh":
        outcome["mesh"] = importlib.import_module(f"{blender.__name__}.engine.recon.recon_result").empty_mesh()
        outcome["message"] = "nothing was occupied"
    elif breakage == "all pieces too small":
        scene.vortx.min_piece_faces = 1000
    elif breakage == "missing weights file":
        scene.vortx.weights_source, scene.vortx.weights_path = "FILE", "/nowhere/vortx.safetensors"
    else:
        scene.vortx.weights_source, scene.vortx.weights_path = "FILE", "/nowhere/vortx.ckpt"
    before = {**before, "settings": scene_state(scene)["settings"]}
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.vortx.reconstruct()
    assert full_state(scene) == before
    assert overlay.current(scene) is shown  # the previous run's tiles are shown again


def test_missing_default_weights_name_the_panel_settings(blender, capture_dir, fake_engine, monkeypatch, tmp_path) -> None:
    import bpy

    _, calls = fake_engine
    weights = importlib.import_module(f"{blender.__name__}.engine.model.weights")
    monkeypatch.setattr(weights, "DEFAULT_WEIGHTS", tmp_path / "vortx-default.safetensors")
    scene = posed_scene(blender, capture_dir, weights_source="DEFAULT")
    before = full_state(scene)
    with pytest.raises(RuntimeError, match="not installed .* set Weights to File .* or to Random"):
        bpy.ops.vortx.reconstruct()
    assert full_state(scene) == before and calls == []


def test_cancel_after_first_progress_changes_nothing(blender, capture_dir, monkeypatch) -> None:
    """The real engine, cancelled through the job runner (what Esc does) at its first progress report."""
    import bpy

    recon = driver(blender)
    real = recon.reconstruct
    jobs = blender.vortx_blender.jobs
    reports: list = []

    def cancelling(capture, settings, progress=None, cancel=None, plan=None):
        def first_then_cancel(stage, done, total):
            progress(stage, done, total)
            reports.append(stage)
            jobs.active_job().cancel()

        return real(capture, settings, first_then_cancel, cancel, plan=plan)

    scene = posed_scene(blender, capture_dir)
    before = full_state(scene)
    monkeypatch.setattr(recon, "reconstruct", cancelling)
    assert bpy.ops.vortx.reconstruct() == {"CANCELLED"}
    assert reports and len(reports) <= 2  # stopped at the next cancel check
    assert full_state(scene) == before
    assert not jobs.is_busy()
    assert blender.vortx_blender.tile_overlay.current(scene) is None


def test_small_pieces_are_dropped_before_insertion(blender, capture_dir, fake_engine) -> None:
    import bpy

    outcome, _ = fake_engine
    outcome["mesh"] = box_room_mesh(blender, extra_piece=True)
    scene = posed_scene(blender, capture_dir, min_piece_faces=2)
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    mesh = bpy.data.objects["living_room"].data
    assert (len(mesh.vertices), len(mesh.polygons)) == (8, 12)
    stats = json.loads(bpy.data.objects["living_room"]["vortx_stats"])
    assert stats["pieces"] == {"pieces": 2, "faces": 13, "removed_pieces": 1, "removed_faces": 1}
    scene.vortx.min_piece_faces = 0
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    assert len(bpy.data.objects["living_room"].data.polygons) == 13


# --- settings -> ReconSettings ---------------------------------------------------------------------------


def test_weights_choices(blender, empty_scene, tmp_path: Path) -> None:
    from_scene = blender.vortx_blender.reconstruct.recon_settings_from_scene
    errors = blender.engine.errors
    settings = empty_scene.vortx
    assert from_scene(settings).weights is None  # DEFAULT
    settings.weights_source = "RANDOM"
    network = importlib.import_module(f"{blender.__name__}.engine.recon.network")
    assert from_scene(settings).weights == network.RANDOM
    settings.weights_source = "FILE"
    with pytest.raises(errors.WeightsError, match="no weights file is chosen"):
        from_scene(settings)
    weights = tmp_path / "official.safetensors"
    weights.write_bytes(b"not read here")
    settings.weights_path = str(weights)
    assert from_scene(settings).weights == str(weights)
    assert from_scene(settings, with_weights=False).weights is None
    for name, match in (("vortx.ckpt", "convert-official"), ("weights.onnx", "must be a .safetensors")):
        settings.weights_path = str(tmp_path / name)
        with pytest.raises(errors.WeightsError, match=match):
            from_scene(settings)


def test_device_choices_follow_torch(blender, empty_scene) -> None:
    import torch

    items = [item[0] for item in blender.vortx_blender.properties.device_items()]
    assert items[0] == "CPU"
    assert ("CUDA" in items) == torch.cuda.is_available()
    assert empty_scene.vortx.device == "CPU"
    assert blender.vortx_blender.reconstruct.recon_settings_from_scene(empty_scene.vortx).device == "cpu"


def test_scene_defaults_are_the_engine_defaults(blender, empty_scene) -> None:
    settings = blender.vortx_blender.reconstruct.recon_settings_from_scene(empty_scene.vortx)
    engine = blender.engine.recon.ReconSettings()
    for field in ("voxel_size", "views", "tile_size", "seed", "image_long_side", "colour_views", "max_room_size",
                  "colour", "device"):
        assert getattr(settings, field) == getattr(engine, field), field


def test_invalid_settings_are_refused_with_the_setting_named(blender, empty_scene) -> None:
    settings = empty_scene.vortx
    settings.tile_size = 10  # not a multiple of the coarse voxel (4)
    with pytest.raises(blender.engine.errors.VortxError, match="tile size must be a positive multiple of 4"):
        blender.vortx_blender.reconstruct.recon_settings_from_scene(settings)


# --- the interactive path: Reconstruct's own methods on a modal stand-in (headless has no events) -------


RECONSTRUCT_METHODS = ("job_title", "job_detail", "make_job_function", "apply_result", "job_finished")


def test_modal_run_shows_tiles_in_the_status_bar_and_esc_cancels(blender, capture_dir, monkeypatch) -> None:
    import threading
    import time

    TileState = blender.engine.recon.TileState
    ReconResult = importlib.import_module(f"{blender.__name__}.engine.recon.recon_result").ReconResult
    fusing, finish = threading.Event(), threading.Event()

    def engine(capture, settings, progress=None, cancel=None, plan=None):
        active = [t for t in plan.tiles if len(t.views)]
        active[0].state = TileState.RUNNING
        progress("fusion 16 cm", 0, len(active))
        fusing.set()
        while not finish.is_set():
            cancel.check()  # Esc lands here
            time.sleep(0.005)
        for tile in plan.tiles:
            tile.state = TileState.DONE if len(tile.views) else TileState.EMPTY
        return ReconResult(box_room_mesh(blender), plan.tiles, {"model": {"weights": "stand-in"}}, None)

    monkeypatch.setattr(driver(blender), "reconstruct", engine)
    scene = posed_scene(blender, capture_dir)
    context = SimpleNamespace(scene=scene, window=object(), window_manager=WindowManager(), workspace=Workspace(),
                              screen=None)
    before = full_state(scene)

    op = modal_operator(blender, "VORTX_OT_reconstruct", RECONSTRUCT_METHODS)
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert fusing.wait(10)
    time.sleep(0.05)
    assert op.modal(context, SimpleNamespace(type="TIMER", value="NOTHING")) == {"RUNNING_MODAL"}
    status = context.workspace.status[-1]
    assert status.startswith("VoRTX Reconstruct: fusion 16 cm 0/") and ", tiles 0/" in status and "1 running" in status
    assert op.modal(context, SimpleNamespace(type="ESC", value="PRESS")) == {"RUNNING_MODAL"}
    assert tick_until_done(op, context, 10.0) == {"CANCELLED"}
    assert full_state(scene) == before
    assert blender.vortx_blender.tile_overlay.current(scene) is None  # nothing shown from the cancelled run

    finish.set()  # the next run goes through to the end
    op = modal_operator(blender, "VORTX_OT_reconstruct", RECONSTRUCT_METHODS)
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert tick_until_done(op, context, 10.0) == {"FINISHED"}
    assert results_in(blender, scene) == ["living_room"]
    assert context.workspace.status[-1] is None and context.window_manager.timers == set()
    assert set(blender.vortx_blender.tile_overlay.current(scene).states()) <= {"done", "empty"}


def _refined_stand_in(blender, capture, shift: np.ndarray):
    """A RefineResult that moves every posed frame by `shift` metres."""
    refine = importlib.import_module(f"{blender.__name__}.engine.poses.refine")
    poses_pkg = importlib.import_module(f"{blender.__name__}.engine.poses")
    frames, changes = [], []
    for frame in capture.frames:
        pose = frame.pose.copy()
        pose[:3, 3] += shift
        frames.append(dataclasses.replace(frame, pose=pose))
        changes.append(refine.FrameChange(frame.name, 0.3, float(np.linalg.norm(shift)), refine.STATUS_REFINED))
    return refine.RefineResult(
        capture=capture.with_frames(frames), changes=changes, units="m", points=np.zeros((0, 3)),
        point_colors=np.zeros((0, 3), np.uint8), mean_reprojection_error=0.4, error_given_px=1.6, scaled_size=(96, 72),
        adjusted_frames=len(frames), adjustment=refine.PASS_HELD, focal_scale=[1.0])


@pytest.mark.parametrize("keep", [False, True])
def test_poses_the_check_found_off_are_refined_before_reconstructing(blender, capture_dir, fake_engine, monkeypatch,
                                                                     keep: bool) -> None:
    import bpy

    poses_pkg = importlib.import_module(f"{blender.__name__}.engine.poses")
    scene = posed_scene(blender, capture_dir)
    scene.vortx.pose_check = "the photos say the given poses look off: 1.8 px mean reprojection error"
    scene.vortx.keep_given_poses = keep
    cameras = sorted((o for o in bpy.data.objects if o.type == "CAMERA" and "vortx_frame" in o), key=lambda o: o["vortx_frame"])
    before = [np.array(o["vortx_pose"]).reshape(4, 4) for o in cameras]
    shift = np.array([0.02, -0.01, 0.0])
    refined_inputs, reconstructed = [], []

    def fake_refine(capture, options=None, progress=None, cancel=None):
        refined_inputs.append(capture)
        return _refined_stand_in(blender, capture, shift)

    monkeypatch.setattr(poses_pkg, "refine_poses", fake_refine)
    real_reconstruct = driver(blender).reconstruct
    monkeypatch.setattr(driver(blender), "reconstruct", lambda capture, *a, **k: (reconstructed.append(capture),
                                                                                   real_reconstruct(capture, *a, **k))[1])
    assert bpy.ops.vortx.reconstruct() == {"FINISHED"}
    after = [np.array(o["vortx_pose"]).reshape(4, 4) for o in cameras]
    (used,) = reconstructed
    if keep:
        assert refined_inputs == [] and scene.vortx.pose_check, "Keep Given Poses: as given, the warning stays"
        np.testing.assert_allclose(np.stack(after), np.stack(before))
        return
    assert len(refined_inputs) == 1
    # Stereo and colours get the refined poses, and the scene's cameras move to them.
    np.testing.assert_allclose(used.frames[0].pose[:3, 3], before[0][:3, 3] + shift, atol=1e-9)
    np.testing.assert_allclose(after[0][:3, 3], before[0][:3, 3] + shift, atol=1e-6)
    assert scene.vortx.pose_status.endswith(", refined") and scene.vortx.pose_check == ""
