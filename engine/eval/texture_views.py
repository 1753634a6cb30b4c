"""How a textured result looks from a photo it was not made from, against the vertex colours and the
ground-truth mesh textured the same way (issue 13, "Measured").

Some photos are held out; the texture is baked (VR preset, `engine.texture.vr.textured_result`) and
the vertices coloured (`engine.recon.colour.colour_vertices`, as a reconstruction colours them) from
the others only. Each result is rendered (engine/eval/view_render.py) from every held-out camera at
the photo's resolution and compared with the photo (PSNR, SSIM: engine/eval/image_metrics.py). The
ground-truth mesh baked from the same photos is the ceiling the photos and poses allow: the gap
between it and the texture is the reconstruction's geometry; the gap between the texture and the
vertex colours is what the texture adds.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..capture import Capture
from ..capture.images import resized_size
from ..errors import VortxError
from ..geometry.cameras import camera_to_pixels, scale_intrinsics, world_to_camera
from ..geometry.depth_render import NEAR_PLANE
from ..jobs import ProgressCallback, report
from ..mesh_io import Mesh
from ..meshops import compact, merge_duplicate_vertices, subdivide, vertex_normals
from ..photo_sampling import occlusion_depth
from ..recon.colour import COLOUR_LONG_SIDE, ColourView, colour_vertices
from ..texture.bake import bake_texture
from ..texture.file_parts import encode_png
from ..texture.ktx2 import decode_ktx2, encode_ktx2
from ..texture.options import TextureOptions
from ..texture.presets import gpu_texture_bytes
from ..texture.views import TextureView, views_from_capture
from ..texture.vr import textured_result
from .image_metrics import psnr, ssim
from .view_render import render_textured, render_vertex_colours

VERTEX_COLOURS, TEXTURE, GROUND_TRUTH = "vertex colours", "texture", "ground truth textured"
GT_MAX_EDGE = 0.1  # metres: ground-truth triangles (whole walls) are split so the z-buffers sample them densely
WELD = 1e-5  # metres: vertices this close are one vertex, so split triangles share edges (charts, normals)
VOTE_TOLERANCE = 0.03  # metres behind the rendered ground-truth depth a face centre may lie and count as seen
VOTE_LONG_SIDE = 160  # pixels of the depth maps that decide which cameras see a face (a vote needs no detail)


def heldout_texture_report(mesh: Mesh, capture: Capture, heldout: Sequence[str], options: TextureOptions,
                           gt_mesh: Optional[Mesh] = None, progress: Optional[ProgressCallback] = None) -> dict:
    """PSNR and SSIM of each method's render against each held-out photo. Writes nothing.

    mesh: the result (world metres, the capture's frame, normals facing the cameras; computed if
    missing). capture: posed, in the mesh's frame. heldout: photo stems or file names, excluded from
    the bake and the vertex colours. options: the bake's (its occlusion tolerance is also the vertex
    colours'). gt_mesh: the true surface in the same frame, or None.

    Methods: VERTEX_COLOURS (the full mesh, coloured from the other photos), TEXTURE (the VR preset:
    small pieces dropped, decimated to options.face_budget, baked), GROUND_TRUTH (gt_mesh split into
    <= GT_MAX_EDGE triangles, each face turned toward the cameras that see it, baked with no face
    budget). Mask: per view, the pixels that *every* method's render covers (the ground truth's
    included), so all methods are scored on the same pixels; PSNR over those pixels' channels, SSIM
    averaged over them. "mean" averages the per-view values.

    Returns {"heldout": names, "views": [{"photo", "pixels", "coverage", "psnr": {method: dB},
    "ssim": {method: value}}], "mean": {"psnr": {...}, "ssim": {...}}, "bake", "ground_truth_bake"
    (bake stats or None), "texture_files" (with a KTX2 headset preset: bytes on disk and on the GPU of
    the PNG and the KTX2 texture, whose decoded texels are scored as "texture <format>"), "timings_s", "renders": {photo: {"photo": image, method: image}}} — the
    renders are (h, w, 3) uint8 arrays (drop them before writing the rest as JSON).
    """
    wanted = set(heldout)
    if not wanted:
        raise VortxError("hold out at least one photo to measure the texture against")
    all_views = views_from_capture(capture)
    held = [v for v in all_views if v.name in wanted or Path(v.name).stem in wanted]
    found = {v.name for v in held} | {Path(v.name).stem for v in held}
    missing = sorted(wanted - found)
    if missing:
        raise VortxError(f"held-out photos not among the posed photos of {capture.root}: {', '.join(missing)}")
    train = views_from_capture(capture, exclude=list(wanted))
    if mesh.normals is None:
        mesh = replace(mesh, normals=vertex_normals(mesh.vertices, mesh.faces))
    timings: dict[str, float] = {}

    mark = time.perf_counter()
    textured, bake_stats = textured_result(mesh, train, options, progress)
    timings["texture bake"] = time.perf_counter() - mark

    compressed, texture_files = None, {}
    if options.texture_format != "png":  # the headset preset's GPU texture, decoded as a GPU shows it

        mark = time.perf_counter()
        report(progress, f"held-out: {options.texture_format}", 0, 1)
        data = encode_ktx2(textured.texture, options.texture_format, f"the '{options.preset}' headset preset")
        compressed = replace(textured, texture=decode_ktx2(data))
        width, height = textured.texture_size
        texture_files = {fmt: {"bytes": size, "gpu_bytes": gpu_texture_bytes(width, height, fmt)}
                         for fmt, size in (("png", len(encode_png(textured.texture))), (options.texture_format, len(data)))}
        timings[f"texture {options.texture_format}"] = time.perf_counter() - mark

    mark = time.perf_counter()
    report(progress, "held-out: vertex colours", 0, 1)
    coloured = replace(mesh, colors=colour_vertices(mesh, colour_views(train), options.occlusion_tolerance))
    timings["vertex colours"] = time.perf_counter() - mark

    gt_textured, gt_stats = None, None
    if gt_mesh is not None:
        mark = time.perf_counter()
        surface = ground_truth_surface(gt_mesh, train)
        gt_textured, gt_stats = bake_texture(surface, train, replace(options, face_budget=0), progress)
        timings["ground truth bake"] = time.perf_counter() - mark

    mark = time.perf_counter()
    views, renders = [], {}
    for i, view in enumerate(held):
        report(progress, "held-out: render", i, len(held))
        photo = view.load()
        shown = {VERTEX_COLOURS: render_vertex_colours(coloured, view.K, view.pose, view.size),
                 TEXTURE: render_textured(textured, view.K, view.pose, view.size)}
        if compressed is not None:
            shown[f"{TEXTURE} {options.texture_format}"] = render_textured(compressed, view.K, view.pose, view.size)
        if gt_textured is not None:
            shown[GROUND_TRUTH] = render_textured(gt_textured, view.K, view.pose, view.size)
        mask = np.logical_and.reduce([m for _, m in shown.values()])
        entry = {"photo": view.name, "pixels": int(mask.sum()), "coverage": round(float(mask.mean()), 4),
                 "psnr": {}, "ssim": {}}
        for method, (image, _) in shown.items():
            entry["psnr"][method] = psnr(photo, image, mask) if mask.any() else float("nan")
            entry["ssim"][method] = ssim(photo, image, mask) if mask.any() else float("nan")
        views.append(entry)
        renders[view.name] = {"photo": photo, **{method: image for method, (image, _) in shown.items()}}
    report(progress, "held-out: render", len(held), len(held))
    timings["renders and metrics"] = time.perf_counter() - mark

    methods = list(views[0]["psnr"])
    mean = {metric: {m: float(np.nanmean([v[metric][m] for v in views])) for m in methods} for metric in ("psnr", "ssim")}
    return {"heldout": [v.name for v in held], "views": views, "mean": mean, "bake": bake_stats,
            "ground_truth_bake": gt_stats, "texture_files": texture_files,
            "timings_s": {k: round(t, 2) for k, t in timings.items()}, "renders": renders}


def colour_views(views: Sequence[TextureView]) -> list[ColourView]:
    """The photos as a reconstruction's vertex colouring sees them: at most COLOUR_LONG_SIDE pixels."""
    out = []
    for view in views:
        image = view.load()
        w, h = view.size
        if max(w, h) > COLOUR_LONG_SIDE:
            size = resized_size(w, h, COLOUR_LONG_SIDE)
            image, K = cv2.resize(image, size, interpolation=cv2.INTER_AREA), scale_intrinsics(view.K, (w, h), size)
        else:
            K = view.K
        out.append(ColourView(image, K, view.pose))
    return out


