"""PatchMatch depth and normal maps of a set of reference views: coarse to fine per view, then
geometric-consistency passes over all views together.

Per reference (`photometric_planes`): the planes start at the coarsest scale from an initial depth
(the sparse points' triangulated depth, sparse_seed.py, where they cover the view) with the normals of
its surface, and random planes elsewhere, run
`coarse_iterations` of PatchMatch, and carry to each finer scale (twice the size), where
`fine_iterations` refine them: a weakly textured area takes its planes from the coarse scale, where
the same window covers four times the surface. With `planar_prior` (ACMP, planar_prior.py), the
pixels a triangle of confident pixels covers then run `prior_iterations` more, scored with the prior.

Then (`geometric_passes`), with every reference's depth map known, each reference is rescored with
the forward-backward reprojection error into its sources' depth maps and refined for
`geometric_iterations` more iterations (ACMM's geometric consistency; the maps of the previous pass
are used, so the result does not depend on the order of the views).

Tensors on `device`; images (h, w) grey in [0, 1]; K in pixels of their image; poses camera-to-world.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Optional, Sequence, TypeVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..geometry.cameras import scale_intrinsics
from ..jobs import CancelToken, ProgressCallback, check, report
from .patchmatch import PlaneState, initial_state, patchmatch_iterations, rescore, upsample_planes
from .planar_prior import planar_prior, prior_iterations
from .plane_cost import MAX_COST, ReferenceWindows, SourceViews
from .stage_clock import collecting_now as stage_clock_collecting, phase, stage
from .sweep import sweep_depth

SEED_WINDOW = 5  # the seed sweep's NCC window at the coarsest scale (pixels)
SEED_MIN_NCC = 0.3  # a seed depth is kept from this NCC: a wrong seed costs no more than the random plane it replaces

_T = TypeVar("_T")

# An image source: (position) -> (grey (h, w) float32 tensor at the finest stereo size, K (3, 3) for it).
ImageSource = Callable[[int], tuple[Tensor, np.ndarray]]


@dataclass(frozen=True)
class PatchMatchSchedule:
    scales: int = 2  # image sizes, each twice the previous, ending at the stereo size
    window: int = 9  # window side in pixels at every scale (sampled every 2nd pixel)
    coarse_iterations: int = 3
    fine_iterations: int = 2  # at each finer scale
    geometric_passes: int = 1  # passes over all views with the geometric term
    geometric_iterations: int = 1  # PatchMatch iterations per view and pass
    geometric_weight: float = 0.2  # cost per pixel of reprojection error (ACMM: 0.2, capped at 3 px)
    seed: int = 0
    seed_planes: int = 0  # > 0: start the coarsest scale from a fronto-parallel sweep over this many planes (0 = random planes)
    planar_prior: bool = False  # ACMP's planar prior after the finest scale (planar_prior.py)
    prior_iterations: int = 2  # PatchMatch iterations scored with the prior (ACMP: 3)

    def photometric_iterations(self) -> int:
        """Iterations of the photometric stage: where the geometric passes' shrinking schedules go on from."""
        return self.coarse_iterations + (self.scales - 1) * self.fine_iterations + (self.prior_iterations if self.planar_prior else 0)


@dataclass
class PlaneMap:
    """One reference's PatchMatch result at the stereo size."""

    depth: np.ndarray  # (h, w) float32 metres, planar z (> 0 everywhere before filtering)
    normal: np.ndarray  # (h, w, 3) float32 unit, camera coordinates, facing the camera
    cost: np.ndarray  # (h, w) float32 photometric cost 1 - NCC of the view-weighted sources, in [0, 2]
    prior_depth: Optional[np.ndarray] = None  # (h, w) float32 the planar prior's depth, 0 where none (None: prior off)


def _resize(image: Tensor, size: tuple[int, int]) -> Tensor:
    """(h, w) image at size (h', w') (area averaging when shrinking)."""
    if tuple(image.shape) == size:
        return image
    return F.interpolate(image[None, None], size=size, mode="area")[0, 0]


def _scale_sizes(height: int, width: int, scales: int) -> list[tuple[int, int]]:
    """Image sizes (h, w), coarsest first, ending at (height, width)."""
    sizes = [(height, width)]
    for _ in range(scales - 1):
        h, w = sizes[0]
        sizes.insert(0, (max(8, round(h / 2)), max(8, round(w / 2))))
    return sizes


