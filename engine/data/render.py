"""Rendering a built room headless with bpy: colour (JPEG) and exact planar depth per camera pose.

Verified recipe (platform-notes.md section 2): the Z pass goes through a compositor File Output node
(Blender 5.0: `scene.compositing_node_group`) into a 32-bit EXR that is read back in-process; Z is
planar depth along the camera axis in metres. Cycles (CPU) gives the photo-like images; Workbench in
TEXTURE colour mode with numpy-painted images is ~50x faster for bulk data. Both give the same Z.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..process_guards import keep_triton_out
from .blender_scene import SceneBuilder
from .geometry import MeshPart
from .room import RoomSpec

RENDERERS = ("cycles", "workbench")
NO_HIT_DEPTH = 1e4  # Z of pixels that hit nothing is ~1e10; anything beyond this is "no surface"
CLIP_START = 0.05


@dataclass
class RenderSettings:
    renderer: str = "cycles"
    width: int = 320
    height: int = 240
    hfov_deg: float = 60.0  # ScanNet's depth camera has ~58 deg
    samples: int = 16  # Cycles only
    denoise: bool = True  # Cycles only: OpenImageDenoise (+~25 % time); 16 spp alone is grainy
    max_bounces: int = 4
    exposure: float = -0.8  # film exposure in stops: keeps pale walls in the mid-tones where AgX keeps contrast
    jpeg_quality: int = 90
    texture_size: int = 256  # Workbench image textures, pixels per metre of surface

    def __post_init__(self) -> None:
        if self.renderer not in RENDERERS:
            raise ValueError(f"renderer must be one of {RENDERERS}, not {self.renderer!r}")
        if self.width < 8 or self.height < 8:
            raise ValueError("resolution must be at least 8x8")

    @property
    def focal_px(self) -> float:
        return self.width / 2.0 / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics in the engine's convention: pixel (0, 0) covers [0, 1)^2, so Blender's
        unshifted principal point is exactly (W/2, H/2)."""
        f = self.focal_px
        return np.array([[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0.0, 0.0, 1.0]])

    def to_json(self) -> dict:
        return asdict(self)


