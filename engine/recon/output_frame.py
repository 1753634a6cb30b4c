"""The frame a reconstruction is written in: the Z-up, floor-at-zero metric world, or the capture's own.

The engine always reconstructs in the prepared world (Z up, floor at z = 0, metres: what the network
and the stereo depth ranges assume). `prepare_capture` says, once, what took the capture's posed
frames there: `PreparedCapture.similarity`, x_world = s R x_capture + t. Writing in the capture's frame
applies its inverse to the finished mesh, so a pipeline can lay the mesh over its own cameras (a NeRF
transforms.json, a COLMAP model) without an alignment step. Every result records both directions
(`frame_record`), whichever frame it is written in, so a pipeline can map either way.

There is no capture frame when structure from motion estimated the poses (the photos came without
any): its model's frame is arbitrary, and the world is then the only frame of the result.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional, TypeVar

import numpy as np

from ..errors import VortxError
from ..poses.align import Similarity
from ..poses.prepare import PreparedCapture
from .settings import FRAME_CAPTURE, FRAME_WORLD, FRAMES  # noqa: F401 (the frames are a setting: ReconSettings.frame)

CONVENTION = ("x_to = scale * rotation @ x_from + translation (rotation rows as listed; 'matrix' is the same "
              "4x4 homogeneous transform); the world is in metres, the capture frame in the capture's own units")

MeshLike = TypeVar("MeshLike")  # engine.mesh_io.Mesh or engine.texture.textured_mesh.TexturedMesh


# Why there is no capture frame, said the same way by every entry point.
SFM_HAS_NO_CAPTURE_FRAME = ("structure from motion estimated the poses, in a frame of its own choosing, so there are no "
                            "capture coordinates to map the result to: it is in the Z-up world")
NO_POSES_NO_CAPTURE_FRAME = "no frame of the capture has a pose"


def capture_frame_missing(prepared: PreparedCapture) -> Optional[str]:
    """Why the result has no capture frame to be written in, or None when it has one."""
    if prepared.ran_sfm:
        return SFM_HAS_NO_CAPTURE_FRAME
    if prepared.similarity is None:
        return NO_POSES_NO_CAPTURE_FRAME
    return None


def world_to_output(prepared: PreparedCapture, frame: str) -> Similarity:
    """The similarity from the reconstruction world to the output `frame` (one of FRAMES).

    Raises VortxError for the capture frame of a capture without poses of its own."""
    if frame not in FRAMES:
        raise VortxError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    if frame == FRAME_WORLD:
        return Similarity.identity()
    missing = capture_frame_missing(prepared)
    if missing is not None:
        raise VortxError(f"--frame {FRAME_CAPTURE}: {missing}. Use --frame {FRAME_WORLD}, or give the capture's own "
                         "poses (transforms.json, a COLMAP model)")
    assert prepared.similarity is not None
    return prepared.similarity.inverse()


def frame_record(prepared: PreparedCapture, frame: str) -> dict[str, Any]:
    """JSON-ready: which frame the result is in and the similarities between the capture's frame, the
    world and the output, both ways (None, with "note", when the capture has no frame of its own)."""
    return similarity_record(prepared.similarity if capture_frame_missing(prepared) is None else None, frame,
                             world_to_output(prepared, frame), capture_frame_missing(prepared))


def similarity_record(capture_to_world: Optional[Similarity], frame: str, output_from_world: Similarity,
                      note: Optional[str] = None) -> dict[str, Any]:
    """`frame_record` from its parts (for a world that moved after preparation, e.g. Blender's Set Scale)."""
    record: dict[str, Any] = {"frame": frame, "convention": CONVENTION, "world_to_output": output_from_world.to_dict()}
    if capture_to_world is None:
        record.update(capture_to_world=None, world_to_capture=None, capture_to_output=None, output_to_capture=None,
                      note=note or "the capture has no coordinates of its own")
        return record
    capture_to_output = capture_to_world.then(output_from_world)
    record.update(capture_to_world=capture_to_world.to_dict(), world_to_capture=capture_to_world.inverse().to_dict(),
                  capture_to_output=capture_to_output.to_dict(), output_to_capture=capture_to_output.inverse().to_dict())
    return record


def record_in_frame(record: dict[str, Any], frame: str, world_change: Optional[Similarity] = None) -> dict[str, Any]:
    """A `frame_record` made again for a result in `frame`, after the world moved by `world_change`
    (x_new = change(x_world), e.g. Blender's Set Scale) when given.

    Raises VortxError for the capture frame when the record has none (its "note" says why)."""
    if frame not in FRAMES:
        raise VortxError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    capture_to_world = similarity_from_record(record.get("capture_to_world"))
    if capture_to_world is None:
        note = record.get("note") or "the capture has no coordinates of its own"
        if frame == FRAME_CAPTURE:
            raise VortxError(note)
        return similarity_record(None, frame, Similarity.identity(), note)
    if world_change is not None:
        capture_to_world = capture_to_world.then(world_change)
    return similarity_record(capture_to_world, frame,
                             capture_to_world.inverse() if frame == FRAME_CAPTURE else Similarity.identity())


def similarity_from_record(entry: Optional[dict[str, Any]]) -> Optional[Similarity]:
    """A similarity as `Similarity.to_dict` wrote it (a record's "capture_to_world" ...), or None."""
    if entry is None:
        return None
    return Similarity(np.array(entry["rotation"], dtype=np.float64), np.array(entry["translation"], dtype=np.float64),
                      float(entry["scale"]))


def moved_mesh(mesh: MeshLike, similarity: Similarity) -> MeshLike:
    """`mesh` (any dataclass with vertices (V, 3) and normals (V, 3) or None) with its vertices moved by
    `similarity` and its normals rotated; faces, colours, texture and attributes are kept."""
    vertices = similarity.apply_points(mesh.vertices).astype(mesh.vertices.dtype)  # type: ignore[attr-defined]
    normals = mesh.normals  # type: ignore[attr-defined]
    if normals is not None:
        normals = similarity.apply_directions(normals).astype(normals.dtype)
    return replace(mesh, vertices=vertices, normals=normals)  # type: ignore[type-var]