def _source_views(images: Sequence[Tensor], Ks: Sequence[np.ndarray], ref_pose: np.ndarray, poses: Sequence[np.ndarray],
                  size: Optional[tuple[int, int]], device: torch.device, depths: Optional[Sequence[Optional[Tensor]]] = None
                  ) -> SourceViews:
    """The sources of one reference at one size (h, w) (None: their own size)."""
    resized, Kr = [], []
    for image, K in zip(images, Ks):
        h, w = size if size is not None else tuple(image.shape)
        resized.append(_resize(image, (h, w)).to(device))
        Kr.append(scale_intrinsics(K, (image.shape[1], image.shape[0]), (w, h)))
    src_from_ref = np.stack([np.linalg.inv(p) @ ref_pose for p in poses]) if len(poses) else np.zeros((0, 4, 4))
    stacked_depths = None
    if depths is not None:
        h, w = resized[0].shape if resized else (1, 1)
        stacked_depths = torch.stack([
            (F.interpolate(d[None, None], size=(h, w), mode="nearest")[0, 0] if d is not None
             else torch.zeros((h, w))).to(device) for d in depths])
    as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    return SourceViews(
        images=torch.stack(resized) if resized else torch.zeros((0, 1, 1), device=device),
        K=as_tensor(np.stack(Kr)) if Kr else torch.zeros((0, 3, 3), device=device),
        rotation=as_tensor(src_from_ref[:, :3, :3]), translation=as_tensor(src_from_ref[:, :3, 3]),
        depths=stacked_depths)


@dataclass
class _KeptPlanes:
    """A view's planes between stages, on the CPU: depth (HW,), normal (HW, 3), view weights (S, HW)."""

    depth: Tensor
    normal: Tensor
    view_weights: Tensor
    size: tuple[int, int]  # (h, w)
    prior_depth: Optional[Tensor] = None  # (HW,) the planar prior's depth, 0 where none

    @staticmethod
    def of(state: PlaneState, ref: ReferenceWindows) -> "_KeptPlanes":
        return _KeptPlanes(state.depth.cpu(), state.normal.cpu(), state.view_weights.cpu(), (ref.height, ref.width),
                           None if state.prior_depth is None else state.prior_depth.cpu())

    def restore(self, ref: ReferenceWindows, device: torch.device) -> PlaneState:
        """A PlaneState to refine further (its costs are filled by the next rescore). Copies: refining it
        must not change these planes, which the other views of the same pass read as this view's map
        (on the CPU `.to` alone would hand back the same storage)."""
        weights = self.view_weights.to(device, copy=True)
        state = PlaneState(self.depth.to(device, copy=True), self.normal.to(device, copy=True), torch.zeros_like(weights),
                           torch.zeros_like(self.depth, device=device), weights,
                           None if self.prior_depth is None else self.prior_depth.to(device, copy=True))
        state._rays = ref.rays
        return state


def _plane_map(state: PlaneState, ref: ReferenceWindows, cost: Tensor) -> PlaneMap:
    h, w = ref.height, ref.width
    prior = None if state.prior_depth is None else state.prior_depth.reshape(h, w).cpu().numpy().astype(np.float32)
    return PlaneMap(state.depth.reshape(h, w).cpu().numpy().astype(np.float32),
                    state.normal.reshape(h, w, 3).cpu().numpy().astype(np.float32),
                    cost.clamp(0, MAX_COST).reshape(h, w).cpu().numpy().astype(np.float32), prior)


def _fronto_normals(rays: Tensor) -> Tensor:
    return -rays / rays.norm(dim=-1, keepdim=True)


SEED_NORMAL_STEP = 2  # pixels either side for the seed's normals: a sweep's depth is stepped, one pixel is too close


