"""The VR preset: a light mesh a headset can draw, textured from the photos.

Drop small pieces (specks in the air), decimate to a face budget (quadric edge collapse,
fast-simplification), then the atlas and the bake (bake.py). Decimation moves and merges vertices,
so the vertex colours and the confidence layer are carried over from the nearest source vertex.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import Mesh
from ..meshops import compact, remove_small_pieces, vertex_normals
from ..native_worker import run_in_child
from .bake import bake_texture
from .options import TextureOptions
from .textured_mesh import TexturedMesh
from .views import TextureView


DECIMATE_TRIES = 4
DECIMATE_STEP = "mesh decimation (fast-simplification)"
DECIMATE_TIME_LIMIT_S = (120.0, 5e-4)  # seconds: start plus per face; it takes ~1 s per 100k faces, so only a hang meets it
DECIMATE_ADVICE = "Try again; if it fails again, bake with another face budget (Face Budget, --face-budget)."


def decimate(mesh: Mesh, face_budget: int, cancel: Optional[CancelToken] = None) -> Mesh:
    """At most `face_budget` faces (0 or a budget above the mesh's faces: the mesh as it is).

    The edge collapses run in a child process (native_worker.py): a crash or hang of the native
    library raises NativeStepError instead of ending this process (Blender, inside Blender).
    """
    if face_budget <= 0 or len(mesh.faces) <= face_budget:
        return mesh
    from scipy.spatial import cKDTree  # defers scipy: slow to import

    result = run_in_child(DECIMATE_STEP, simplified,
                          {"points": np.asarray(mesh.vertices, np.float64), "faces": np.asarray(mesh.faces, np.int32)},
                          {"face_budget": int(face_budget)},
                          time_limit_s=DECIMATE_TIME_LIMIT_S[0] + DECIMATE_TIME_LIMIT_S[1] * len(mesh.faces),
                          cancel=cancel, advice=DECIMATE_ADVICE)
    points, faces = result["points"], result["faces"]
    vertices = points.astype(np.float32)
    faces = faces.astype(np.int32)
    _, nearest = cKDTree(np.asarray(mesh.vertices, np.float64)).query(points)

    def carried(values: Optional[np.ndarray]) -> Optional[np.ndarray]:
        return None if values is None else np.asarray(values)[nearest]

    return Mesh(vertices=vertices, faces=faces, normals=vertex_normals(vertices, faces), colors=carried(mesh.colors),
                attributes={k: carried(v) for k, v in mesh.attributes.items()})


def simplified(points: np.ndarray, faces: np.ndarray, face_budget: int) -> dict:
    """Quadric edge collapse (fast-simplification) to at most `face_budget` faces, run in the child
    process (see decimate). points (V, 3) float64, faces (F, 3) int32 -> {"points", "faces"}."""
    import fast_simplification  # defers fast_simplification: optional native package

    # The collapse order is approximate: small budgets can end above the target (300 -> 505 faces on
    # the demo room), so it is run again on its own result, a few times at most.
    for _ in range(DECIMATE_TRIES):
        points, faces = fast_simplification.simplify(points, faces.astype(np.int32),
                                                     target_count=int(min(face_budget, len(faces) - 1)))
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
        # Edge collapses can leave the same triangle twice (glTF exporters then drop one): keep the first.
        _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
        faces = faces[np.sort(first)]
        points, faces = compact(points, faces)
        if len(faces) <= face_budget:
            break
    return {"points": points, "faces": faces}


def vr_mesh(mesh: Mesh, options: TextureOptions, cancel: Optional[CancelToken] = None) -> tuple[Mesh, dict]:
    """Small pieces dropped, then decimated to the face budget. -> (mesh, stats)."""
    light, pieces = remove_small_pieces(mesh, min_fraction=options.min_piece_fraction)
    light = decimate(light, options.face_budget, cancel)
    return light, {"faces_in": int(len(mesh.faces)), "pieces_removed": pieces.removed_pieces,
                   "faces_after_pieces": int(len(mesh.faces) - pieces.removed_faces), "faces": int(len(light.faces))}


def textured_result(mesh: Mesh, views: Sequence[TextureView], options: TextureOptions,
                    progress: Optional[ProgressCallback] = None, cancel: Optional[CancelToken] = None,
                    ) -> tuple[TexturedMesh, dict]:
    """The VR preset end to end: `vr_mesh`, then `bake_texture`. -> (textured mesh, stats)."""
    options.validate()
    report(progress, "texture: decimate", 0, 1)
    light, stats = vr_mesh(mesh, options, cancel)
    report(progress, "texture: decimate", 1, 1)
    check(cancel)
    textured, bake_stats = bake_texture(light, views, options, progress, cancel)
    return textured, {"vr": stats, **bake_stats, "headset": options.preset, "texture_format": options.texture_format,
                      "geometry": options.geometry}
