"""The sparse-vs-dense benchmark used by `python -m engine bench` (tiny sizes: this checks the plumbing)."""

from __future__ import annotations

import torch

from engine.sparse.bench import bench_sparse_vs_dense, surface_coords


def test_surface_coords_is_a_one_voxel_shell_without_boxes():
    coords = surface_coords((6, 5, 4), num_boxes=0)
    on_boundary = ((coords == 0) | (coords == torch.tensor([5, 4, 3]))).any(dim=1)
    assert bool(on_boundary.all())
    assert len(coords) == 6 * 5 * 4 - 4 * 3 * 2  # everything but the interior


def test_bench_reports_timings_for_both_patterns():
    for occupancy in (None, 0.3):
        result = bench_sparse_vs_dense(grid=(10, 10, 6), channels=4, occupancy=occupancy, repeats=1)
        assert result["voxels"] > 0 and result["pairs"] >= result["voxels"]  # the centre offset alone pairs every voxel
        for key in ("kernel_map_s", "sparse_forward_s", "sparse_forward_backward_s", "dense_forward_s",
                    "dense_forward_backward_s", "speedup_forward", "speedup_forward_backward"):
            assert result[key] > 0, key
    assert "dense_forward_s" not in bench_sparse_vs_dense(grid=(6, 6, 6), channels=2, repeats=1, dense=False)