def ground_truth_surface(gt_mesh: Mesh, views: Sequence[TextureView]) -> Mesh:
    """The true mesh made bakeable: triangles split to <= GT_MAX_EDGE (the z-buffers skip triangles
    crossing the near plane and sample huge ones sparsely), coincident vertices welded, each face
    turned toward the cameras that see it (a modelled scene's winding need not face the room), and
    normals from the new winding."""
    points, faces = subdivide(gt_mesh.vertices, gt_mesh.faces, max_edge=GT_MAX_EDGE, max_rounds=12)
    points, faces = compact(*merge_duplicate_vertices(points, faces, tolerance=WELD))
    faces = orient_toward_cameras(points, faces, views)
    vertices = points.astype(np.float32)
    return Mesh(vertices=vertices, faces=faces.astype(np.int32), normals=vertex_normals(vertices, faces))


def orient_toward_cameras(vertices: np.ndarray, faces: np.ndarray, views: Sequence[TextureView]) -> np.ndarray:
    """faces (F, 3) with the winding of each flipped where most cameras that see its centre (in the
    image, not hidden behind the mesh's own depth) are behind it; faces no camera sees keep theirs."""
    v = np.asarray(vertices, np.float64)
    tri = v[faces]
    centre = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    votes = np.zeros(len(faces))
    mesh = Mesh(vertices=v.astype(np.float32), faces=faces)
    for view in views:
        w, h = view.size
        depth = occlusion_depth(mesh, view.K, view.pose, view.size, long_side=VOTE_LONG_SIDE)
        cam = world_to_camera(centre, view.pose)
        z = cam[:, 2]
        u, vv = camera_to_pixels(cam, view.K)
        ok = (z > NEAR_PLANE) & (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
        ids = np.flatnonzero(ok)
        dh, dw = depth.shape
        col = np.minimum((u[ids] * dw / w).astype(np.int64), dw - 1)
        row = np.minimum((vv[ids] * dh / h).astype(np.int64), dh - 1)
        seen = ids[z[ids] <= depth[row, col] + VOTE_TOLERANCE + 0.02 * z[ids]]
        votes[seen] += np.sign(np.einsum("nk,nk->n", normal[seen], view.pose[:3, 3] - centre[seen]))
    flip = votes < 0
    out = np.array(faces, copy=True)
    out[flip] = out[flip][:, [0, 2, 1]]
    return out


def write_comparison_picture(path: Path, photo: np.ndarray, renders: dict[str, np.ndarray]) -> None:
    """One PNG: the photo, then each render (label -> (h, w, 3) uint8 RGB, in the dict's order), side
    by side with 4-pixel white gaps, each labelled in its top-left corner."""
    panels = [("held-out photo", photo), *renders.items()]
    h, w = photo.shape[:2]
    for label, image in panels:
        if image.shape != (h, w, 3):
            raise VortxError(f"render '{label}' is {image.shape}, the photo {photo.shape}: they must match")
    gap = np.full((h, 4, 3), 255, np.uint8)
    parts = []
    for i, (label, image) in enumerate(panels):
        panel = np.ascontiguousarray(image[..., ::-1])  # RGB -> BGR for OpenCV
        # Dark outline under white text: readable on the photo's bright walls and on black background.
        cv2.putText(panel, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(panel, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        parts += [gap, panel] if i else [panel]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.concatenate(parts, axis=1)):
        raise VortxError(f"cannot write {path}")


def spread_heldout(stems: Sequence[str], count: int) -> list[str]:
    """`count` photos spread evenly over the walk (the middles of `count` equal stretches of the
    sorted names), so the held-out views look at different parts of the room."""
    ordered = sorted(stems)
    if not 1 <= count < len(ordered):
        raise VortxError(f"cannot hold out {count} of {len(ordered)} photos: keep at least one to bake from")
    return [ordered[int((2 * k + 1) * len(ordered) / (2 * count))] for k in range(count)]


def report_table(report: dict) -> list[str]:
    """The report as lines of text: one row per held-out photo, PSNR dB / SSIM per method, then the mean."""
    methods = list(report["views"][0]["psnr"])
    lines = [f"{'photo':<14} {'pixels':>7} " + " ".join(f"{m:>24}" for m in methods)]
    for view in report["views"]:
        lines.append(f"{view['photo']:<14} {view['pixels']:>7} "
                     + " ".join(f"{view['psnr'][m]:>14.2f} / {view['ssim'][m]:.3f}" for m in methods))
    lines.append(f"{'mean':<14} {'':>7} " + " ".join(
        f"{report['mean']['psnr'][m]:>14.2f} / {report['mean']['ssim'][m]:.3f}" for m in methods))
    return lines
