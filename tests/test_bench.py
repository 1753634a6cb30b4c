"""The benchmark's pure parts: the memory model and the report table (the runs themselves are
exercised end to end by tests/test_recon_driver.py)."""

from __future__ import annotations

from engine.bench import machine_info, markdown, projected_memory
from engine.recon.memory_estimate import (CNN_BYTES_PER_VOXEL, box_room_surface_area, coarse_voxels, estimate_memory,
                                          keep_fraction_voxels, surface_band_voxels)


def test_feature_cache_and_level_terms_follow_the_shapes():
    est = estimate_memory((1000, 0, 0), keyframes=10, image_size=(640, 480), views=5, baseline=0)
    # Per frame: 80x30x40 + 40x60x80 + 24x120x160 values, fp16.
    assert est.components["feature_cache"] == 10 * (80 * 30 * 40 + 40 * 60 * 80 + 24 * 120 * 160) * 2
    assert est.components["fine_level"] == 0
    bigger = estimate_memory((1000, 0, 2_000_000), keyframes=10, image_size=(640, 480), views=5, baseline=0)
    assert bigger.components["fine_level"] > 2_000_000 * CNN_BYTES_PER_VOXEL[2]
    assert bigger.total == bigger.components["feature_cache"] + bigger.components["fine_level"]
    fp32 = estimate_memory((1000, 0, 0), 10, (640, 480), 5, fp16_features=False, baseline=0)
    assert fp32.components["feature_cache"] == 2 * est.components["feature_cache"]


def test_voxel_models():
    assert coarse_voxels((10, 10, 3), 0.04) == 63 * 63 * 19
    assert keep_fraction_voxels(1000, (0.5, 0.25)) == (1000, 4000, 8000)
    area = box_room_surface_area((10, 10, 3), furniture_factor=1.0)
    assert area == 320
    coarse, medium, fine = surface_band_voxels(10**9, area, 0.04)
    assert medium == int(8 * area * 3 / 0.16**2) and fine == int(8 * area * 4 / 0.08**2)
    # The band cannot keep more voxels than exist.
    assert surface_band_voxels(10, area, 0.04) == (10, 80, 640)


def test_report_table_and_projection():
    run = {"case": "N=20, 1 m room", "keyframes": 12, "views_per_tile_max": 9, "voxels": [100, 400, 1600], "occupied": [50, 200, 900],
           "timings_s": {"features": 1.0, "fusion 16 cm": 0.5, "fusion 8 cm": 0.25, "3D CNN 16 cm": 2.0, "mesh": 0.1,
                         "colour": 0.2, "total": 4.0},
           "cpu_timings_s": {"total": 3.0}, "keyframes_per_s": 3.0, "peak_rss_bytes": 700 * 2**20,
           "estimated_peak_bytes": 650 * 2**20}
    projection = projected_memory([run])
    name = next(k for k in projection if k.startswith("random weights"))
    assert "keep 0.50 / 0.50" in name and projection[name]["voxels"] == [75411, 301644, 1206576]
    sparse = {"grid": (8, 8, 8), "channels": 4, "pattern": "surface", "voxels": 10, "kernel_map_s": 0.1,
              "sparse_forward_s": 0.2, "dense_forward_s": 0.4, "speedup_forward": 2.0, "speedup_forward_backward": 1.5}
    table = markdown({"machine": machine_info(), "runs": [run], "sparse_vs_dense": [sparse], "projected_memory": projection})
    assert "| N=20, 1 m room | 12 | 9 | 100 / 400 / 1600 | 1.0 | 0.8 | 2.0 | 0.3 | 4.0 (3.0) | 3.00 | 700 (650) |" in table
    assert "| 8x8x8, 4 ch, surface | 10 |" in table and "GiB" in table
