"""Meshes of a room seen from above, side by side: a floor plan view (the pictures of the finishing stage).

Each mesh is levelled (world Z, or the cameras' horizon where the surface lies more level along it:
`engine.finish.planes.room_up`, as the finishing stage levels it), turned so the last mesh's walls run
along the picture's sides, cut above the cameras so the ceiling
does not hide the room, and rendered straight down (a camera 200 m up: nearly orthographic). Colour is
height (blue floor to red at the cut), shaded by the surface's slope; faces the finishing added (the
vertex attribute `added`) are tinted magenta; the capture's cameras are white dots.

    python scripts/plan_view_picture.py /work/data/sun3d off.ply room.ply /work/data/sun3d/mesh_gt.ply \
        --labels "Finish Off" "Finish Room" "truth" --out docs/finish_sun3d_plan.jpg
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine.capture import load_capture  # noqa: E402
from engine.finish.planes import _histogram_peaks, face_geometry, find_structural_planes, room_up, rotation_to_z  # noqa: E402
from engine.geometry.depth_render import render_depth, shade  # noqa: E402
from engine.mesh_io import read_ply  # noqa: E402
from engine.meshops import subdivide  # noqa: E402
from engine.observation import ADDED  # noqa: E402

CAMERA_HEIGHT = 200.0  # m above the room: the view is nearly orthographic
CUT_ABOVE_CAMERAS = 0.3  # m: faces higher than this above the cameras' median height are left out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", help="the posed capture the meshes belong to (its cameras level the view)")
    ap.add_argument("meshes", nargs="+", help="PLY meshes in the capture's frame")
    ap.add_argument("--labels", nargs="+", help="one label per mesh (default: the file names)")
    ap.add_argument("--out", required=True, help="picture to write (PNG or JPEG)")
    ap.add_argument("--size", type=int, default=420, help="pixels of each panel's longer side")
    args = ap.parse_args(argv)

    import cv2

    if args.labels and len(args.labels) != len(args.meshes):
        raise SystemExit(f"error: {len(args.labels)} labels for {len(args.meshes)} meshes")
    labels = args.labels or [Path(m).stem for m in args.meshes]
    capture = load_capture(args.capture)
    poses = np.stack([f.pose for f in capture.posed_frames])
    meshes = [read_ply(path) for path in args.meshes]
    centroids, areas, normals = face_geometry(np.asarray(meshes[0].vertices, np.float64), np.asarray(meshes[0].faces))
    up, _ = room_up(poses, centroids, areas, normals)
    rotation = rotation_to_z(up)
    # Turned about up so the room's walls (its Manhattan heading, from the last mesh) run along the picture.
    _, layout = find_structural_planes(np.asarray(meshes[-1].vertices, np.float64) @ rotation.T, np.asarray(meshes[-1].faces),
                                       poses[:, :3, 3] @ rotation.T)
    heading = -np.radians(layout["heading_deg"])
    rotation = np.array([[np.cos(heading), -np.sin(heading), 0.0], [np.sin(heading), np.cos(heading), 0.0],
                         [0.0, 0.0, 1.0]]) @ rotation
    cameras = poses[:, :3, 3] @ rotation.T
    cut = float(np.median(cameras[:, 2])) + CUT_ABOVE_CAMERAS
    levelled = []
    for mesh in meshes:
        added = mesh.attributes.get(ADDED) if mesh.attributes else None
        # Large triangles (a truth mesh's walls) are cut small so the renderer's samples cover them.
        if added is None:
            vertices, faces = subdivide(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces))
        else:
            vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
        vertices = vertices @ rotation.T
        keep = vertices[faces][:, :, 2].max(axis=1) <= cut
        levelled.append((vertices, faces[keep], None if added is None else np.asarray(added)))
    # One frame for all panels: the extent of the reconstructions (all meshes but the last, the truth, whose
    # backdrops outside the windows reach far) and the cameras; the floor is the last mesh's lowest
    # up-facing surface below the cameras with a fifth of the strongest one's area.
    framing = levelled[:-1] if len(levelled) > 1 else levelled
    used = np.concatenate([v[np.unique(f)] for v, f, _ in framing])
    low = np.minimum(np.percentile(used[:, :2], 1.0, axis=0), cameras[:, :2].min(axis=0)) - 0.2
    high = np.maximum(np.percentile(used[:, :2], 99.0, axis=0), cameras[:, :2].max(axis=0)) + 0.2
    last_v, last_f, _ = levelled[-1]
    c, a, n = face_geometry(last_v, last_f)
    facing_up = (n[:, 2] > 0.9) & (c[:, 2] < float(np.median(cameras[:, 2])) - 0.3)
    peaks = _histogram_peaks(c[facing_up, 2], a[facing_up], 0.0)
    floor = (min(z for z, w in peaks if w >= 0.2 * peaks[0][1]) if peaks else float(np.percentile(last_v[:, 2], 1.0)))
    pixels = args.size / float((high - low).max())  # per metre
    width, height = (np.ceil((high - low) * pixels).astype(int) + 1)
    focal = pixels * CAMERA_HEIGHT
    K = np.array([[focal, 0.0, -low[0] * pixels], [0.0, focal, high[1] * pixels], [0.0, 0.0, 1.0]])
    pose = np.eye(4)  # looking down -Z; image x = world +X, image y = world -Y (north up)
    pose[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    pose[:3, 3] = [0.0, 0.0, CAMERA_HEIGHT]
    panels = []
    for (vertices, faces, added), label in zip(levelled, labels):
        depth = render_depth(vertices, faces, K, pose, (int(width), int(height)))
        hit = np.isfinite(depth)
        z = np.where(hit, CAMERA_HEIGHT - depth, floor)
        level = np.clip((z - floor) / max(cut - floor, 1e-6), 0, 1)
        colour = cv2.applyColorMap((level * 255).astype(np.uint8), cv2.COLORMAP_JET).astype(np.float64)
        light = shade(np.where(hit, depth, np.inf).astype(np.float32), K).astype(np.float64)[..., None] / 255.0
        image = colour * (0.35 + 0.65 * light)
        if added is not None and (added > 0.5).any():
            marked = faces[added[faces].min(axis=1) > 0.5]
            added_depth = render_depth(vertices, marked, K, pose, (int(width), int(height)))
            on_added = hit & np.isfinite(added_depth) & (np.abs(np.where(np.isfinite(added_depth), added_depth, 0.0) - depth) < 0.01)
            image[on_added] = 0.5 * image[on_added] + 0.5 * np.array([255.0, 0.0, 255.0])
        image[~hit] = 255.0
        image = image.astype(np.uint8)
        for x, y in cameras[:, :2]:
            centre = (int(round((x - low[0]) * pixels)), int(round((high[1] - y) * pixels)))
            cv2.circle(image, centre, 3, (0, 0, 0), -1, cv2.LINE_AA)
            cv2.circle(image, centre, 2, (255, 255, 255), -1, cv2.LINE_AA)
        band = np.full((24, image.shape[1], 3), 255, np.uint8)  # the label above the plan, not on it
        cv2.putText(band, label, (6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
        panels.append(np.vstack([band, image]))
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    row = panels[0]
    for panel in panels[1:]:
        row = np.hstack([row, gap, panel])
    footer = np.full((20, row.shape[1], 3), 255, np.uint8)
    cv2.putText(footer, "from above, cut %.1f m above the floor; colour = height (blue floor); magenta = added by the "
                "finishing; dots = cameras" % (cut - floor), (6, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (60, 60, 60), 1,
                cv2.LINE_AA)
    row = np.vstack([row, footer])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), row, [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {out} ({row.shape[1]} x {row.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
