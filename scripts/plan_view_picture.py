"""Meshes of a room seen from above, side by side: a floor plan view (the pictures of the finishing stage).

Each mesh is levelled (world Z, or the cameras' horizon where the surface lies more level along it:
`engine.finish.planes.room_up`, as the finishing stage levels it), cut above the cameras so the ceiling
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
from engine.finish.planes import face_geometry, room_up, rotation_to_z  # noqa: E402
from engine.geometry.depth_render import render_depth, shade  # noqa: E402
from engine.mesh_io import read_ply  # noqa: E402
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
    cameras = poses[:, :3, 3] @ rotation.T
    cut = float(np.median(cameras[:, 2])) + CUT_ABOVE_CAMERAS
    levelled = []
    for mesh in meshes:
        vertices = np.asarray(mesh.vertices, np.float64) @ rotation.T
        faces = np.asarray(mesh.faces)
        keep = vertices[faces][:, :, 2].max(axis=1) <= cut
        added = mesh.attributes.get(ADDED) if mesh.attributes else None
        levelled.append((vertices, faces[keep], None if added is None else np.asarray(added)))
    # One frame for all panels: the extent of the first mesh (below the cut) and the cameras.
    used = levelled[0][0][np.unique(levelled[0][1])]
    low = np.minimum(np.percentile(used[:, :2], 0.5, axis=0), cameras[:, :2].min(axis=0)) - 0.2
    high = np.maximum(np.percentile(used[:, :2], 99.5, axis=0), cameras[:, :2].max(axis=0)) + 0.2
    floor = float(np.percentile(used[:, 2], 1.0))
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
        cv2.putText(image, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
        panels.append(image)
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    row = panels[0]
    for panel in panels[1:]:
        row = np.hstack([row, gap, panel])
    cv2.putText(row, "from above, cut %.1f m above the floor; colour = height; magenta = added" % (cut - floor),
                (6, row.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), row, [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {out} ({row.shape[1]} x {row.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
