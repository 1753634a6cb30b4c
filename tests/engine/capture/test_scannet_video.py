"""ScanNet export layout and video files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine.capture import load_capture
from engine.capture.video import blurry_frames
from engine.errors import CaptureError
from fixtures_capture import intrinsics, project, ring_poses, textured_image, write_scannet, write_video

W, H = 64, 48


def test_scannet_poses_K_depth_and_metric(tmp_path):
    poses = ring_poses(12)  # 0..11: "10" and "11" must come after "2"
    K = intrinsics(55.0, W, H, fy=56.0)
    write_scannet(tmp_path, poses, K, (W, H))
    (tmp_path / "depth" / "3.png").unlink()

    capture = load_capture(tmp_path)

    assert capture.format == "scannet" and capture.metric is True and capture.warnings == []
    assert [f.name for f in capture.frames] == [f"{i}.jpg" for i in range(12)]
    point = np.array([0.1, 0.2, 1.2])
    for frame, pose in zip(capture.frames, poses):
        np.testing.assert_allclose(frame.K, K)
        np.testing.assert_allclose(frame.pose, pose, atol=1e-12)  # np.savetxt keeps 18 digits
        np.testing.assert_allclose(project(frame.K, frame.pose, point), project(K, pose, point), atol=1e-9)
    assert capture.frames[3].depth_path is None
    assert capture.frames[4].depth_path == tmp_path / "depth" / "4.png"
    assert load_capture(tmp_path, metric=False).metric is False


def test_scannet_inf_pose_and_missing_pose_file_are_skipped(tmp_path):
    write_scannet(tmp_path, ring_poses(4), intrinsics(55.0, W, H), (W, H), depth=False)
    np.savetxt(tmp_path / "pose" / "1.txt", np.full((4, 4), -np.inf))  # ScanNet's "tracking lost"
    (tmp_path / "pose" / "2.txt").unlink()
    capture = load_capture(tmp_path)
    assert [f.name for f in capture.frames] == ["0.jpg", "3.jpg"]
    assert any("1.txt" in w and "non-finite" in w for w in capture.warnings)
    assert any("2.jpg" in w and "no pose file" in w for w in capture.warnings)


def test_scannet_without_any_valid_pose_is_an_error(tmp_path):
    write_scannet(tmp_path, ring_poses(2), intrinsics(55.0, W, H), (W, H), depth=False)
    for i in range(2):
        np.savetxt(tmp_path / "pose" / f"{i}.txt", np.full((4, 4), np.nan))
    with pytest.raises(CaptureError, match=r"no frame of .* has a usable pose.*0\.txt"):
        load_capture(tmp_path)


def test_scannet_missing_intrinsics_names_the_file(tmp_path):
    write_scannet(tmp_path, ring_poses(2), intrinsics(55.0, W, H), (W, H), depth=False)
    (tmp_path / "intrinsic" / "intrinsic_color.txt").unlink()
    with pytest.raises(CaptureError, match="intrinsic_color.txt is missing"):
        load_capture(tmp_path)


def _walk_video(path, count, fps, blurred=()):
    """A textured scene panning right 2 px per frame; frames in `blurred` get a strong blur."""
    scene = textured_image(400, 120, seed=7)
    frames = []
    for i in range(count):
        frame = np.ascontiguousarray(scene[:, 2 * i:2 * i + 160])
        if i in blurred:
            frame = cv2.GaussianBlur(frame, (0, 0), 4.0)
        frames.append(frame)
    return write_video(path, frames, fps)


def test_video_sampled_at_rate_and_blurry_frames_dropped(tmp_path):
    video = _walk_video(tmp_path / "walk.mp4", count=30, fps=10, blurred={10, 15})
    capture = load_capture(video, cache_dir=tmp_path / "cache")  # 2 per second: frames 0, 5, ..., 25
    assert capture.format == "video" and capture.root == video
    assert [f.name for f in capture.frames] == [f"walk_{i:06d}.jpg" for i in (0, 5, 20, 25)]
    assert all(f.pose is None and f.K is None for f in capture.frames)
    assert capture.resolution == (160, 120)
    dropped = next(w for w in capture.warnings if "blurry" in w)
    assert "2 of 6" in dropped and "walk_000010.jpg" in dropped and "walk_000015.jpg" in dropped
    assert not (tmp_path / "cache" / "video-walk-2fps" / "walk_000010.jpg").exists()

    every = load_capture(video, fps=10, blur_fraction=0.0, cache_dir=tmp_path / "cache")
    assert len(every.frames) == 30


def test_video_cache_is_reused_and_default_location(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "user-cache"))
    monkeypatch.setattr("sys.platform", "linux")
    video = _walk_video(tmp_path / "videos" / "Clip.MOV", count=8, fps=4)
    first = load_capture(video)  # default: the per-user cache, not beside the video
    folder = first.frames[0].image_path.parent
    assert folder.name == "video-Clip-2fps" and folder.parent.name.startswith("videos-")
    assert folder.parent.parent == tmp_path / "user-cache" / "vortx"
    assert sorted(p.name for p in (tmp_path / "videos").iterdir()) == ["Clip.MOV"]
    stamp = first.frames[0].image_path.stat().st_mtime_ns
    again = load_capture(video)
    assert [f.image_path for f in again.frames] == [f.image_path for f in first.frames]
    assert again.frames[0].image_path.stat().st_mtime_ns == stamp  # not extracted again
    with pytest.raises(CaptureError, match="choose the video file itself"):
        load_capture(tmp_path / "videos")


def test_unreadable_video_is_reported(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a real video")
    with pytest.raises(CaptureError, match="broken.mp4"):
        load_capture(bad, cache_dir=tmp_path / "cache")


def test_blur_rule():
    assert blurry_frames([100.0, 90.0, 40.0, 110.0, 10.0], 0.5) == [2, 4]  # median 90 -> threshold 45
    assert blurry_frames([100.0, 90.0, 40.0], 0.0) == []
