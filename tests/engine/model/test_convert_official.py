"""`convert-official`: a checkpoint with the official keys and shapes converts, loads strictly, and its
torchsparse kernels compute what torchsparse computes (checked with plain loops over the spec's rule)."""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import pytest
import torch

from engine.__main__ import main
from engine.errors import WeightsError
from engine.model import load_weights
from engine.model.convert_official import convert_checkpoint
from engine.sparse import SparseVoxels

KEYS_FILE = Path(__file__).resolve().parents[3].parent / "shared" / "design" / "vortx-official-keys.txt"

# The official Upsampler's constant tables, in its [x, y, z, batch] column order.
OFFICIAL_OFFSETS = [[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 1, 0, 0], [0, 1, 1, 0], [1, 0, 1, 0], [1, 1, 1, 0]]
OFFICIAL_MUL = [2, 2, 2, 1]


@pytest.fixture(autouse=True, scope="module")
def single_thread():
    """One intra-op thread: on a shared 2-core machine two spinning OpenMP threads make small ops crawl."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def official_shapes() -> dict[str, tuple[int, ...]]:
    if not KEYS_FILE.is_file():
        pytest.skip(f"official key list not available: {KEYS_FILE} is missing (only beside the team's checkout)")
    shapes = {}
    for line in KEYS_FILE.read_text().splitlines():
        name, shape = line.split("\t")
        shapes[name] = tuple(int(s) for s in shape.strip("[]").split(",") if s.strip())
    return shapes


def random_official_state() -> dict[str, torch.Tensor]:
    """Random tensors with exactly the official keys and shapes (the upsampler tables are the
    architecture's constants, as in the real file)."""
    generator = torch.Generator().manual_seed(0)
    state = {}
    for name, shape in official_shapes().items():
        if name.endswith("num_batches_tracked"):
            state[name] = torch.tensor(12345)
        elif name.endswith("running_var"):
            state[name] = torch.rand(shape, generator=generator) + 0.5
        else:
            state[name] = torch.randn(shape, generator=generator)
    state["vortx.upsampler.upsample_offsets"] = torch.tensor([OFFICIAL_OFFSETS], dtype=torch.int32)
    state["vortx.upsampler.upsample_mul"] = torch.tensor([[OFFICIAL_MUL]], dtype=torch.int32)
    return state


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """(official state, converted model): the checkpoint is written as Lightning does and converted by the CLI."""
    tmp = tmp_path_factory.mktemp("official")
    state = random_official_state()
    torch.save({"epoch": 499, "global_step": 123456, "state_dict": state, "optimizer_states": []}, tmp / "vortx.ckpt")
    assert main(["convert-official", str(tmp / "vortx.ckpt"), "--out", str(tmp / "official.safetensors")]) == 0
    model, config = load_weights(tmp / "official.safetensors")
    assert (config.backbone, config.use_proj_occ, config.fusion) == ("mnasnet", True, "transformer")
    return state, model


def random_voxels(n: int, extent: int, generator: torch.Generator) -> torch.Tensor:
    """(n, 4) distinct [batch 0, x, y, z] coordinates in [0, extent)^3."""
    flat = torch.randperm(extent**3, generator=generator)[:n]
    xyz = torch.stack([flat // extent**2, (flat // extent) % extent, flat % extent], dim=1)
    return torch.cat([torch.zeros(n, 1, dtype=torch.long), xyz], dim=1)


def test_every_official_tensor_arrives_under_its_name(converted):
    state, model = converted
    ours = model.state_dict()
    assert len(ours) == len(state)
    for name, value in state.items():
        key = name[len("vortx."):]
        if key.startswith("upsampler."):
            continue  # reordered columns, checked below
        assert torch.equal(ours[key], value.to(ours[key].dtype)), key
    # Upsampler tables: [x, y, z, batch] -> [batch, x, y, z].
    assert ours["upsampler.upsample_mul"].tolist() == [[[1, 2, 2, 2]]]
    assert ours["upsampler.upsample_offsets"][0].tolist() == [[o[3], o[0], o[1], o[2]] for o in OFFICIAL_OFFSETS]


def test_converted_3x3x3_conv_follows_the_torchsparse_rule(converted):
    """out[p] = sum_k in[p + off_k] @ W[k], offsets x fastest: k = (dz+1)*9 + (dy+1)*3 + (dx+1)."""
    state, model = converted
    W = state["vortx.cnns3d.medium.stem.0.kernel"]  # (27, 137, 16)
    generator = torch.Generator().manual_seed(1)
    coords = random_voxels(60, 5, generator)
    feats = torch.randn(60, W.shape[1], generator=generator)
    with torch.no_grad():
        out = model.get_submodule("cnns3d.medium.stem.0")(SparseVoxels(coords, feats)).feats

    row = {tuple(c): i for i, c in enumerate(coords.tolist())}
    expected = torch.zeros(60, W.shape[2])
    for i, (b, x, y, z) in enumerate(coords.tolist()):
        for dx, dy, dz in itertools.product((-1, 0, 1), repeat=3):
            j = row.get((b, x + dx, y + dy, z + dz))
            if j is not None:
                expected[i] += feats[j] @ W[(dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)]
    torch.testing.assert_close(out, expected, atol=1e-4, rtol=1e-5)


def test_converted_2x2x2_stride2_conv_follows_the_torchsparse_rule(converted):
    """Outputs at parents floor(c/2)*2 that have children; out[p] = sum_k in[p + off_k] @ W[k], offsets
    in {0,1}^3 z fastest: k = dx*4 + dy*2 + dz."""
    state, model = converted
    W = state["vortx.cnns3d.medium.stage1.0.net.0.kernel"]  # (8, 16, 16)
    generator = torch.Generator().manual_seed(2)
    coords = random_voxels(50, 6, generator)
    feats = torch.randn(50, W.shape[1], generator=generator)
    with torch.no_grad():
        result = model.get_submodule("cnns3d.medium.stage1.0.net.0")(SparseVoxels(coords, feats))
    assert result.stride == 2

    row = {tuple(c): i for i, c in enumerate(coords.tolist())}
    parents = sorted({(b, x // 2 * 2, y // 2 * 2, z // 2 * 2) for b, x, y, z in coords.tolist()})
    assert sorted(map(tuple, result.coords.tolist())) == parents
    expected = {}
    for b, x, y, z in parents:
        total = torch.zeros(W.shape[2])
        for dx, dy, dz in itertools.product((0, 1), repeat=3):
            j = row.get((b, x + dx, y + dy, z + dz))
            if j is not None:
                total += feats[j] @ W[dx * 4 + dy * 2 + dz]
        expected[(b, x, y, z)] = total
    for c, value in zip(result.coords.tolist(), result.feats):
        torch.testing.assert_close(value, expected[tuple(c)], atol=1e-4, rtol=1e-5)


def test_a_checkpoint_with_pickled_objects_is_refused_with_a_clear_message(tmp_path):
    state = {"vortx.layer_norms.coarse.weight": torch.ones(80)}
    torch.save({"state_dict": state, "hyper_parameters": argparse.Namespace(lr=1e-3)}, tmp_path / "odd.ckpt")
    with pytest.raises(WeightsError, match="weights_only=True"):
        convert_checkpoint(tmp_path / "odd.ckpt", tmp_path / "out.safetensors")
    assert not (tmp_path / "out.safetensors").exists()


def test_a_checkpoint_that_is_not_vortx_is_refused(tmp_path):
    torch.save({"state_dict": {"model.fc.weight": torch.ones(2, 2)}}, tmp_path / "other.ckpt")
    with pytest.raises(WeightsError, match="vortx"):
        convert_checkpoint(tmp_path / "other.ckpt", tmp_path / "out.safetensors")
    missing = random_official_state()
    del missing["vortx.cnns3d.fine.stem.0.kernel"]
    torch.save({"state_dict": missing}, tmp_path / "partial.ckpt")
    with pytest.raises(WeightsError, match="1 missing"):
        convert_checkpoint(tmp_path / "partial.ckpt", tmp_path / "out.safetensors")
