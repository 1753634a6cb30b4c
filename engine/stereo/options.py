"""The knobs of plane-sweep stereo. Starting points measured outside the product (stereo-evidence.md:
160 px, 64 inverse-depth planes, 4 sources, 5 x 5 NCC, NCC >= 0.3); the defaults here were tuned on
the demo sample with true poses (MODEL.md, docs/results.md): 200 px, 80 planes, 7 x 7 NCC, NCC >= 0.5.
PatchMatch, the default matcher, was tuned on real photos since (issue 44): 240 px, two iterations at
120 px and one at 240, geometric weight 0.4."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import VortxError


MATCHER_PATCHMATCH = "patchmatch"  # per-pixel slanted planes (patchmatch.py)
MATCHER_FAST = "fast"  # fronto-parallel plane sweep (sweep.py)
STEREO_MATCHERS = (MATCHER_PATCHMATCH, MATCHER_FAST)


@dataclass(frozen=True)
class StereoOptions:
    # PatchMatch by default since issue 34: on real rooms its surfaces are clean (SUN3D: normals 0.31
    # against the sweep's 0.20, a third of the floaters) at about 2 s per keyframe on 2 cores.
    matcher: str = MATCHER_PATCHMATCH  # STEREO_MATCHERS
    # Stereo image long side in pixels, independent of the network's image size. 240 with PatchMatch's
    # lighter schedule below, not 200 with the heavier one: the same time, finer depth (docs/experiments.md,
    # "Finer pixels, fewer iterations").
    long_side: int = 240
    planes: int = 80  # depth hypotheses of the sweep, uniform in inverse depth
    refine_planes: int = 8  # hypotheses of each per-pixel refinement sweep over +-1 step of the previous (0 = off)
    refine_rounds: int = 1  # refinement sweeps (a second round measured no better on the demo sample)
    sources: int = 4  # source views per reference
    best_k: int = 2  # aggregate the best k source scores: robust to a source that is occluded
    window: int = 7  # NCC window side in pixels (odd); 7 beat 5 and 9 on the demo sample
    min_ncc: float = 0.5  # depths whose aggregated NCC is below this are dropped
    min_depth: float = 0.2  # metres: the nearest plane
    max_depth: float = 5.0  # metres: the farthest plane (the depth range is narrowed per view to the scene)
    ground_planes: int = 0  # horizontal planes (world z) swept as well, for floors and tables at grazing angles (0 = off)
    clean_depth: bool = False  # drop speckles and take a 5 x 5 median of each depth map (depth_filters.py)
    # Keyframes used as references, evenly spaced when there are more. 80, not 100: on a 200-frame
    # 640 x 480 capture (100 keyframes, refined poses) 80 references matched in 98 s instead of 115-125,
    # the whole default path 145 s instead of 163, F 0.52 either way (docs/experiments.md, "A 200-frame
    # capture in 2.5 minutes"). Captures of up to 80 keyframes (the demo room, SUN3D) do not change.
    max_references: int = 80
    consistency_views: int = 0  # keep a depth only if this many other references agree (0 = off)
    evidence_fusion: bool = False  # weigh each depth by its evidence in fusion (fused_tsdf.fuse_stereo_evidence)
    min_support: int = 1  # with evidence fusion: views that must agree before a voxel can carry a surface
    piece_min_views: int = 0  # with evidence fusion: drop mesh pieces that fewer views agree on anywhere (0 = keep all)
    # PatchMatch (matcher "patchmatch"): patchmatch_views.PatchMatchSchedule; `sources`, `min_ncc`,
    # `long_side` and `consistency_views` (the geometric filter's agreeing views) are shared with the sweep.
    scales: int = 2  # image sizes, each half the next, ending at long_side
    pm_window: int = 9  # window side in pixels, sampled every 2nd pixel
    # Two coarse and one fine iteration at 240 px, not 3 and 2 at 200 px: SUN3D's maps within 5 % 0.663 ->
    # 0.685 (3 and 2 at 240 px: 0.685 too, at 1.3x the time); the mesh's Finish Room F 0.469 -> 0.537 there,
    # the 200-frame room 0.730 -> 0.749, in about the time of before; the corridor against its LiDAR level
    # within its run-to-run spread; the demo room's recorded run 0.836-0.840 -> 0.822, `make demo` 0.825 ->
    # 0.828 (docs/experiments.md, "Finer pixels, fewer iterations").
    coarse_iterations: int = 2
    fine_iterations: int = 1
    geometric_passes: int = 1
    # Cost per pixel of reprojection error into the sources' depth maps (ACMM: 0.2, capped at 3 px). 0.4
    # at 240 px: SUN3D's maps within 5 % 0.675 -> 0.684, the corridor's Finish Room 0.423 -> 0.442 with
    # 80 maps (docs/experiments.md, "Finer pixels, fewer maps").
    geometric_weight: float = 0.4
    seed_planes: int = 0  # PatchMatch starts from a fronto-parallel sweep over this many planes at its coarsest scale (0 = random planes)
    # PatchMatch starts from the sparse points' triangulated depth where they cover a view (sparse_seed.py),
    # as OpenMVS does. Measured (docs/experiments.md, "A seed from the sparse points"): room_05002 F
    # +0.03 over three runs each, room_07002 0.641 -> 0.656, SUN3D, the demo and room_05001 within
    # their noise, no time lost; one fine iteration fewer with it costs SUN3D 0.015 F, so the schedule stays.
    sparse_seed: bool = True
    # ACMP's planar prior (planar_prior.py): weakly textured pixels take the plane of a triangle of
    # confident pixels, and keep it when two other views confirm it. Off: on SUN3D, the demo room and
    # the realistic room_05002 it moved F within one run's noise (-0.008 / -0.001 / +0.002 with Finish
    # Room; SUN3D's repeat +0.013), recall likewise, maps 0.1-0.4 points more complete, at 3-16 % more
    # stereo CPU time (SUN3D 2.58 -> 3.00 s per keyframe): at 200 px the supports' depths are too noisy
    # for 5 px triangles and the pixels left empty are seldom under one (docs/experiments.md, "ACMP
    # planar prior (issue 34)").
    planar_prior: bool = False
    # Each PatchMatch depth smoothed along its neighbours' planes where they agree within 5 % (plane_smoothing.py):
    # SUN3D's depth-map normals within 30 deg 0.34 -> 0.48 (docs/experiments.md, "Depth maps smoothed along their planes").
    plane_smoothing: bool = True
    # A depth no other map confirms takes the plane of a neighbour that other maps confirm
    # (view_agreement.adopt_confirmed_planes): edge fattening, chance matches, maps that disagree by a
    # few cm. Measured on recorded runs (docs/experiments.md, "Depths that take a confirmed neighbour's
    # plane"): the corridor's stereo against its LiDAR within 5 cm, Off 0.364 -> 0.382, Room 0.355 ->
    # 0.380; the demo room F 0.836 -> 0.838; SUN3D's Room 0.474 -> 0.466 with fewer floaters.
    adopt_confirmed_planes: bool = True
    # A phone's depth sensor (Frame.sensor_depth, LiDAR) gives the maps of the keyframes that have it,
    # in place of stereo (sensor_maps.py); captures without sensor depth are unaffected.
    sensor_depth: bool = True
    device: str = "cpu"

    def validate(self) -> None:
        """Raise VortxError naming the setting at fault."""
        if self.matcher not in STEREO_MATCHERS:
            raise VortxError(f"stereo matcher must be one of {', '.join(STEREO_MATCHERS)}, got {self.matcher!r}")
        if self.long_side < 32:
            raise VortxError(f"stereo long side must be at least 32 pixels, got {self.long_side}")
        if self.planes < 3:
            raise VortxError(f"stereo planes must be at least 3, got {self.planes}")
        if self.refine_planes < 0:
            raise VortxError(f"stereo refine planes cannot be negative, got {self.refine_planes}")
        if self.refine_rounds < 0:
            raise VortxError(f"stereo refine rounds cannot be negative, got {self.refine_rounds}")
        if self.sources < 1:
            raise VortxError(f"stereo sources must be at least 1, got {self.sources}")
        if not 1 <= self.best_k <= self.sources:
            raise VortxError(f"stereo best-k must be between 1 and the number of sources ({self.sources}), got {self.best_k}")
        if self.window < 3 or self.window % 2 == 0:
            raise VortxError(f"stereo window must be an odd number of pixels >= 3, got {self.window}")
        if not -1.0 <= self.min_ncc < 1.0:
            raise VortxError(f"stereo minimum NCC must be in [-1, 1), got {self.min_ncc}")
        if not 0 < self.min_depth < self.max_depth:
            raise VortxError(f"stereo depth range must satisfy 0 < min ({self.min_depth}) < max ({self.max_depth})")
        if self.ground_planes < 0:
            raise VortxError(f"stereo ground planes cannot be negative, got {self.ground_planes}")
        if self.max_references < 1:
            raise VortxError(f"stereo references must be at least 1, got {self.max_references}")
        if self.seed_planes != 0 and self.seed_planes < 3:
            raise VortxError(f"PatchMatch seed planes must be 0 (off) or at least 3, got {self.seed_planes}")
        if not isinstance(self.sparse_seed, bool):
            raise VortxError(f"PatchMatch sparse seed must be true or false, got {self.sparse_seed!r}")
        if not isinstance(self.planar_prior, bool):
            raise VortxError(f"PatchMatch planar prior must be true or false, got {self.planar_prior!r}")
        if not isinstance(self.adopt_confirmed_planes, bool):
            raise VortxError(f"PatchMatch adopt-confirmed-planes must be true or false, got {self.adopt_confirmed_planes!r}")
        if not isinstance(self.plane_smoothing, bool):
            raise VortxError(f"PatchMatch plane smoothing must be true or false, got {self.plane_smoothing!r}")
        if self.geometric_weight < 0:
            raise VortxError(f"PatchMatch geometric weight cannot be negative, got {self.geometric_weight}")
        if self.consistency_views < 0:
            raise VortxError(f"stereo consistency views cannot be negative, got {self.consistency_views}")
