"""Choosing the network: seeded random init, a weights file, the default weights."""

from __future__ import annotations

import pytest
import torch

from engine.errors import WeightsError
from engine.model import weights as model_weights
from engine.recon.network import load_network

CPU = torch.device("cpu")


def test_random_weights_are_seeded_and_leave_the_global_rng_alone():
    torch.manual_seed(123)
    expected_next = torch.rand(1)
    torch.manual_seed(123)
    a, config, label = load_network("random", 0, CPU)
    assert torch.rand(1) == expected_next  # the caller's random stream is untouched
    b, _, _ = load_network("random", 0, CPU)
    c, _, _ = load_network("random", 1, CPU)
    sa, sb, sc = a.state_dict(), b.state_dict(), c.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert any(not torch.equal(sa[k], sc[k]) for k in sa if sa[k].is_floating_point())
    assert label == "random (seed 0)" and not a.training


def test_a_weights_file_round_trips(tmp_path):
    model, config, _ = load_network("random", 3, CPU)
    path = model_weights.save_weights(model, config, tmp_path / "w.safetensors")
    loaded, loaded_config, label = load_network(str(path), 0, CPU)
    assert loaded_config == config and label == str(path)
    state = loaded.state_dict()
    assert all(torch.equal(v, state[k]) for k, v in model.state_dict().items())


def test_shipping_weights_with_scene_norm_statistics_switches_every_3d_batchnorm(tmp_path):
    from engine.sparse import SparseBatchNorm
    from engine.model.weights import ship_weights

    model, config, _ = load_network("random", 3, CPU)
    trained = model_weights.save_weights(model, config, tmp_path / "trained.safetensors")
    shipped = ship_weights(trained, tmp_path / "shipped.safetensors", config_changes={"sparse_norm_statistics": "scene"})
    loaded, loaded_config, _ = load_network(str(shipped), 0, CPU)
    assert config.sparse_norm_statistics == "running" and loaded_config.sparse_norm_statistics == "scene"
    norms_3d = [m for m in loaded.cnns3d.modules() if isinstance(m, SparseBatchNorm)]
    assert norms_3d and all(m.scene_statistics for m in norms_3d)
    assert not any(m.scene_statistics for m in model.modules() if isinstance(m, SparseBatchNorm))
    assert '"sparse_norm_statistics": "scene"' in model_weights.sidecar_path(shipped).read_text()


def test_missing_default_weights_say_what_to_do(tmp_path, monkeypatch):
    monkeypatch.setattr(model_weights, "DEFAULT_WEIGHTS", tmp_path / "absent.safetensors")
    with pytest.raises(WeightsError, match="--weights random"):
        load_network(None, 0, CPU)
