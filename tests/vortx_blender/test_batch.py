"""One capture of the batch inside Blender (vortx_blender/batch.py): how an operator's outcome and
its reports become the batch's error and warnings. The whole run: tests/scripts/test_vortx_batch*.py."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from fixtures_capture import write_photo_folder


class FakeOperator:
    """Stands in for a bpy.ops operator: poll(), and a call that prints Blender's report lines."""

    def __init__(self, outcome: set[str], printed: str = "", error: str = "", poll: bool = True) -> None:
        self.outcome, self.printed, self.error, self.can_run = outcome, printed, error, poll

    def poll(self) -> bool:
        return self.can_run

    def __call__(self, **kwargs) -> set[str]:
        print(self.printed, end="")
        if self.error:
            raise RuntimeError(self.error)
        return self.outcome


@pytest.fixture
def batch(blender):
    return importlib.import_module(f"{blender.__name__}.vortx_blender.batch")


def test_an_operators_warnings_are_kept_and_its_error_is_the_batch_error(batch, capsys) -> None:
    warnings: list[str] = []
    batch.run_operator("Import Capture", FakeOperator({"FINISHED"}, "Info: 3 frames\nWarning: photo 2 is blurry\n"), warnings)
    assert warnings == ["photo 2 is blurry"]
    assert "Warning: photo 2 is blurry" in capsys.readouterr().out  # still printed, as Blender prints it
    with pytest.raises(batch.BatchError, match=r"^no frame has a pose$"):
        batch.run_operator("Reconstruct", FakeOperator(set(), "Warning: few photos\n", "Error: no frame\n has a pose"), warnings)
    assert warnings == ["photo 2 is blurry", "few photos"]  # a failing operator's warnings are kept too
    with pytest.raises(batch.BatchError, match=r"Estimate Poses did not finish \(CANCELLED\)"):
        batch.run_operator("Estimate Poses", FakeOperator({"CANCELLED"}))
    with pytest.raises(batch.BatchError, match="Refine Poses cannot run now"):
        batch.run_operator("Refine Poses", FakeOperator({"FINISHED"}, poll=False))


def test_a_folder_of_captures_is_expanded_only_for_an_output_folder(batch, tmp_path: Path) -> None:
    for name in ("kitchen", "hall"):
        write_photo_folder(tmp_path / "rooms" / name, 3)
    rooms = str(tmp_path / "rooms")
    assert [p.name for p in batch.captures_to_run(batch.parse_arguments([rooms, "--out", str(tmp_path / "out")]))] == ["hall", "kitchen"]
    assert batch.captures_to_run(batch.parse_arguments([rooms, "--out", str(tmp_path / "one.blend")])) == [Path(rooms)]


def test_a_gpu_asked_for_where_pytorch_sees_none_is_refused_with_what_to_do(batch, empty_scene, monkeypatch) -> None:
    args = batch.parse_arguments(["cap", "--out", "a.blend", "--device", "cuda"])

    def no_cuda(settings, recon) -> None:
        raise ValueError("enum 'CUDA' not found")

    monkeypatch.setattr(batch, "write_scene_settings", no_cuda)
    with pytest.raises(batch.BatchError, match="--device cuda: PyTorch sees no CUDA GPU here"):
        batch.apply_recon_settings(empty_scene.vortx, args.settings)
    assert empty_scene.vortx.weights_source == "DEFAULT" and empty_scene.vortx.result_mode == "REPLACE"
