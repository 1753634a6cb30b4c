"""The demo's look inside Blender: the estimated cameras read back from the batch's .blend, the mesh
rendered from a capture camera (Workbench, vertex colours) and the GLB as Blender's own glTF
importer opens it (Cycles). Each function gets the enabled `vortx` add-on module."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from engine.capture.writers import write_scannet

from .messages import DemoError


def read_capture_cameras(addon: ModuleType, blend: Path, render_to: Path, posed_dir: Path) -> tuple[dict[str, np.ndarray], str]:
    """Open the batch's .blend: return {photo stem: estimated camera-to-world} and render the mesh
    from the middle capture camera (Workbench, vertex colours, the photo's resolution) into
    `render_to`. Returns also the rendered photo's path. The posed capture is written to `posed_dir`
    (ScanNet layout), so the other methods are scored on exactly the same poses."""
    import bpy  # defers bpy: the demo's parent process loads Blender only once the batch has run

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    cameras = addon.vortx_blender.cameras
    capture = cameras.posed_capture_from_scene(scene)
    if capture is None or not capture.posed_frames:
        raise DemoError(f"{blend} has no posed capture cameras")
    estimated = {Path(f.image_path).stem: f.pose for f in capture.posed_frames}
    write_scannet(capture, posed_dir, overwrite=True)
    capture_cameras = sorted((o for o in scene.objects if cameras.is_capture_camera(o)), key=lambda o: int(o[cameras.PROP_FRAME]))
    camera = capture_cameras[len(capture_cameras) // 2]
    render_mesh(scene, camera, render_to)
    return estimated, str(camera[cameras.PROP_IMAGE])


def render_mesh(scene: Any, camera: Any, path: Path) -> None:
    import bpy  # defers bpy: the demo's parent process loads Blender only once the batch has run

    scene.camera = camera
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.light = "STUDIO"
    scene.display.shading.color_type = "VERTEX"
    # The photos are sRGB and the vertex colours came from them: no filmic/AgX tone curve on top.
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_percentage = 100  # resolution_x/y were set to the photos' size on import
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise DemoError(f"the Workbench render did not write {path}")


def render_glb(addon: ModuleType, blend: Path, glb: Path, photo: str, path: Path) -> None:
    """The GLB as a VR engine would get it, opened in Blender with its own glTF importer and rendered
    with Cycles from the capture camera of `photo` (the batch's mesh hidden), into `path`."""
    import bpy  # defers bpy: the demo's parent process loads Blender only once the batch has run

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    for obj in scene.objects:
        if obj.type == "MESH":
            obj.hide_render = True
    if "FINISHED" not in bpy.ops.import_scene.gltf(filepath=str(glb)):
        raise DemoError(f"Blender's glTF importer could not read {glb}")
    cameras = addon.vortx_blender.cameras
    scene.camera = next(o for o in scene.objects if cameras.is_capture_camera(o) and o[cameras.PROP_IMAGE] == photo)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"  # the texture holds photo colours: no tone curve on top
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise DemoError(f"the Cycles render did not write {path}")
