"""The benchmark's pure parts: the memory model and the report table (the runs themselves are
exercised end to end by tests/engine/recon/test_driver.py)."""

from __future__ import annotations

from engine.bench import (DEPTH_KEYS, FULL_CASES, QUICK_CASES, compare_with_stereo, compare_with_vortx, machine_info,
                          markdown, network_seconds, profile_markdown, projected_memory, stereo_cases)
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


def test_stereo_runs_once_per_capture_against_vortx_at_its_most_views():
    chosen = stereo_cases(FULL_CASES)
    assert [c.name for c in chosen] == ["N=60, 2 m region", "N=20, 1.5 m region", "N=20, 3 m region"]
    assert stereo_cases(QUICK_CASES) == list(QUICK_CASES)


def _stereo_run(cpu_total: float, peak_mb: float) -> dict:
    return {"case": "N=60, 2 m room", "keyframes": 64, "references": 64,
            "timings_s": {"stereo depth": 30.0, "TSDF fusion": 1.5, "mesh": 0.2, "colour": 2.0, "evidence": 0.4, "total": 40.0},
            "cpu_timings_s": {"total": cpu_total}, "keyframes_per_s": 1.6, "peak_rss_bytes": int(peak_mb * 2**20)}


def test_stereo_budget_is_twice_the_cpu_time_and_one_gib_more_memory():
    vortx = [{"case": "N=20, 2 m room", "cpu_timings_s": {"total": 10.0}, "timings_s": {"total": 8.0}, "peak_rss_bytes": 500 * 2**20},
             {"case": "N=60, 2 m room", "cpu_timings_s": {"total": 46.0}, "timings_s": {"total": 34.0}, "peak_rss_bytes": 1100 * 2**20}]
    inside = compare_with_vortx(_stereo_run(80.0, 1500), vortx)
    assert inside == {"vortx_case": "N=60, 2 m room", "cpu_ratio": round(80 / 46, 3), "wall_ratio": round(40 / 34, 3),
                      "extra_peak_rss_bytes": 400 * 2**20, "within_budget": True}
    assert not compare_with_vortx(_stereo_run(93.0, 1500), vortx)["within_budget"]  # > 2x the CPU time
    assert not compare_with_vortx(_stereo_run(80.0, 2200), vortx)["within_budget"]  # > 1 GiB more


def test_report_table_shows_the_stereo_stages():
    run = _stereo_run(80.0, 1500)
    run["versus_vortx"] = {"cpu_ratio": 1.74, "extra_peak_rss_bytes": 400 * 2**20, "within_budget": True}
    report = {"machine": machine_info(), "runs": [], "stereo_runs": [run], "sparse_vs_dense": [],
              "projected_memory": {"room_m": [10, 10, 3], "views": 60, "keyframes": 500, "image_size": [640, 480]}}
    table = markdown(report)
    assert "| stereo depth s | TSDF fusion s | mesh s | colour s | evidence s |" in table
    assert "| N=60, 2 m room | 64 | 64 | 30.0 | 1.5 | 0.2 | 2.0 | 0.4 | 40.0 (80.0) | 1.60 | 1500 | 1.74x | +400 | yes |" in table


def test_report_table_shows_the_texture_bake():
    texture = {"case": "N=20, 1.5 m region", "texture_size": 2048, "photos": 24, "faces_in": 30000, "faces": 30000,
               "charts": 812, "atlas_utilisation": 0.7, "texels": 2_900_000, "texels_seen": 2_030_000,
               "timings_s": {"atlas": 12.0, "texels": 1.5, "bake": 9.25, "total": 23.0}, "cpu_s": 24.5,
               "peak_rss_bytes": 900 * 2**20, "start_rss_bytes": 600 * 2**20}
    report = {"machine": machine_info(), "runs": [], "stereo_runs": [], "texture_runs": [texture], "sparse_vs_dense": [],
              "projected_memory": {"room_m": [10, 10, 3], "views": 60, "keyframes": 500, "image_size": [640, 480]}}
    table = markdown(report)
    assert "| texture px | photos | faces (in) | charts | texels (seen) | atlas s | texels s | bake s |" in table
    assert "| N=20, 1.5 m region | 2048 | 24 | 30000 (30000) | 812 | 2900000 (70 %) | 12.0 | 1.5 | 9.2 | 23.0 (24.5) | 900 (+300) |" in table


def _evidence_run(cpu_total: float, peak_mb: float, keyframes: int = 64) -> dict:
    timings = {"keyframes": 0.1, "stereo depth": 30.0, "TSDF fusion": 1.5, "features": 3.0, "fusion 16 cm": 1.0,
               "3D CNN 16 cm": 0.5, "fusion 8 cm": 2.0, "3D CNN 8 cm": 1.0, "fusion 4 cm": 4.0, "3D CNN 4 cm": 2.5,
               "mesh": 0.2, "colour": 2.0, "evidence": 0.4, "total": 48.0}
    return {"case": "N=60, 2 m room", "weights": "untrained (recipe widths)", "keyframes": keyframes,
            "timings_s": timings, "cpu_timings_s": {"total": cpu_total}, "network_s": network_seconds(timings),
            "network_cpu_s": 20.0, "peak_rss_bytes": int(peak_mb * 2**20)}


