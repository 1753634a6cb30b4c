"""Structure from motion end to end on a synthetic textured room with known cameras.

The room is ray-cast analytically (no Blender): a camera inside an axis-aligned box sees, per
pixel, the nearest box face along its ray, textured with band-limited noise that gives SIFT
plenty of features. Camera convention as everywhere: OpenCV axes, camera-to-world, K with the
image corner at 0 (pixel centres at +0.5).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from fixtures_capture import look_yaw_pitch as look

from engine.capture.model import Capture, Frame
from engine.errors import PoseError
from engine.poses import SfmOptions, estimate_poses, pose_errors
from engine.poses.align import umeyama
from engine.poses.sfm import choose_matcher, intrinsics_mode

ROOM = np.array([6.0, 5.0, 3.0])  # metres, corner at the origin, Z up
WIDTH, HEIGHT, FOCAL = 320, 240, 200.0
K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
TEXEL = 0.01  # metres per texture pixel


def noise_texture(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """uint8 (rows, cols) noise with blobs from 1 to 15 texels: corners and blobs at every scale."""
    image = np.zeros((rows, cols), np.float32)
    for sigma in (1.0, 2.5, 6.0, 15.0):
        image += sigma * cv2.GaussianBlur(rng.standard_normal((rows, cols)).astype(np.float32), (0, 0), sigma)
    image = (image - image.min()) / (image.max() - image.min()) * 255
    return cv2.equalizeHist(image.astype(np.uint8))


def room_faces(rng: np.random.Generator) -> list[tuple[int, float, int, int, np.ndarray]]:
    """Six faces as (normal axis, plane coordinate, texture u axis, texture v axis, texture)."""
    faces = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for value in (0.0, ROOM[axis]):
            texture = noise_texture(rng, int(ROOM[v] / TEXEL) + 2, int(ROOM[u] / TEXEL) + 2)
            faces.append((axis, value, u, v, texture))
    return faces


def render(cam_to_world: np.ndarray, faces: list) -> np.ndarray:
    """uint8 (H, W, 3) view from inside the room: each ray stops at the first face it leaves through."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    pixels = np.stack([cols + 0.5, rows + 0.5, np.ones_like(cols)], axis=-1)
    rays = pixels @ np.linalg.inv(K).T @ cam_to_world[:3, :3].T
    origin = cam_to_world[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays > 0, (ROOM - origin) / rays, np.where(rays < 0, -origin / rays, np.inf))
    axis, hit = t.argmin(axis=-1), origin + t.min(axis=-1)[..., None] * rays
    image = np.zeros((HEIGHT, WIDTH), np.uint8)
    for face_axis, value, u, v, texture in faces:
        mask = (axis == face_axis) & (np.abs(hit[..., face_axis] - value) < 1e-6)
        warped = cv2.remap(texture, (hit[..., u] / TEXEL).astype(np.float32), (hit[..., v] / TEXEL).astype(np.float32),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        image[mask] = warped[mask]
    return np.repeat(image[..., None], 3, axis=-1)


def true_poses(count: int = 12) -> list[np.ndarray]:
    """A loop 2.4 m across at hand height, looking across the room and a little down.

    Evenly spaced yaws with alternating pitch and height: the cameras' mean up is exactly +Z and
    their median height 1.5 m, so gravity and scale have a known right answer.
    """
    poses = []
    for k in range(count):
        a = 2 * np.pi * k / count
        position = np.array([3 + 1.2 * np.cos(a), 2.5 + 1.2 * np.sin(a), 1.5 + (0.1 if k % 2 else -0.1)])
        poses.append(look(position, a + np.pi + 0.25, np.radians(-12 if k % 2 else -22)))
    return poses


@pytest.fixture(scope="module")
def room_photos(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    folder = tmp_path_factory.mktemp("room")
    faces = room_faces(np.random.default_rng(7))
    poses = true_poses()
    for k, pose in enumerate(poses):
        cv2.imwrite(str(folder / f"{k:03d}.png"), render(pose, faces))
    return folder, poses


def photo_capture(folder: Path, K_known: np.ndarray | None = None, format: str = "images") -> Capture:
    frames = [Frame(p, WIDTH, HEIGHT, None if K_known is None else K_known.copy()) for p in sorted(folder.glob("*.png"))]
    return Capture(folder, format, frames)


def test_poses_gravity_and_scale_of_a_synthetic_room(room_photos):
    folder, truth = room_photos
    progress: list[tuple[str, int, int]] = []
    result = estimate_poses(photo_capture(folder), SfmOptions(), progress=lambda *a: progress.append(a))

    assert result.unregistered == [] and len(result.registered) == 12
    assert result.model_sizes == [12] and result.matcher == "exhaustive"
    assert result.K[0, 0] == pytest.approx(FOCAL, rel=0.01)
    assert result.mean_reprojection_error < 0.5 and len(result.points) > 1000
    assert result.warnings == []
    estimated = [f.pose for f in result.capture.frames]
    errors = pose_errors(estimated, truth)
    assert errors["rotation_deg_max"] < 1.0
    # Gravity: what separates the result from the truth is a turn about Z only.
    fit = umeyama(np.array([p[:3, 3] for p in estimated]), np.array([p[:3, 3] for p in truth]))
    assert np.degrees(np.arccos(np.clip(fit.rotation[2, 2], -1, 1))) < 1.0
    # Scale from the 1.5 m camera height and the floor seen in the sparse points.
    assert fit.scale == pytest.approx(1.0, abs=0.05)
    assert np.median([p[2, 3] for p in estimated]) == pytest.approx(1.5, abs=1e-6)
    assert result.capture.metric and result.alignment.scale_source == "camera height"
    # Every stage reported, and the bar of each stage reached its end.
    stages = {stage: (done, total) for stage, done, total in progress}
    assert set(stages) == {"poses: downscale photos", "poses: SIFT features", "poses: matching", "poses: mapping"}
    assert all(done == total for done, total in stages.values())
    assert "registered 12 of 12" in result.report


def test_dim_low_contrast_photos_get_their_features_found_again(room_photos, tmp_path):
    """A dim, soft room (a twelfth of the contrast, slightly blurred: plain walls in poor light): at COLMAP's default
    contrast threshold SIFT finds too few features to chain the views; the worker extracts them again
    at a lower threshold, says so, and every photo is posed."""
    folder, truth = room_photos
    for path in sorted(folder.glob("*.png")):
        image = cv2.GaussianBlur(cv2.imread(str(path)).astype(np.float32), (0, 0), 1.5)
        cv2.imwrite(str(tmp_path / path.name), np.clip(0.08 * image + 40, 0, 255).astype(np.uint8))
    result = estimate_poses(photo_capture(tmp_path, K), SfmOptions(intrinsics="fixed"))
    note = next((n for n in result.notes if n.startswith("few features")), f"no note in {result.notes}")
    before, after = (float(w) for w in re.findall(r"\((\d+)(?: features)? per photo", note))
    assert before < 500 < after
    assert len(result.registered) == 12
    assert pose_errors([f.pose for f in result.capture.frames], truth)["rotation_deg_max"] < 1.0
    # Well-textured photos keep COLMAP's default threshold.
    assert not any("few features" in n for n in estimate_poses(photo_capture(folder, K), SfmOptions(intrinsics="fixed")).notes)


def test_small_soft_photos_with_too_few_features_to_pose_precisely_get_more(room_photos, tmp_path):
    """Photos that chain fine but keep under 1,200 features (softened, a third of the contrast: about
    900 per photo at 320 x 240) are extracted again for SfM, as the demo's small photos are: their weakest
    views are posed from too few matches otherwise. The note says so, with the counts before and after."""
    folder, truth = room_photos
    for path in sorted(folder.glob("*.png")):
        image = cv2.GaussianBlur(cv2.imread(str(path)).astype(np.float32), (0, 0), 1.5)
        cv2.imwrite(str(tmp_path / path.name), np.clip(0.3 * image + 0.7 * 128, 0, 255).astype(np.uint8))
    result = estimate_poses(photo_capture(tmp_path, K), SfmOptions(intrinsics="fixed"))
    note = next((n for n in result.notes if n.startswith("few features")), f"no note in {result.notes}")
    before, after = (float(w) for w in re.findall(r"\((\d+)(?: features)? per photo", note))
    assert 500 < before < 1200 < after
    assert len(result.registered) == 12
    assert pose_errors([f.pose for f in result.capture.frames], truth)["rotation_deg_max"] < 1.0


def test_mapping_runs_again_while_fewer_than_half_the_photos_are_posed(tmp_path):
    """Three rooms with nothing in common, 5 photos each: no run can pose more than a third, so the
    mapper runs three times (it is randomised: on weakly matched photos another run poses more), says
    so, and keeps the best run."""
    poses = true_poses()[:5]
    for room in range(3):
        faces = room_faces(np.random.default_rng(100 + room))
        for k, pose in enumerate(poses):
            cv2.imwrite(str(tmp_path / f"{room}{k:02d}.png"), render(pose, faces))
    result = estimate_poses(photo_capture(tmp_path, K), SfmOptions(intrinsics="fixed"))
    assert len(result.registered) == 5 and result.model_sizes[0] == 5
    note = next((n for n in result.notes if n.startswith("mapping ran")), f"no note in {result.notes}")
    assert note.startswith("mapping ran 3 times (few photos posed: 5, 5, 5 of 15)"), note
    # The split is reported with the photos of each group, and nothing links the rooms.
    split = next((w for w in result.warnings if "separate groups" in w), f"no split warning in {result.warnings}")
    kept = result.registered[0][0]
    assert f"only the largest is used ({kept}00.png to {kept}04.png)" in split, split
    for room in {"0", "1", "2"} - {kept}:
        assert f"{room}00.png to {room}04.png (5 photos) is left out: where the capture passes from" in split, split
    assert split.count("no photo pair links the two groups") == 2, split


def test_fixed_intrinsics_sequential_matching_and_downscaling(room_photos):
    """A calibrated capture keeps its K exactly; poses come from 3/4-size photos."""
    folder, truth = room_photos
    capture = photo_capture(folder, K_known=K, format="colmap")
    options = SfmOptions(matcher="sequential", sequential_overlap=6, max_side=240, align=False)
    result = estimate_poses(capture, options)

    assert result.scaled_size == (240, 180)
    assert result.camera_model == "PINHOLE (fixed)"
    assert all(np.array_equal(f.K, K) for f in result.capture.frames)
    assert result.matcher == "sequential" and len(result.registered) >= 11
    posed = [(f.pose, truth[i]) for i, f in enumerate(result.capture.frames) if f.pose is not None]
    assert pose_errors([p for p, _ in posed], [t for _, t in posed])["rotation_deg_max"] < 1.0


def _matched_pairs(database: Path) -> set[tuple[int, int]]:
    """Photo index pairs (i < j, capture order) COLMAP verified in `database` (names are the indices)."""
    import pycolmap

    with pycolmap.Database.open(str(database)) as db:
        index = {image.image_id: int(Path(image.name).stem) for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
    pairs = set()
    for pair_id, count in zip(pair_ids, inliers):
        if count >= 15:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            pairs.add(tuple(sorted((index[a], index[b]))))
    return pairs


def test_sequential_matching_finds_the_same_place_far_apart_in_the_walk(room_photos, tmp_path):
    """A walk round the room ends where it began. Sequential matching pairs each photo with the next
    ones only (and at gaps of 2, 4, 8: COLMAP's quadratic overlap), so the last photo never meets the
    first; loop detection, with a vocabulary tree trained on the photos' own features (COLMAP's would
    be a download, impossible offline), matches them too."""
    folder, _ = room_photos
    sequential_gaps = {1, 2, 4, 8}
    found = {}
    for loops in (False, True):
        work = tmp_path / f"loops_{loops}"
        options = SfmOptions(matcher="sequential", sequential_overlap=1, loop_detection=loops, align=False, work_dir=work)
        result = estimate_poses(photo_capture(folder), options)
        assert len(result.registered) >= 10
        found[loops] = {(i, j) for i, j in _matched_pairs(work / "database.db") if j - i not in sequential_gaps}
        assert (work / "vocabulary_tree.bin").is_file() == loops
    assert not found[False]
    # Photos 0 and 11 (and 1 and 11, 0 and 10) stand side by side at the loop's closing.
    assert found[True] & {(0, 11), (1, 11), (0, 10)}, found[True]


def test_photos_far_apart_in_the_walk_need_strong_evidence_to_be_matched(tmp_path):
    """A loop pair as weak as the look-alike corridors' false ones is forgotten before mapping; a strong
    one and weak neighbours stay."""
    import pycolmap

    from engine.poses.sfm_worker import FAR_PAIR_MIN_INLIERS, drop_weak_far_pairs

    database = tmp_path / "database.db"
    with pycolmap.Database.open(str(database)) as db:
        camera = db.write_camera(pycolmap.Camera(model="SIMPLE_PINHOLE", width=64, height=48, params=[100, 32, 24]))
        ids = [db.write_image(pycolmap.Image(name=f"{i:06d}.jpg", camera_id=camera)) for i in range(40)]
        for (i, j), count in {(0, 25): FAR_PAIR_MIN_INLIERS - 4, (1, 30): FAR_PAIR_MIN_INLIERS + 10, (5, 6): 16,
                              (7, 12): 20}.items():
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = 2  # calibrated
            geometry.inlier_matches = np.array([[k, k] for k in range(count)], dtype=np.uint32)
            db.write_two_view_geometry(ids[i], ids[j], geometry)

    assert drop_weak_far_pairs(database, overlap=10) == 1
    assert _matched_pairs(database) == {(1, 30), (5, 6), (7, 12)}


def distort(image: np.ndarray, k1: float) -> np.ndarray:
    """The photo a lens with radial term k1 (x_d = x (1 + k1 r^2), normalised by K) would take."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    xd, yd = (cols + 0.5 - K[0, 2]) / FOCAL, (rows + 0.5 - K[1, 2]) / FOCAL
    xu, yu = xd.copy(), yd.copy()
    for _ in range(20):  # fixed point of x_u = x_d / (1 + k1 |x_u|^2)
        factor = 1 + k1 * (xu**2 + yu**2)
        xu, yu = xd / factor, yd / factor
    map_x = (xu * FOCAL + K[0, 2] - 0.5).astype(np.float32)  # OpenCV samples at integer centres
    map_y = (yu * FOCAL + K[1, 2] - 0.5).astype(np.float32)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def test_strong_lens_distortion_is_estimated_and_removed(room_photos, tmp_path):
    folder, truth = room_photos
    distorted = tmp_path / "distorted"
    distorted.mkdir()
    for photo in sorted(folder.glob("*.png")):
        cv2.imwrite(str(distorted / photo.name), distort(cv2.imread(str(photo)), 0.08))
    result = estimate_poses(photo_capture(distorted), SfmOptions(cache_dir=tmp_path / "cache", align=False))

    assert result.radial_distortion[0] == pytest.approx(0.08, abs=0.01)
    assert len(result.registered) == 12 and any("undistorted" in note for note in result.notes)
    frame = result.capture.frames[5]
    assert (tmp_path / "cache") in frame.image_path.parents
    assert pose_errors([f.pose for f in result.capture.frames], truth)["rotation_deg_max"] < 1.0
    # The undistorted photo is the pinhole photo seen through the new K: K_new K^-1 maps one onto the other.
    undistorted = cv2.imread(str(frame.image_path), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    pinhole = cv2.imread(str(folder / "005.png"), cv2.IMREAD_GRAYSCALE)
    half = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])  # to OpenCV's integer pixel centres
    H = half @ frame.K @ np.linalg.inv(K) @ np.linalg.inv(half)
    expected = cv2.warpPerspective(pinhole, H, (WIDTH, HEIGHT)).astype(np.float32)
    inner = (slice(20, HEIGHT - 20), slice(20, WIDTH - 20))
    assert np.abs(undistorted[inner] - expected[inner]).mean() < 12  # unrelated texture differs by ~70


def test_blank_photos_fail_clearly(tmp_path):
    for k in range(5):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.full((HEIGHT, WIDTH, 3), 128, np.uint8))
    with pytest.raises(PoseError) as error:
        estimate_poses(photo_capture(tmp_path))
    message = str(error.value)
    assert str(tmp_path) in message and "0 features per photo" in message and "overlap" in message


def test_unreadable_photo_is_named(tmp_path):
    cv2.imwrite(str(tmp_path / "0.png"), np.full((HEIGHT, WIDTH, 3), 128, np.uint8))
    (tmp_path / "1.png").write_bytes(b"not a png")
    with pytest.raises(PoseError, match=r"1\.png"):
        estimate_poses(photo_capture(tmp_path))


def test_matcher_and_intrinsics_choice(tmp_path):
    frames = [Frame(tmp_path / f"{i}.jpg", 640, 480, None) for i in range(61)]
    assert choose_matcher(Capture(tmp_path, "images", frames[:60]), SfmOptions()) == "exhaustive"
    assert choose_matcher(Capture(tmp_path, "images", frames), SfmOptions()) == "sequential"
    assert choose_matcher(Capture(tmp_path, "video", frames[:5]), SfmOptions()) == "sequential"
    assert choose_matcher(Capture(tmp_path, "video", frames[:5]), SfmOptions(matcher="exhaustive")) == "exhaustive"
    with pytest.raises(PoseError, match="matcher"):
        choose_matcher(Capture(tmp_path, "images", frames), SfmOptions(matcher="vocab"))

    with_K = [Frame(f.image_path, 640, 480, K.copy()) for f in frames[:3]]
    assert intrinsics_mode(Capture(tmp_path, "images", frames[:3]), SfmOptions())[0] == "estimate"
    assert intrinsics_mode(Capture(tmp_path, "images", with_K), SfmOptions())[0] == "prior"  # EXIF guess
    assert intrinsics_mode(Capture(tmp_path, "transforms", with_K), SfmOptions())[0] == "fixed"
    mixed = with_K[:2] + frames[2:3]
    assert intrinsics_mode(Capture(tmp_path, "images", mixed), SfmOptions())[0] == "estimate"
    with pytest.raises(PoseError, match="one K"):
        intrinsics_mode(Capture(tmp_path, "images", mixed), SfmOptions(intrinsics="fixed"))


def test_cli_writes_a_capture_the_loaders_read_back(room_photos, tmp_path):
    from engine.__main__ import main
    from engine.capture import load_capture

    folder, truth = room_photos
    out = tmp_path / "posed"
    assert main(["poses", str(folder), "--out", str(out), "--max-side", "320", "--quiet",
                 "--known-distance", "000.png", "006.png", "2.4"]) == 0
    posed = load_capture(out)
    assert posed.format == "scannet" and posed.metric and len(posed.frames) == 12
    assert [f.name for f in posed.frames] == [f"{k:03d}.png" for k in range(12)]
    errors = pose_errors([f.pose for f in posed.frames], truth)
    assert errors["rotation_deg_max"] < 1.0
    assert errors["scale"] == pytest.approx(1.0, abs=0.02)  # cameras 0 and 6 are 2.4 m apart

    import pycolmap

    model = pycolmap.Reconstruction(str(out / "colmap"))
    assert model.num_reg_images() == 12 and model.num_points3D() > 1000
    image = next(im for im in model.images.values() if im.name == "003.png")
    cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
    assert np.allclose(np.linalg.inv(cam_from_world), posed.frames[3].pose, atol=1e-9)


if __name__ == "__main__":  # write the synthetic photos somewhere to look at them
    target = Path(sys.argv[1])
    target.mkdir(parents=True, exist_ok=True)
    room = room_faces(np.random.default_rng(7))
    for index, pose in enumerate(true_poses()):
        cv2.imwrite(str(target / f"{index:03d}.png"), render(pose, room))


def test_the_mappers_error_filter_follows_the_photos_size():
    """COLMAP's 4 px is for photos of 1,000 px and more; smaller photos get a filter as sharp in angle,
    down to 1 px, and larger ones keep COLMAP's own."""
    from engine.poses.sfm_worker import mapper_max_error_px

    assert mapper_max_error_px(1024) == 4.0 and mapper_max_error_px(4000) == 4.0
    assert mapper_max_error_px(320) == pytest.approx(1.28)
    assert mapper_max_error_px(640) == pytest.approx(2.56)
    assert mapper_max_error_px(160) == 1.0


def test_a_bent_model_is_mapped_again_and_cut_if_it_stays_bent(room_photos, monkeypatch):
    """The bend itself is found by the photos' vertical lines (test_bends.py); here `find_bend` says
    what it found, and SfM maps the same matches again, keeps a straight model, or cuts the last one."""
    from engine.poses import sfm
    from engine.poses.bends import Bend

    folder, truth = room_photos
    calls: list[int] = []

    def bent_first(frames):
        calls.append(len(frames))
        return Bend(list(range(6)), list(range(6, 12)), [(6, 11)], [8.0, 8.0, 8.0]) if len(calls) == 1 else None

    monkeypatch.setattr(sfm, "find_bend", bent_first)
    straight = estimate_poses(photo_capture(folder), SfmOptions(align=False))

    assert calls == [12, 12]  # mapped twice, the second model straight
    assert len(straight.registered) == 12 and not any("bend" in w for w in straight.warnings)
    assert any("mapping ran again 1 time(s)" in n for n in straight.notes)
    assert "map again" in straight.timings
    assert pose_errors([f.pose for f in straight.capture.frames], truth)["rotation_deg_max"] < 1.0

    calls.clear()
    monkeypatch.setattr(sfm, "find_bend", lambda frames: calls.append(len(frames)) or Bend(
        list(range(6)), list(range(6, 12)), [(6, 11)], [8.0, 8.0, 8.0]))
    cut = estimate_poses(photo_capture(folder), SfmOptions(align=False))

    assert calls == [12] * (1 + sfm.BENT_REMAPS)
    assert cut.registered == [f"{k:03d}.png" for k in range(6)]
    assert cut.unregistered == [f"{k:03d}.png" for k in range(6, 12)]
    assert [f.pose is None for f in cut.capture.frames] == [False] * 6 + [True] * 6
    assert any("only the 6 photos 000.png..005.png are used" in w and "the mapper ran 3 times, bent every time" in w
               for w in cut.warnings)
    assert len(cut.points) < len(straight.points)  # the cut photos' points went with them