def depth_map_normals(depth: Tensor, ref: ReferenceWindows) -> Tensor:
    """(HW, 3) unit normals facing the camera of the surface of a depth map (HW,) at the reference's
    pixels, from the cross product of its points SEED_NORMAL_STEP pixels apart either way; facing the
    camera where a neighbour has no depth."""
    H, W, k = ref.height, ref.width, SEED_NORMAL_STEP
    points = (ref.rays * depth[:, None]).reshape(H, W, 3)
    has = (depth > 0).reshape(H, W)
    normal = _fronto_normals(ref.rays).reshape(H, W, 3).clone()
    if H > 2 * k and W > 2 * k:
        du = points[k:-k, 2 * k:] - points[k:-k, :-2 * k]
        dv = points[2 * k:, k:-k] - points[:-2 * k, k:-k]
        cross = torch.linalg.cross(du, dv)
        length = cross.norm(dim=-1, keepdim=True)
        ok = has[k:-k, 2 * k:] & has[k:-k, :-2 * k] & has[2 * k:, k:-k] & has[:-2 * k, k:-k] & (length[..., 0] > 0)
        cross = cross / length.clamp_min(1e-12)
        rays = ref.rays.reshape(H, W, 3)[k:-k, k:-k]
        cross = torch.where((cross * rays).sum(-1, keepdim=True) > 0, -cross, cross)
        normal[k:-k, k:-k] = torch.where(ok[..., None], cross, normal[k:-k, k:-k])
    return normal.reshape(-1, 3)


