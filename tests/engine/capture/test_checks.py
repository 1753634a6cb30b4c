"""Skip, warn, go on: a bad photo among good ones is left out with a warning naming it, in every
loader and in `engine info`; the capture fails only when too few photos remain.

Real photos (the instant-ngp fox, 1080 x 1920 JPEGs) are copied into tmp_path and one copy is cut
to half its bytes, as an interrupted transfer leaves it; the test skips when the data is absent.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_dataset
from engine.__main__ import main
from engine.capture import load_capture
from engine.capture.images import UnusableImage, read_image_info
from fixtures_capture import intrinsics, ring_poses, textured_image, write_image, write_photo_folder, write_scannet, \
    write_transforms_json



def _fox_copy(tmp_path: Path, with_transforms: bool) -> tuple[Path, list[str]]:
    """The first five fox photos (and their transforms.json entries) in tmp_path/fox, the third cut
    in half; returns the folder and the five names."""
    fox = shared_dataset("fox")
    names = sorted(p.name for p in (fox / "images").glob("*.jpg"))[:5]
    folder = tmp_path / "fox"
    (folder / "images").mkdir(parents=True)
    for name in names:
        shutil.copy(fox / "images" / name, folder / "images" / name)
    data = (folder / "images" / names[2]).read_bytes()
    (folder / "images" / names[2]).write_bytes(data[: len(data) // 2])
    if with_transforms:
        meta = json.loads((fox / "transforms.json").read_text())
        meta["frames"] = [f for f in meta["frames"] if Path(f["file_path"]).name in names]
        (folder / "transforms.json").write_text(json.dumps(meta))
    return folder, names


def test_a_real_photo_cut_in_half_is_detected(tmp_path):
    fox = shared_dataset("fox")
    data = (fox / "images" / "0001.jpg").read_bytes()
    assert read_image_info(fox / "images" / "0001.jpg").size == (1080, 1920)
    for fraction in (0.5, 0.999):  # half the bytes, and only the last bytes missing
        cut = tmp_path / f"cut{fraction}.jpg"
        cut.write_bytes(data[: int(len(data) * fraction)])
        with pytest.raises(UnusableImage, match="truncated") as error:
            read_image_info(cut)
        assert error.value.path == cut and cut.name in str(error.value)


def test_fox_folder_with_a_truncated_photo_loads_without_it_and_info_says_so(tmp_path, capsys):
    folder, names = _fox_copy(tmp_path, with_transforms=False)
    capture = load_capture(folder)
    assert [f.name for f in capture.frames] == names[:2] + names[3:]
    assert main(["info", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "frames      4" in out
    assert f"1 photo(s) skipped, the capture goes on without them: {names[2]} (corrupt, truncated" in out


def test_fox_transforms_json_with_a_truncated_photo_loads_without_it(tmp_path, capsys):
    folder, names = _fox_copy(tmp_path, with_transforms=True)
    capture = load_capture(folder, cache_dir=tmp_path / "cache")  # the fox has lens distortion: undistorted there
    assert [Path(f.name).stem for f in capture.frames] == [Path(n).stem for n in names[:2] + names[3:]]
    assert all(f.pose is not None for f in capture.frames)
    assert any(f"{names[2]} (corrupt, truncated" in w for w in capture.warnings)
    assert main(["info", str(folder), "--json", "--cache-dir", str(tmp_path / "cache")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 4 and any(names[2] in w for w in summary["warnings"])


def test_transforms_json_photo_of_another_aspect_ratio_is_skipped_with_the_hint(tmp_path):
    poses = ring_poses(4)
    write_photo_folder(tmp_path / "images", 4, (64, 48), suffix=".jpg")
    write_image(tmp_path / "images" / "frame2.jpg", textured_image(48, 64, seed=9))  # rotated by its EXIF tag, say
    write_transforms_json(tmp_path / "transforms.json", [(f"images/frame{i}.jpg", p) for i, p in enumerate(poses)],
                          fl_x=60.0, w=64, h=48)
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["frame0.jpg", "frame1.jpg", "frame3.jpg"]
    [warning] = [w for w in capture.warnings if "skipped, the capture goes on" in w]
    assert "frame2.jpg (48 x 64, while" in warning and "states a 64 x 48 camera" in warning


def test_every_photo_rotated_gives_the_exif_hint(tmp_path):
    poses = ring_poses(2)
    write_photo_folder(tmp_path / "images", 2, (48, 64), suffix=".jpg")
    write_transforms_json(tmp_path / "transforms.json", [(f"images/frame{i}.jpg", p) for i, p in enumerate(poses)],
                          fl_x=60.0, w=64, h=48)
    with pytest.raises(Exception, match=r"no posed photos after skipping 2 unusable photo\(s\).*exiftool -Orientation="):
        load_capture(tmp_path)


def test_scannet_zero_byte_photo_is_skipped(tmp_path):
    colors = write_scannet(tmp_path, ring_poses(4), intrinsics(55.0, 64, 48), (64, 48), depth=False)
    colors[1].write_bytes(b"")
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["0.jpg", "2.jpg", "3.jpg"]
    assert any("1.jpg (an empty file (0 bytes))" in w for w in capture.warnings)
    np.testing.assert_allclose(capture.frames[1].pose, ring_poses(4)[2], atol=1e-12)  # poses stay with their photos