def test_learned_method_budget_is_one_and_a_half_times_stereo_per_keyframe_and_one_gib_more():
    stereo = [_stereo_run(80.0, 1500)]
    assert network_seconds(_evidence_run(0, 0)["timings_s"]) == 3.0 + 1.0 + 0.5 + 2.0 + 1.0 + 4.0 + 2.5  # not "TSDF fusion"
    inside = compare_with_stereo(_evidence_run(110.0, 2400), stereo)
    assert inside == {"cpu_ratio_per_keyframe": round(110 / 80, 3), "extra_peak_rss_bytes": 900 * 2**20, "within_budget": True}
    assert not compare_with_stereo(_evidence_run(125.0, 2400), stereo)["within_budget"]  # > 1.5x per keyframe
    assert compare_with_stereo(_evidence_run(125.0, 2400, keyframes=128), stereo)["within_budget"]  # per keyframe
    assert not compare_with_stereo(_evidence_run(110.0, 2600), stereo)["within_budget"]  # > 1 GiB more
    run = _evidence_run(110.0, 2400)
    run["versus_stereo"] = compare_with_stereo(run, stereo)
    report = {"machine": machine_info(), "runs": [], "stereo_runs": [], "evidence_runs": [run], "sparse_vs_dense": [],
              "projected_memory": {"room_m": [10, 10, 3], "views": 60, "keyframes": 500, "image_size": [640, 480]}}
    assert ("| N=60, 2 m room | untrained (recipe widths) | 64 | 30.0 | 1.5 | 14.0 (20.0) | 2.2 | 48.0 (110.0) | 2400 "
            "| 1.38x | +900 | yes |") in markdown(report)


def test_report_table_shows_each_matcher_with_its_stages_and_seconds_per_keyframe():
    fast = {**_stereo_run(80.0, 1500), "matcher": "fast", "references": 64, "stereo_image_size": [200, 150]}
    patchmatch = {**_stereo_run(300.0, 1800), "matcher": "patchmatch", "references": 64, "stereo_image_size": [320, 240],
                  "stereo_stages_s": {"patchmatch": 150.0, "geometric consistency": 90.0, "depth filter": 4.0}}
    patchmatch["timings_s"] = {**patchmatch["timings_s"], "stereo depth": 256.0}
    fast["versus_vortx"] = {"cpu_ratio": 1.74, "extra_peak_rss_bytes": 0, "within_budget": True}
    report = {"machine": machine_info(), "runs": [], "stereo_runs": [fast], "matcher_runs": [patchmatch],
              "sparse_vs_dense": [], "projected_memory": {"room_m": [10, 10, 3], "views": 60, "keyframes": 500,
                                                          "image_size": [640, 480]}}
    table = markdown(report)
    assert "| N=60, 2 m room | fast | 64 | 200x150 | - | - | - | 30.0 | 0.47 |" in table
    assert "| N=60, 2 m room | patchmatch | 64 | 320x240 | 150.0 | 90.0 | 4.0 | 256.0 | 4.00 |" in table


def test_refine_profile_table_gives_each_stage_and_the_stretch_scales():
    from engine.bench import refine_markdown

    profile = {"capture": "/rooms/sun3d", "frames": 99, "adjusted_frames": 58, "points": 2275, "error_given_px": 1.82,
               "error_refined_px": 0.77, "stretch_scales": [1.0, 0.9992], "wall_s": 40.2,
               "timings_s": {"prepare": 0.9, "extract": 17.0, "match": 8.2, "triangulate": 1.3, "adjust": 6.3}}
    table = refine_markdown(profile).splitlines()
    assert table[0].count("|") == table[1].count("|") == table[2].count("|")
    assert "| sun3d | 99 (58) | 2275 | 1.82 -> 0.77 | 1.000 / 0.999 | 0.9 | 17.0 | 8.2 | 1.3 | 6.3 | 40.2 |" == table[2]


def test_patchmatch_profile_table_has_a_row_per_stage_and_the_depth_metrics():
    quality = {k: 0.5 for k in DEPTH_KEYS}
    profiles = [
        {"image_size": [160, 120], "overrides": {}, "cpu_s_per_keyframe": 2.0,
         "stages_cpu_s_per_keyframe": {"warp": 0.7, "geometric pass/warp": 0.3}, "quality": quality},
        {"image_size": [320, 240], "overrides": {"coarse_iterations": 1}, "cpu_s_per_keyframe": 8.0,
         "stages_cpu_s_per_keyframe": {"warp": 3.0, "NCC": 1.0}, "quality": quality},
    ]
    table = profile_markdown(profiles)
    lines = table.splitlines()
    assert "320x240 coarse_iterations=1" in lines[0]
    rows = {line.split("|")[1].strip(): line for line in lines[2:]}
    assert rows["warp"].count("0.700") == 1 and "3.000" in rows["warp"]
    assert "0.000" in rows["NCC"], "a stage one run lacks reads 0"
    # The geometric pass's stages come after the photometric ones.
    assert lines.index(rows["geometric pass/warp"]) > lines.index(rows["warp"])
    assert "**8.00**" in rows["**total**"] and all(k in rows for k in DEPTH_KEYS)
