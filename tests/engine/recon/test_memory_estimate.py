"""estimate_capture_memory: what one capture's batch run declares to a Ray cluster, from the capture
and the run's settings, before anything heavy runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.capture import load_capture
from engine.recon.memory_estimate import (BASELINE_BYTES, BLENDER_PROCESS_BYTES, TEXTURE_BYTES_PER_TEXEL,
                                          estimate_capture_memory)
from engine.recon.settings import ReconSettings
from fixtures_capture import intrinsics, ring_poses, write_photo_folder, write_scannet


@pytest.fixture(scope="module")
def posed(tmp_path_factory) -> object:
    folder = tmp_path_factory.mktemp("memory") / "scan"
    write_scannet(folder, ring_poses(8, radius=1.0), intrinsics(100.0, 160, 120), (160, 120), depth=False)
    return load_capture(folder)


def test_finer_voxels_and_more_views_need_more_memory(posed) -> None:
    coarse = estimate_capture_memory(posed, ReconSettings(voxel_size=0.16, views=3))
    fine = estimate_capture_memory(posed, ReconSettings(voxel_size=0.04, views=3))
    assert fine.total > coarse.total and fine.voxels[2] > coarse.voxels[2]
    # The tiny test run (16 cm, 3 views, 160 px) peaked at 1.43-1.50 GB RSS in the batch process.
    tiny = estimate_capture_memory(posed, ReconSettings(voxel_size=0.16, views=3, image_long_side=160,
                                                        max_room_size=(2.0, 2.0, 2.0)))
    assert 1.3e9 < tiny.total < 2.0e9, tiny.to_dict()
    assert tiny.components["blender"] == BLENDER_PROCESS_BYTES


def test_an_unposed_capture_is_costed_at_the_whole_room_box(tmp_path: Path, posed) -> None:
    """Structure from motion has not posed it yet: every frame is a keyframe and the room may fill
    max_room_size, so it declares more than the same frames posed in a 2 m ring."""
    write_photo_folder(tmp_path / "photos", 8, (160, 120), suffix=".jpg")
    unposed = load_capture(tmp_path / "photos")
    settings = ReconSettings(voxel_size=0.08, views=8)
    assert estimate_capture_memory(unposed, settings).total > estimate_capture_memory(posed, settings).total
    smaller_box = ReconSettings(voxel_size=0.08, views=8, max_room_size=(4.0, 4.0, 3.0))
    assert estimate_capture_memory(unposed, smaller_box).total < estimate_capture_memory(unposed, settings).total


def test_the_vr_bake_counts_when_it_needs_more_than_the_reconstruction(posed) -> None:
    settings = ReconSettings(voxel_size=0.16, views=3, texture_size=8192)
    plain = estimate_capture_memory(posed, settings)
    baked = estimate_capture_memory(posed, settings, texture=True)
    assert baked.components["texture_bake"] == BASELINE_BYTES + TEXTURE_BYTES_PER_TEXEL * 8192 ** 2
    assert baked.total == BLENDER_PROCESS_BYTES + baked.components["texture_bake"] > plain.total