class RoomRenderer:
    """A room built in its own Blender scene, ready to render from any pose. Use as a context manager."""

    def __init__(self, spec: RoomSpec, parts: list[MeshPart], settings: RenderSettings,
                 lossless_color: bool = False) -> None:
        """lossless_color: write the colour as 8-bit PNG instead of JPEG (a "real" room degrades the
        render before its one JPEG compression, engine.data.degrade)."""

        keep_triton_out()  # a Workbench render here must not meet Triton later (see process_guards)
        import bpy  # defers bpy: only inside Blender

        self.bpy = bpy
        self.settings = settings
        self.lossless_color = lossless_color
        self.builder = SceneBuilder(f"vortx_room_{spec.seed}")
        self._tmp = tempfile.TemporaryDirectory(prefix="vortx-render-")
        try:
            b = self.builder
            b.add_materials(spec, with_images=settings.renderer == "workbench", image_size=settings.texture_size)
            b.add_meshes(parts)
            b.add_lights(spec.lights)
            b.add_world(spec.world_color, spec.world_strength)
            self.scene = b.scene
            self.camera = self._camera()
            self._configure_render()
            self._configure_depth_output()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> "RoomRenderer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self.builder is not None:
            self.builder.remove_all()
            self.builder = None  # type: ignore[assignment]
        self._tmp.cleanup()

    # ---------------------------------------------------------------------------------- setup

    def _camera(self) -> Any:
        bpy, s = self.bpy, self.settings
        data = self.builder._track(bpy.data.cameras.new("scan_camera"))
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = 36.0
        data.lens = s.focal_px * 36.0 / s.width  # f_px = lens / sensor_width * W
        data.clip_start = CLIP_START
        data.clip_end = 200.0
        obj = self.builder._track(bpy.data.objects.new("scan_camera", data))
        self.scene.collection.objects.link(obj)
        self.scene.camera = obj
        return obj

    def _configure_render(self) -> None:
        s, scene = self.settings, self.scene
        r = scene.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = s.width, s.height, 100
        if self.lossless_color:
            r.image_settings.file_format = "PNG"
            r.image_settings.color_depth = "8"
            r.image_settings.compression = 15  # fast: the PNG is an intermediate
        else:
            r.image_settings.file_format = "JPEG"
            r.image_settings.quality = s.jpeg_quality
        r.use_compositing = True
        scene.view_settings.view_transform = "AgX"
        # AgX's base look is flat; more local contrast keeps textures visible to SIFT and the CNN.
        scene.view_settings.look = "AgX - Medium High Contrast"
        scene.view_settings.exposure = s.exposure
        if s.renderer == "cycles":
            r.engine = "CYCLES"
            c = scene.cycles
            c.device = "CPU"
            c.samples = s.samples
            c.use_adaptive_sampling = False  # fixed work per frame: predictable time, same noise level
            c.use_denoising = s.denoise
            c.max_bounces = s.max_bounces
            c.diffuse_bounces = min(3, s.max_bounces)
            c.glossy_bounces = min(2, s.max_bounces)
            c.transmission_bounces = 0
            c.volume_bounces = 0
            c.sample_clamp_indirect = 5.0  # tames fireflies from light bouncing through windows
            c.seed = 0
        else:
            r.engine = "BLENDER_WORKBENCH"
            shading = scene.display.shading
            shading.light = "STUDIO"
            shading.color_type = "TEXTURE"
            shading.show_cavity = False

    def _configure_depth_output(self) -> None:
        bpy, scene = self.bpy, self.scene
        scene.view_layers[0].use_pass_z = True
        tree = self.builder._track(bpy.data.node_groups.new("vortx_depth", "CompositorNodeTree"))
        scene.compositing_node_group = tree
        layers = tree.nodes.new("CompositorNodeRLayers")
        layers.scene = scene
        out = tree.nodes.new("CompositorNodeOutputFile")
        out.format.media_type = "IMAGE"  # must precede file_format (enum error otherwise)
        out.format.file_format = "OPEN_EXR"
        out.format.color_depth = "32"
        out.file_output_items.new("FLOAT", "Z")
        tree.links.new(layers.outputs["Depth"], out.inputs["Z"])
        out.directory = self._tmp.name + "/"
        out.file_name = "depth_"
        self._depth_file = Path(self._tmp.name) / "depth_Z.exr"

    # -------------------------------------------------------------------------------- render

    def render(self, cam_to_world: np.ndarray, color_path: Path) -> np.ndarray:
        """Render one view: writes the colour JPEG (PNG if lossless_color) to `color_path`, returns planar depth (H, W) float32
        metres (0 where the ray hits nothing). cam_to_world (4, 4) in OpenCV axes."""
        from mathutils import Matrix  # defers mathutils: only inside Blender

        # Blender cameras look down -Z with +Y up: the OpenCV camera rotated 180 deg about x.
        self.camera.matrix_world = Matrix((np.asarray(cam_to_world) @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist())
        self.scene.render.filepath = str(color_path)
        color_path.parent.mkdir(parents=True, exist_ok=True)
        self.bpy.ops.render.render(write_still=True, scene=self.scene.name)
        depth = self._read_depth()
        self._depth_file.unlink(missing_ok=True)
        return depth

    def _read_depth(self) -> np.ndarray:
        image = self.bpy.data.images.load(str(self._depth_file), check_existing=False)
        try:
            width, height = image.size
            pixels = np.empty(width * height * image.channels, np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            self.bpy.data.images.remove(image)
        depth = pixels.reshape(height, width, -1)[::-1, :, 0].copy()  # Blender rows start at the bottom
        depth[~np.isfinite(depth) | (depth > NO_HIT_DEPTH)] = 0.0
        return depth

    # -------------------------------------------------------------------------- ground truth

    def scene_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The evaluated triangles of every mesh object in world metres: (vertices (V, 3) float32,
        faces (F, 3) int32) -- exactly the geometry that was rendered."""
        depsgraph = self.scene.view_layers[0].depsgraph
        depsgraph.update()
        vertices, faces, offset = [], [], 0
        for obj in sorted(self.scene.objects, key=lambda o: o.name):
            if obj.type != "MESH":
                continue
            evaluated = obj.evaluated_get(depsgraph)
            mesh = evaluated.to_mesh()
            try:
                mesh.calc_loop_triangles()
                co = np.empty(len(mesh.vertices) * 3, np.float32)
                mesh.vertices.foreach_get("co", co)
                tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
                mesh.loop_triangles.foreach_get("vertices", tris)
                world = np.array(evaluated.matrix_world, np.float64)
                co = co.reshape(-1, 3).astype(np.float64) @ world[:3, :3].T + world[:3, 3]
                vertices.append(co.astype(np.float32))
                faces.append(tris.reshape(-1, 3) + offset)
                offset += len(co)
            finally:
                evaluated.to_mesh_clear()
        return np.concatenate(vertices), np.concatenate(faces).astype(np.int32)


def bpy_version() -> str:
    import bpy  # defers bpy: only inside Blender

    return bpy.app.version_string
