"""One photo of a posed capture beside a mesh rendered (shaded depth) from that photo's camera.

Used for MODEL.md's picture of the fox capture, which has no ground-truth mesh to score against:

    python scripts/capture_view_picture.py /tmp/fox fox.ply --frame 0018 --out docs/fox_reconstruction.png

Several meshes side by side (before / after, the truth), each under its own label:

    python scripts/capture_view_picture.py ROOM before.ply after.ply ROOM/mesh_gt.ply --frame 000040 \
        --labels "before: normals 0.17" "after: normals 0.18" "truth" --out docs/room_before_after.jpg
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine.capture import load_capture, load_image  # noqa: E402
from engine.mesh_io import read_ply  # noqa: E402
from engine.meshops import subdivide  # noqa: E402
from engine.geometry.depth_render import render_depth  # noqa: E402
from engine.geometry.depth_render import shade  # noqa: E402


NO_SURFACE_BGR = (60, 60, 170)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", help="a posed capture (e.g. the output folder of `python -m engine poses`)")
    ap.add_argument("meshes", nargs="+", help="PLY meshes in the capture's world frame")
    ap.add_argument("--labels", nargs="+", help="one label per mesh (default: 'mesh, same camera' or the file names)")
    ap.add_argument("--frame", required=True, help="photo name or stem, e.g. 0018")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--height", type=int, default=480, help="picture height in pixels")
    args = ap.parse_args(argv)

    import cv2

    capture = load_capture(args.capture)
    matches = [f for f in capture.frames if args.frame in (f.name, f.image_path.stem)]
    if not matches or not matches[0].has_pose or matches[0].K is None:
        raise SystemExit(f"error: no posed frame named {args.frame!r} in {args.capture}")
    frame = matches[0]
    scale = args.height / frame.height
    size = (round(frame.width * scale), args.height)
    K = frame.K.copy()
    K[:2] *= scale
    if args.labels and len(args.labels) != len(args.meshes):
        raise SystemExit(f"error: {len(args.labels)} labels for {len(args.meshes)} meshes: give one label per mesh")
    labels = args.labels or (["mesh, same camera"] if len(args.meshes) == 1 else [Path(m).stem for m in args.meshes])
    panels = [cv2.resize(cv2.cvtColor(load_image(frame.image_path), cv2.COLOR_RGB2BGR), size, interpolation=cv2.INTER_AREA)]
    for path in args.meshes:
        mesh = read_ply(path)
        vertices, faces = subdivide(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces))
        depth = render_depth(vertices, faces, K, frame.pose, size)
        panel = cv2.cvtColor(shade(depth, K), cv2.COLOR_GRAY2BGR)
        # No surface in red: shading draws a surface facing the camera nearly white, as white as nothing.
        panel[~np.isfinite(depth)] = NO_SURFACE_BGR
        panels.append(panel)
    for image, label in zip(panels, ["photo", *labels]):
        cv2.putText(image, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 160), 1, cv2.LINE_AA)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    params = [cv2.IMWRITE_JPEG_QUALITY, 85] if args.out.lower().endswith((".jpg", ".jpeg")) else [cv2.IMWRITE_PNG_COMPRESSION, 9]
    cv2.imwrite(args.out, np.concatenate(panels, 1), params)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
