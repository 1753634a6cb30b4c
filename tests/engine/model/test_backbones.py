"""2D backbones: official MnasNet key layout, EfficientNet-Lite0 ImageNet weights, pyramid shapes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from engine.model.backbone_efficientnet import (
    EfficientNetLite0,
    EfficientNetLite0Pyramid,
    LITE_PIXEL_MEAN,
    LITE_PIXEL_STD,
    imagenet_weights_path,
    load_imagenet_weights,
)
from engine.model.backbone_mnasnet import MnasNetPyramid

SHARED = Path(__file__).resolve().parents[3].parent / "shared"
KEYS_FILE = SHARED / "design" / "vortx-official-keys.txt"
FOX_PHOTO = SHARED / "data" / "fox" / "images" / "0030.jpg"
RED_FOX = 277  # ImageNet class index


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def official_keys(prefix: str) -> dict[str, tuple[int, ...]]:
    if not KEYS_FILE.is_file():
        pytest.skip(f"official key list not available: {KEYS_FILE} is missing (only beside the team's checkout)")
    keys = {}
    for line in KEYS_FILE.read_text().splitlines():
        name, shape = line.split("\t")
        if name.startswith(prefix):
            keys[name[len(prefix):]] = tuple(int(s) for s in shape.strip("[]").split(",") if s.strip())
    return keys


def test_mnasnet_pyramid_state_dict_is_the_official_cnn2d_layout():
    expected = official_keys("vortx.cnn2d.")
    ours = {k: tuple(v.shape) for k, v in MnasNetPyramid((80, 40, 24)).state_dict().items()}
    assert ours == expected


@pytest.mark.parametrize("backbone", ["mnasnet", "efficientnet"])
def test_pyramid_maps_are_at_one_sixteenth_one_eighth_one_quarter(backbone):
    pyramid = MnasNetPyramid((80, 40, 24)) if backbone == "mnasnet" else EfficientNetLite0Pyramid((80, 40, 24))
    with torch.no_grad():
        coarse, medium, fine = pyramid.eval()(torch.rand(2, 3, 96, 128) * 255)
    assert coarse.shape == (2, 80, 6, 8)
    assert medium.shape == (2, 40, 12, 16)
    assert fine.shape == (2, 24, 24, 32)


def test_efficientnet_lite0_imagenet_weights_load_with_every_key():
    state = torch.load(imagenet_weights_path(), map_location="cpu", weights_only=True)
    classifier = EfficientNetLite0()
    classifier.load_state_dict(state, strict=True)  # the full network: every file key, every module key
    pyramid = EfficientNetLite0Pyramid((80, 40, 24), pretrained=True)
    trunk = {k: v for k, v in pyramid.state_dict().items() if k.split(".")[0] in ("_conv_stem", "_bn0", "_blocks")}
    assert len(trunk) > 150
    for key, value in trunk.items():
        assert torch.equal(value, state[key]), key


def test_efficientnet_lite0_recognises_a_red_fox():
    if not FOX_PHOTO.is_file():
        pytest.skip(f"test photo not available: {FOX_PHOTO} is missing (only beside the team's checkout)")
    import cv2

    image = cv2.imread(str(FOX_PHOTO))[:, :, ::-1]
    h, w = image.shape[:2]
    side = min(h, w)
    image = image[(h - side) // 2 : (h - side) // 2 + side, (w - side) // 2 : (w - side) // 2 + side]
    image = cv2.resize(image, (224, 224), interpolation=cv2.INTER_AREA).astype(np.float32)
    x = torch.from_numpy(image).permute(2, 0, 1)[None]
    x = (x - torch.tensor(LITE_PIXEL_MEAN).view(1, 3, 1, 1)) / torch.tensor(LITE_PIXEL_STD).view(1, 3, 1, 1)
    classifier = EfficientNetLite0()
    load_imagenet_weights(classifier)
    with torch.no_grad():
        probabilities = classifier.eval()(x).softmax(-1)[0]
    assert int(probabilities.argmax()) == RED_FOX
    assert probabilities[RED_FOX] > 0.5


def test_freeze_trunk_stops_gradients_and_statistics_only_in_the_trunk():
    pyramid = MnasNetPyramid((16, 8, 8))
    pyramid.freeze_trunk()
    trunk_bn = pyramid.conv1[0].layers[1]
    before = trunk_bn.running_mean.clone()
    pyramid.train()
    outputs = pyramid(torch.rand(2, 3, 64, 64) * 255)
    sum(o.sum() for o in outputs).backward()
    assert torch.equal(trunk_bn.running_mean, before)
    assert all(p.grad is None for m in pyramid.trunk_modules() for p in m.parameters())
    assert pyramid.out3[2].weight.grad is not None
    pyramid.freeze_trunk(False)
    assert all(p.requires_grad for p in pyramid.parameters()) and trunk_bn.track_running_stats
