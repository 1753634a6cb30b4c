"""Training loop (engine.train.loop): overfit, exact resume, phase-2 freezing, CLI config + export.

Tiny network and crops on an analytic box room (no Blender), one thread: a few seconds in all."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from engine.train.config import config_from_dict, load_config
from engine.train.batching import CropDataset
from engine.train.crops import CropSettings
from engine.train.loop import TrainingModule, Trainer, bn_modules, trunk_modules
from fixtures_rooms import box_room

TINY_MODEL = {"feature_channels": [8, 8, 8], "unet_base_widths": [4, 4, 4], "max_train_voxels": [2048, 4096]}


@pytest.fixture(scope="module")
def room():
    return box_room(n_frames=8, image_size=(64, 48))


def _cfg(tmp_path, **over):
    data = {
        "name": "t", "model": TINY_MODEL, "crop_size": [32, 32, 16], "n_views": 3, "image_size": [64, 48],
        "phase1": {"steps": 2, "batch_size": 2, "lr": 1e-3, "warmup_steps": 2},
        "phase2": {"steps": 2, "batch_size": 2, "lr": 1e-4},
        "out_dir": str(tmp_path / "run"), "checkpoint_every": 1000, "seed": 7,
    }
    data.update(over)
    return config_from_dict(data)


def _trainer(cfg, room):
    ds = CropDataset([room, room], CropSettings(tuple(cfg.crop_size), cfg.n_views, noise=2.0), image_size=cfg.image_size)
    return Trainer(cfg, dataset=ds, pretrained=False, progress=False, log=True)


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def test_overfit_fixed_batch(tmp_path, room):
    torch.manual_seed(0)
    tr = _trainer(_cfg(tmp_path), room)
    batch = tr.dataset.batch([0, 1], np.random.default_rng(0))  # a crop its views see
    from engine.train.loop import configure_phase, set_train_mode

    params = configure_phase(tr.net, tr.cfg.phase1)
    set_train_mode(tr.net, tr.cfg.phase1)
    module = TrainingModule(tr.net)
    opt = torch.optim.Adam(params, lr=3e-3)
    first = None
    for _ in range(12):
        losses = module(batch)
        opt.zero_grad()
        losses["loss"].backward()
        opt.step()
        first = first if first is not None else float(losses["loss"].detach())
    assert {"occ_0", "occ_1", "tsdf", "projocc_0", "projocc_2", "loss"} <= set(losses)
    assert float(module(batch)["loss"].detach()) < 0.8 * first


def test_exact_resume(tmp_path, room):
    """Train 4 steps straight == train 1, save, resume in a fresh trainer, train 3 (across phases)."""
    cfg = _cfg(tmp_path)
    a = _trainer(cfg, room)
    full = [r["loss"] for r in a.run(4)]

    cfg_b = _cfg(tmp_path, out_dir=str(tmp_path / "run_b"))
    b = _trainer(cfg_b, room)
    part = [r["loss"] for r in b.run(1)]
    ckpt = tmp_path / "run_b" / "checkpoint.pt"
    assert ckpt.is_file()
    with open(tmp_path / "run_b" / "losses.jsonl", "a") as log:  # a crash after step 2, before its checkpoint
        log.write(json.dumps({"step": 2, "loss": 0.0}) + "\n" + '{"step": 3, "lo')
    # scramble every RNG so only the checkpoint can restore them
    torch.manual_seed(123)
    np.random.seed(5)
    c = _trainer(cfg_b, room)
    c.load_checkpoint(ckpt)
    assert c.step == 1
    part += [r["loss"] for r in c.run(4)]
    assert part == full
    for (k, va), vc in zip(a.net.state_dict().items(), c.net.state_dict().values()):
        assert torch.equal(va, vc), k
    log = [json.loads(line) for line in (tmp_path / "run" / "losses.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4] and log[-1]["phase"] == 2
    resumed_log = [json.loads(line) for line in (tmp_path / "run_b" / "losses.jsonl").read_text().splitlines()]
    assert [r["step"] for r in resumed_log] == [1, 2, 3, 4]  # each step once: the lost step 2 is the redone one
    assert [r["loss"] for r in resumed_log] == full


def test_phase2_unfreezes_trunk_but_not_batchnorm(tmp_path, room):
    tr = _trainer(_cfg(tmp_path), room)
    trunk = trunk_modules(tr.net)
    trunk_params = {id(p) for m in trunk for p in m.parameters()}
    bn_params = {id(p) for m in bn_modules(trunk) for p in m.parameters()}
    assert bn_params and trunk_params - bn_params

    tr.run(1)  # phase 1
    in_opt = {id(p) for g in tr.optimizer.param_groups for p in g["params"]}
    assert not (in_opt & trunk_params)
    assert all(not m.training for m in trunk)
    assert tr.net.use_proj_occ is False

    before = {id(p): p.detach().clone() for m in bn_modules(trunk) for p in m.parameters()}
    stats = [m.running_mean.clone() for m in bn_modules(trunk)]
    tr.run(3)  # into phase 2
    in_opt = {id(p) for g in tr.optimizer.param_groups for p in g["params"]}
    assert (trunk_params - bn_params) <= in_opt
    assert not (in_opt & bn_params)
    assert tr.optimizer.param_groups[0]["lr"] == pytest.approx(1e-4)
    assert tr.net.use_proj_occ is True
    assert all(not m.training for m in bn_modules(trunk))
    for m in bn_modules(trunk):
        for p in m.parameters():
            assert torch.equal(p, before[id(p)])
    for m, s in zip(bn_modules(trunk), stats):
        assert torch.equal(m.running_mean, s)


def test_config_files_parse_and_export(tmp_path, room):
    import pathlib

    for path in sorted(pathlib.Path("configs").glob("train_*.json")):
        cfg = load_config(path)
        assert cfg.total_steps > 0
    tr = _trainer(_cfg(tmp_path, phase2={"steps": 0}), room)
    tr.run(1)
    out = tr.export_weights(tmp_path / "w.safetensors")
    from engine.model.weights import read_config

    assert read_config(out).feature_channels == (8, 8, 8)


def test_a_run_starts_from_an_earlier_runs_weights(tmp_path, room):
    """init_weights: the new run's network is the exported one, parameter for parameter; weights of
    another model are refused with a message naming the setting."""
    first = _trainer(_cfg(tmp_path / "a", phase2={"steps": 0}), room)
    first.run(2)
    exported = first.export_weights(tmp_path / "w.safetensors")
    second = _trainer(_cfg(tmp_path / "b", init_weights=str(exported)), room)
    theirs, ours = first.net.state_dict(), second.net.state_dict()
    assert all(torch.equal(theirs[k], ours[k]) for k in ours)
    assert any(not torch.equal(theirs[k], v) for k, v in _trainer(_cfg(tmp_path / "c"), room).net.state_dict().items()
               if v.is_floating_point())

    other = dict(TINY_MODEL, feature_channels=[8, 8, 16])
    from engine.errors import VortxError

    with pytest.raises(VortxError, match="init_weights: .* another model .*feature_channels"):
        _trainer(_cfg(tmp_path / "d", model=other, init_weights=str(exported)), room)
    with pytest.raises(VortxError, match="init_weights: .*missing.safetensors does not exist"):
        _trainer(_cfg(tmp_path / "e", init_weights=str(tmp_path / "missing.safetensors")), room)