def seed_depth(ref: ReferenceWindows, sources: SourceViews, depth_range: tuple[float, float], planes: int) -> Tensor:
    """(HW,) a fronto-parallel sweep's depth of the reference at its own size (0 where it found none):
    planes for PatchMatch to start from, so its first iterations refine surfaces instead of finding them
    (OpenMVS starts from the sparse points; the sweep also covers views without them)."""
    S = len(sources)
    src_from_ref = torch.zeros((S, 4, 4), dtype=sources.rotation.dtype, device=sources.rotation.device)
    src_from_ref[:, :3, :3], src_from_ref[:, :3, 3], src_from_ref[:, 3, 3] = sources.rotation, sources.translation, 1.0
    result = sweep_depth(ref.image, sources.images, ref.K, sources.K, src_from_ref, depth_range, planes, 0,
                         max(1, S // 2), SEED_WINDOW, SEED_MIN_NCC)
    return result.depth.reshape(-1)


def photometric_planes(
    image: Tensor, K: np.ndarray, pose: np.ndarray, source_images: Sequence[Tensor], source_Ks: Sequence[np.ndarray],
    source_poses: Sequence[np.ndarray], depth_range: tuple[float, float], schedule: PatchMatchSchedule,
    device: torch.device, initial_depth: Optional[np.ndarray] = None, cancel: Optional[CancelToken] = None,
) -> tuple[PlaneState, ReferenceWindows]:
    """One reference's planes at the stereo size (the size of `image`), from photo-consistency alone.

    initial_depth: optional (h', w') depth map (0 = none) of any size, e.g. the sparse points'
    (sparse_seed.py); its planes start with the normals of its surface.
    """
    generator = torch.Generator(device=device).manual_seed(schedule.seed)
    H, W = image.shape
    state: Optional[PlaneState] = None
    ref: Optional[ReferenceWindows] = None
    iteration = 0
    for size in _scale_sizes(H, W, schedule.scales):
        check(cancel)
        scaled_K = scale_intrinsics(K, (W, H), (size[1], size[0]))
        ref = ReferenceWindows(_resize(image, size).to(device), torch.as_tensor(scaled_K, dtype=torch.float32, device=device),
                               schedule.window)
        with stage("sources"):
            sources = _source_views(source_images, source_Ks, pose, source_poses, size, device)
        if state is None:
            depth = normal = None
            if initial_depth is not None:
                start = torch.as_tensor(initial_depth, dtype=torch.float32)[None, None]
                depth = F.interpolate(start, size=size, mode="nearest").reshape(-1).to(device)
                normal = depth_map_normals(depth, ref)
            if schedule.seed_planes > 0 and len(sources):
                with stage("seed sweep"):
                    seeded = seed_depth(ref, sources, depth_range, schedule.seed_planes)
                depth = seeded if depth is None else torch.where(depth > 0, depth, seeded)
                normal = depth_map_normals(depth, ref)
            with stage("initialisation"):
                state = initial_state(ref, sources, depth_range, generator, depth, normal)
            count = schedule.coarse_iterations
        else:
            with stage("initialisation"):
                depth, normal = upsample_planes(state, previous_size, ref)
                state = initial_state(ref, sources, depth_range, generator, depth, normal)
            count = schedule.fine_iterations
        patchmatch_iterations(state, ref, sources, depth_range, count, generator, first_iteration=iteration, cancel=cancel)
        iteration += count
        previous_size = size
    assert state is not None and ref is not None
    if schedule.planar_prior:
        with phase("planar prior"):
            with stage("prior planes"):
                prior = planar_prior(state, ref, depth_range) if len(sources) else None
            if prior is None:
                state.prior_depth = torch.zeros_like(state.depth)
            else:
                prior_iterations(state, ref, sources, prior, schedule.prior_iterations, generator, iteration, cancel)
                state.prior_depth = prior.depth
    return state, ref


def geometric_refinement(
    state: PlaneState, ref: ReferenceWindows, pose: np.ndarray, source_images: Sequence[Tensor],
    source_Ks: Sequence[np.ndarray], source_poses: Sequence[np.ndarray], source_depths: Sequence[Optional[Tensor]],
    depth_range: tuple[float, float], schedule: PatchMatchSchedule, device: torch.device, first_iteration: int,
    cancel: Optional[CancelToken] = None,
) -> PlaneState:
    """`state` rescored and refined with the geometric term against the sources' depth maps."""
    generator = torch.Generator(device=device).manual_seed(schedule.seed + 1 + first_iteration)
    with stage("sources"):
        sources = _source_views(source_images, source_Ks, pose, source_poses, (ref.height, ref.width), device, source_depths)
    with stage("initialisation"):
        rescore(state, ref, sources, schedule.geometric_weight, first_iteration)
    return patchmatch_iterations(state, ref, sources, depth_range, schedule.geometric_iterations, generator,
                                 schedule.geometric_weight, first_iteration, cancel)


def photometric_cost(state: PlaneState, ref: ReferenceWindows, pose: np.ndarray, source_images: Sequence[Tensor],
                     source_Ks: Sequence[np.ndarray], source_poses: Sequence[np.ndarray], device: torch.device,
                     iteration: int) -> Tensor:
    """(HW,) the planes' photometric cost alone (the geometric term left out), view-weighted."""
    with stage("sources"):
        sources = _source_views(source_images, source_Ks, pose, source_poses, (ref.height, ref.width), device)
    scored = PlaneState(state.depth, state.normal, state.costs.clone(), state.cost.clone(), state.view_weights.clone())
    scored._rays = state._rays
    with stage("final photometric cost"):
        return rescore(scored, ref, sources, 0.0, iteration).cost


def cpu_workers(device: torch.device, requested: int = 0) -> int:
    """How many references to match at once: one per torch thread on the CPU (`requested` > 0 sets it),
    one on a GPU, and one while the stage clock is collecting (its stack is not per thread)."""
    if device.type != "cpu" or stage_clock_collecting():
        return 1
    return max(1, requested if requested > 0 else torch.get_num_threads())


@contextmanager
def _one_torch_thread(workers: int) -> Iterator[None]:
    """Torch's intra-op threads set to one while `workers` > 1 threads each match a reference.

    PatchMatch's operations are small (a 4,096-pixel chunk of one candidate at a time), so torch's
    own thread pool spends its time waking and joining threads: on 2 cores two threads doubled the
    CPU seconds of one and did not halve the wall time, and when another process held a core, the
    pool's spinning threads took 9x as long (docs/settings.md). One torch thread per reference, and
    as many references at once as there were threads, uses the cores without either cost.
    """
    if workers <= 1:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _each(count: int, job: Callable[[int], _T], workers: int, done: Callable[[int], None]) -> list[_T]:
    """[job(0), ..., job(count - 1)] on `workers` threads (in order; `done(n)` after the n-th finishes).
    The first error (a cancellation included) stops the jobs not yet started and is raised once the
    running ones return."""
    if workers <= 1:
        results = []
        for i in range(count):
            results.append(job(i))
            done(i + 1)
        return results
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="patchmatch") as pool:
        futures = [pool.submit(job, i) for i in range(count)]
        try:
            for finished, future in enumerate(as_completed(futures), start=1):
                future.result()
                done(finished)
        except BaseException:
            for future in futures:
                future.cancel()
            raise
        return [future.result() for future in futures]


def patchmatch_views(
    references: Sequence[int], sources_of: Callable[[int], Sequence[int]], image: ImageSource, poses: np.ndarray,
    depth_ranges: Sequence[tuple[float, float]], schedule: PatchMatchSchedule, device: torch.device,
    initial_depths: Optional[Sequence[Optional[np.ndarray]]] = None, progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None, stages: Optional[dict[str, float]] = None, workers: int = 0,
) -> list[PlaneMap]:
    """PlaneMaps of `references` (positions into `poses` and `image`), each matched against
    `sources_of(reference)`; geometric passes use the maps of the sources that are references too.
    `stages` receives the seconds of the photometric and the geometric stage. `workers`: references
    matched at once on the CPU (`cpu_workers`; 0 = one per torch thread). The result does not depend on
    it: each reference's random planes come from its own seeded generator."""
    stages = stages if stages is not None else {}
    workers = cpu_workers(device, workers)
    steps = len(references) * (1 + schedule.geometric_passes)
    report(progress, "patchmatch", 0, steps)

    # Between the stages each view keeps only its planes and view selection (on the CPU); its windows
    # (the largest part of a view's state) are rebuilt when it is refined again, so memory stays at
    # `workers` views' working sets plus a few maps per reference.
    def photometric(done: int) -> tuple[_KeptPlanes, Optional[PlaneMap]]:
        r = references[done]
        img, K = image(r)
        srcs = list(sources_of(r))
        state, ref = photometric_planes(img, K, poses[r], [image(s)[0] for s in srcs], [image(s)[1] for s in srcs],
                                        [poses[s] for s in srcs], depth_ranges[done], schedule, device,
                                        None if initial_depths is None else initial_depths[done], cancel)
        return _KeptPlanes.of(state, ref), (_plane_map(state, ref, state.cost) if schedule.geometric_passes == 0 else None)

    with _one_torch_thread(workers):
        started = time.perf_counter()
        results = _each(len(references), photometric, workers, lambda n: report(progress, "patchmatch", n, steps))
        kept = [k for k, _ in results]
        maps: list[Optional[PlaneMap]] = [m for _, m in results]
        stages["patchmatch"] = time.perf_counter() - started
        started = time.perf_counter()
        position = {int(r): i for i, r in enumerate(references)}
        iteration = schedule.photometric_iterations()
        for p in range(schedule.geometric_passes):
            with phase("geometric pass"):
                last = p == schedule.geometric_passes - 1
                depths = [k.depth.reshape(k.size) for k in kept]  # the previous pass's maps: the result ignores the order of views

                def geometric(done: int) -> tuple[_KeptPlanes, Optional[PlaneMap]]:
                    r = references[done]
                    img, K = image(r)
                    ref = ReferenceWindows(img.to(device), torch.as_tensor(K, dtype=torch.float32, device=device), schedule.window)
                    state = kept[done].restore(ref, device)
                    srcs = list(sources_of(r))
                    source_images, source_Ks, source_poses = [image(s)[0] for s in srcs], [image(s)[1] for s in srcs], [poses[s] for s in srcs]
                    source_depths = [depths[position[s]] if s in position else None for s in srcs]
                    geometric_refinement(state, ref, poses[r], source_images, source_Ks, source_poses, source_depths,
                                         depth_ranges[done], schedule, device, iteration, cancel)
                    if last:  # the filter judges the photometric cost alone
                        cost = photometric_cost(state, ref, poses[r], source_images, source_Ks, source_poses, device,
                                                iteration + schedule.geometric_iterations)
                        return kept[done], _plane_map(state, ref, cost)
                    return _KeptPlanes.of(state, ref), None

                offset = len(references) * (1 + p)
                results = _each(len(references), geometric, workers, lambda n: report(progress, "patchmatch", offset + n, steps))
                if last:
                    maps = [m for _, m in results]
                else:
                    kept = [k for k, _ in results]
                iteration += schedule.geometric_iterations
    report(progress, "patchmatch", steps, steps)
    stages["geometric consistency"] = time.perf_counter() - started
    assert all(m is not None for m in maps)
    return maps  # type: ignore[return-value]
