"""Refining given poses from the command line: `engine poses CAPTURE --refine --out DIR` and
`engine reconstruct CAPTURE --refine-poses`.

The capture is 16 photos of the bundled demo room (320 x 240) in the ScanNet layout, with their true
poses perturbed on purpose (0.5-2 deg, a few cm, as a tracker would be off; the approach of
test_refine.py). Refined through the CLI and read back from the written folder, the poses agree with
the truth within 0.2 deg, frame to frame. `reconstruct --refine-poses` is checked for its plumbing
(the refined capture reaches the reconstruction, the report and the sidecar) with a stand-in
refinement, so the real one runs once per session (~20 s).
"""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from engine.__main__ import main
from engine.capture import load_capture
from engine.capture.model import Capture, Frame
from engine.capture.writers import write_scannet
from engine.poses import fit_pose_similarity, rotation_angle_deg
from fixtures_capture import perturbed_poses as perturbed, rotation_about

SAMPLE = REPO / "samples" / "demo_room"
COUNT = 16


@pytest.fixture(scope="module")
def perturbed_capture(tmp_path_factory) -> tuple[Path, list[np.ndarray], list[np.ndarray]]:
    """(ScanNet-layout folder with perturbed poses, true poses, given poses), in frame order."""
    if not (SAMPLE / "truth" / "pose").is_dir():
        pytest.skip(f"the demo sample is missing: {SAMPLE}")
    names = sorted(p.name for p in (SAMPLE / "images").glob("*.jpg"))[:COUNT]
    K = np.loadtxt(SAMPLE / "truth" / "intrinsic" / "intrinsic_color.txt")[:3, :3]
    truth = [np.loadtxt(SAMPLE / "truth" / "pose" / f"{Path(n).stem}.txt").reshape(4, 4) for n in names]
    given = perturbed(truth, np.random.default_rng(7), max_shift=0.003)  # a tracker's: turned, centres within 3 mm
    frames = [Frame(SAMPLE / "images" / n, 320, 240, K.copy(), g) for n, g in zip(names, given)]
    folder = tmp_path_factory.mktemp("perturbed") / "scan"
    write_scannet(Capture(SAMPLE / "images", "scannet", frames, metric=True), folder)
    return folder, truth, given


@pytest.fixture(scope="module")
def cli_refinement(perturbed_capture, tmp_path_factory):
    """One `engine poses --refine` run: (output folder, its stdout, exit status)."""
    folder, _, _ = perturbed_capture
    out = tmp_path_factory.mktemp("refined") / "out"
    buffer = io.StringIO()
    with redirect_stdout(buffer):
        status = main(["poses", str(folder), "--refine", "--out", str(out), "--quiet"])
    print(buffer.getvalue())
    return out, buffer.getvalue(), status


def _poses(capture: Capture) -> np.ndarray:
    return np.stack([f.pose for f in capture.frames])


