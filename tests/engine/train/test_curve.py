"""The evidence-model training recipe: output layers first, and a learning curve on held-out rooms that
starts exactly at the classical stereo method and survives a resume.

A tiny evidence network trains on an analytic box room (exact depth standing in for its stereo maps);
the curve room is a ray-cast box room written as a room folder, reconstructed by the product's own
pipeline (real plane-sweep stereo on its photos) at every curve point."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from engine.eval import box_mesh
from engine.mesh_io import write_ply
from engine.recon.synthetic import make_synthetic_capture, render_box_room
from engine.train.batching import CropDataset
from engine.train.config import config_from_dict
from engine.train.crops import CropSettings
from engine.train.curve import CURVE_FILE, curve_table, plot_curve, read_curve
from engine.train.loop import CHECKPOINT, Trainer, trunk_modules
from engine.train.room_stereo import RoomStereo
from fixtures_rooms import box_room

ROOM_SIZE = (3.0, 2.6, 2.4)
TINY_EVIDENCE_MODEL = {"feature_channels": [8, 8, 8], "unet_base_widths": [4, 4, 4], "max_train_voxels": [2048, 4096],
                       "stereo_evidence": {}}
CURVE_SETTINGS = {"image_long_side": 96, "views": 6, "max_room_size": [7.0, 7.0, 3.5], "stereo_image_size": 160, "stereo_views": 12, "stereo_planes": 32,
                  "colour_views": 1}


pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def training_room():
    room = box_room(size=ROOM_SIZE, n_frames=12, image_size=(64, 48))
    frames = np.arange(0, 12, 2)
    room.stereo = RoomStereo(frames, room.depths[frames].copy(), np.full_like(room.depths[frames], 0.8), room.K[frames].copy())
    return room


@pytest.fixture(scope="module")
def curve_rooms(tmp_path_factory):
    """A rendered box room folder (photos, poses, exact depth, the true mesh): what `engine synth` writes."""
    folder = tmp_path_factory.mktemp("curve")
    room = folder / "box"
    capture = make_synthetic_capture(room, room_size=ROOM_SIZE, frames=24, image_size=(160, 120), radius=0.5,
                                     outward_deg=45.0)
    (room / "depth").mkdir()
    for i, frame in enumerate(capture.frames):
        _, depth = render_box_room(frame.K, frame.pose, (frame.width, frame.height), np.asarray(ROOM_SIZE))
        cv2.imwrite(str(room / "depth" / f"{i}.png"), np.round(depth * 1000).astype(np.uint16))
    truth = box_mesh(np.zeros(3), np.array(ROOM_SIZE))
    write_ply(room / "mesh_gt.ply", truth.vertices, truth.faces)
    return folder


def evidence_config(tmp_path, curve_rooms, **over):
    data = {
        "name": "t", "model": TINY_EVIDENCE_MODEL, "crop_size": [32, 32, 16], "n_views": 3, "image_size": [64, 48],
        "phase1": {"steps": 2, "batch_size": 1, "lr": 1e-2, "heads_only": True},
        "phase2": {"steps": 2, "batch_size": 1, "lr": 1e-3, "freeze_backbone": True},
        "out_dir": str(tmp_path / "run"), "checkpoint_every": 2, "seed": 3,
        "curve_rooms": [str(curve_rooms)], "curve_every": 2, "curve_settings": CURVE_SETTINGS,
    }
    data.update(over)
    return config_from_dict(data)


def trainer_for(cfg, room) -> Trainer:
    settings = CropSettings(tuple(cfg.crop_size), cfg.n_views, stereo=True, depth_scale=0.0)
    return Trainer(cfg, dataset=CropDataset([room], settings, image_size=cfg.image_size), pretrained=False,
                   progress=False, log=True)


def test_heads_only_phase_moves_nothing_but_the_output_layers(tmp_path, training_room, curve_rooms):
    cfg = evidence_config(tmp_path, curve_rooms, curve_every=0)
    trainer = trainer_for(cfg, training_room)
    before = {k: v.clone() for k, v in trainer.net.state_dict().items()}
    trainer.run(until=2)
    changed = {k for k, v in trainer.net.state_dict().items()
               if v.dtype.is_floating_point and not torch.equal(v, before[k]) and "running" not in k}
    assert changed and all(k.startswith("output_layers.") for k in changed), sorted(changed)
    trainer.run(until=4)  # phase 2: the rest of the network (the frozen ImageNet trunk aside) trains too
    changed = {k for k, v in trainer.net.state_dict().items()
               if v.dtype.is_floating_point and not torch.equal(v, before[k]) and "running" not in k}
    trunk = {id(p) for m in trunk_modules(trainer.net) for p in m.parameters()}
    trunk_names = {k for k, p in trainer.net.named_parameters() if id(p) in trunk}
    assert any(k.startswith("cnns3d.") for k in changed) and not changed & trunk_names


def test_learning_curve_starts_at_classical_fusion_and_survives_a_resume(tmp_path, training_room, curve_rooms):
    cfg = evidence_config(tmp_path, curve_rooms)
    trainer = trainer_for(cfg, training_room)
    trainer.run(until=2)
    out = cfg.out_path
    lines = read_curve(out / CURVE_FILE)
    assert [(l["step"], l["method"]) for l in lines] == [(0, "learned"), (0, "stereo"), (2, "learned")]
    start, classical = lines[0], lines[1]
    # Untrained, the evidence network's mesh is the classical method's: the same scores.
    assert classical["fscore"] > 0.3, "stereo should find the box's walls"
    for key in ("fscore", "prec", "recall", "floater_share", "pieces"):
        assert start[key] == pytest.approx(classical[key], abs=1e-6), key  # float32 round trip through tanh
    # The same surface, its vertices a float32 rounding apart (the field goes through the network's logits
    # and is meshed on the plan's lattice origin): a few faces near 30 deg from the truth's normal flip.
    assert start["normal_agreement"] == pytest.approx(classical["normal_agreement"], abs=5e-3)
    assert (out / "curve_weights" / "step_000002.safetensors").is_file()  # each point can be scored again
    assert set(start["rooms"]) == {"box"}

    # An interruption after step 2's checkpoint: the resumed run adds step 4 only, once.
    (out / CURVE_FILE).write_text((out / CURVE_FILE).read_text() + '{"step": 3, "method": "learned", "fscore": 0}\n')
    resumed = trainer_for(cfg, training_room)
    resumed.load_checkpoint(out / CHECKPOINT)
    resumed.run()
    steps = [(l["step"], l["method"]) for l in read_curve(out / CURVE_FILE)]
    assert steps == [(0, "learned"), (0, "stereo"), (2, "learned"), (4, "learned")]
    table = curve_table(read_curve(out / CURVE_FILE))
    assert "| 0 | stereo |" in table and "| 4 | learned |" in table
    picture = cv2.imread(str(plot_curve(read_curve(out / CURVE_FILE), tmp_path / "curve.png")))
    assert picture.shape == (240, 3 * 360, 3)
    assert (picture == [200, 80, 0]).all(axis=-1).sum() > 30 and (picture == [0, 0, 220]).all(axis=-1).sum() > 30  # both lines


def test_a_failing_curve_point_is_reported_and_training_goes_on(tmp_path, training_room, curve_rooms, capsys):
    cfg = evidence_config(tmp_path, tmp_path / "no_rooms_here")
    trainer = trainer_for(cfg, training_room)
    trainer.run(until=4)
    assert trainer.step == 4 and not (cfg.out_path / CURVE_FILE).exists()
    printed = capsys.readouterr().out
    assert "curve at step 0 failed, training goes on" in printed and "no_rooms_here" in printed