def test_refine_from_the_cli_brings_perturbed_poses_back_within_a_quarter_of_a_degree(perturbed_capture, cli_refinement):
    _, truth, given = perturbed_capture
    out, stdout, status = cli_refinement
    assert status == 0
    true = np.stack(truth)
    before = [rotation_angle_deg(t[:3, :3].T @ g[:3, :3]) for t, g in zip(true, given)]
    assert min(before) > 0.5 and max(before) > 1.5  # the given poses are off by 0.5-2 deg

    written = load_capture(out)  # the ScanNet layout the CLI wrote
    assert written.format == "scannet" and len(written.frames) == COUNT
    refined = _poses(written)
    fit = fit_pose_similarity(refined, true)
    errors = [rotation_angle_deg(t[:3, :3].T @ fit.apply_pose(r)[:3, :3]) for r, t in zip(refined, true)]
    # The centres stay where they were given (up to 3 mm off at 1-3 m: up to 0.1 deg of what is left).
    assert max(errors) < 0.25 and np.median(errors) < 0.12, errors
    assert fit.scale == pytest.approx(1.0, abs=0.005)  # the metric scale of the given poses is kept

    # The COLMAP text model beside it holds the same cameras and the triangulated points.
    colmap = load_capture(out / "colmap", images_dir=out / "color", metric=True)
    np.testing.assert_allclose(_poses(colmap), refined, atol=1e-6)
    points = [l for l in (out / "colmap" / "points3D.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(points) > 300


def test_refine_report_gives_the_change_per_frame(perturbed_capture, cli_refinement):
    _, truth, given = perturbed_capture
    _, stdout, _ = cli_refinement
    assert "Pose refinement" in stdout and f"refined {COUNT} of {COUNT} posed frames" in stdout
    median = float(stdout.split("rotation changed by ")[1].split(" deg median")[0])
    before = [rotation_angle_deg(t[:3, :3].T @ g[:3, :3]) for t, g in zip(truth, given)]
    assert median == pytest.approx(np.median(before), abs=0.5)  # the perturbation undone
    assert "cm max" in stdout and "wrote 16 posed photos" in stdout
    assert "camera positions held" in stdout and "scale 1.000" in stdout and "adjust" in stdout.split("time:")[1]
    assert "structure from motion replaces them" not in stdout


def test_refine_needs_a_capture_with_poses(tmp_path, capsys):
    from fixtures_capture import write_photo_folder

    write_photo_folder(tmp_path / "photos", 4)
    assert main(["poses", str(tmp_path / "photos"), "--refine", "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "--refine refines the poses a capture has" in err and "0 of 4 frames" in err
    assert not (tmp_path / "out").exists()


def test_reconstruct_refine_poses_uses_and_reports_the_refined_poses(perturbed_capture, tmp_path, monkeypatch, capsys):
    """The refinement runs between loading and reconstructing; its report goes to stderr and the sidecar."""
    import engine.poses
    from engine.poses.refine import FrameChange, RefineResult
    from engine.recon import driver

    folder, truth, _ = perturbed_capture
    calls = []

    def fake_refine(capture, options=None, progress=None, cancel=None):
        calls.append(capture)
        frames = [f.__class__(f.image_path, f.width, f.height, f.K, t) for f, t in zip(capture.frames, truth)]
        changes = [FrameChange(f.name, 1.0 + 0.1 * k, 0.02, "refined") for k, f in enumerate(capture.frames[:-1])]
        changes.append(FrameChange(capture.frames[-1].name, 12.0, 0.5, "refused", "refinement moved it by 12.0 deg"))
        return RefineResult(capture.with_frames(frames), changes, "m", np.zeros((0, 3)), np.zeros((0, 3), np.uint8),
                            mean_reprojection_error=0.4, error_given_px=1.6, scaled_size=(320, 240), adjusted_frames=16,
                            adjustment="camera positions held", focal_scale=[1.0], timings={"adjust": 1.0},
                            warnings=["1 frame(s) would have moved too far and keep their given pose"])

    seen = []

    class Stop(Exception):
        pass

    def fake_reconstruct(capture, settings, progress=None, cancel=None, plan=None):
        seen.append(capture)
        raise Stop

    monkeypatch.setattr(engine.poses, "refine_poses", fake_refine)
    monkeypatch.setattr(driver, "reconstruct", fake_reconstruct)
    with pytest.raises(Stop):
        main(["reconstruct", str(folder), "--refine-poses", "--out", str(tmp_path / "mesh.ply"), "--quiet"])
    assert len(calls) == 1
    np.testing.assert_allclose(_poses(seen[0]), np.stack(truth), atol=1e-12)  # metric: no alignment on top
    err = capsys.readouterr().err
    assert "Pose refinement" in err and "refused: " in err and "keep their given pose" in err

    # Without the flag the check against the photos finds these poses off (a degree or two), so they are
    # refined all the same; --keep-poses keeps them as given.
    calls.clear()
    with pytest.raises(Stop):
        main(["reconstruct", str(folder), "--out", str(tmp_path / "mesh.ply"), "--quiet"])
    assert len(calls) == 1
    calls.clear()
    with pytest.raises(Stop):
        main(["reconstruct", str(folder), "--keep-poses", "--out", str(tmp_path / "mesh.ply"), "--quiet"])
    assert not calls
    assert "look off" in capsys.readouterr().err  # kept as given: the warning instead


def test_reconstruct_sidecar_records_the_refinement(tmp_path, monkeypatch):
    """The sidecar's "poses" entry: source, scale and the refinement's numbers and refused frames."""
    from engine.poses.prepare import PreparedCapture
    from engine.poses.refine import FrameChange, RefineResult
    from engine.poses.stretches import StretchScale

    changes = [FrameChange("a.jpg", 0.5, 0.01, "refined"), FrameChange("b.jpg", 1.5, 0.03, "refined"),
               FrameChange("c.jpg", 20.0, 2.0, "refused", "refinement moved it by 20.0 deg")]
    result = RefineResult(None, changes, "m", np.zeros((5, 3)), np.zeros((5, 3), np.uint8), mean_reprojection_error=0.4,
                          error_given_px=1.5, scaled_size=(320, 240), adjusted_frames=3, adjustment="camera positions held",
                          focal_scale=[1.0], stretches=[StretchScale("stretch", "a.jpg", "c.jpg", 3, 1.0)],
                          timings={"adjust": 2.0})
    summary = PreparedCapture(None, "metric capture", "metric capture: poses kept as they are", refinement=result).summary()
    json.dumps(summary)  # JSON-ready
    assert summary["source"] == "given" and summary["refined"] and summary["scale_source"] == "metric capture"
    refinement = summary["refinement"]
    assert refinement["refined"] == 2 and refinement["posed_frames"] == 3
    assert refinement["rotation_deg_median"] == pytest.approx(1.0) and refinement["rotation_deg_max"] == pytest.approx(1.5)
    assert refinement["translation_max"] == pytest.approx(0.03) and refinement["units"] == "m"
    assert refinement["refused"] == {"c.jpg": "refinement moved it by 20.0 deg"} and refinement["points"] == 5
    assert refinement["given_reprojection_error_px"] == 1.5 and refinement["stretch_scales"][0]["scale"] == 1.0
    assert refinement["timings_s"] == {"adjust": 2.0} and refinement["kept_given"] == ""
