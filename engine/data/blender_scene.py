"""Building a RoomSpec as Blender data (bpy, imported lazily: this module is only used by rendering).

Everything goes into a NEW scene whose datablocks are tracked and removed by `BlenderRoom.close()`,
so rendering rooms never touches the user's scene and one process can render many rooms.
Materials carry both a procedural node tree (what Cycles renders) and an image texture set as the
active node (what Workbench shows in TEXTURE colour mode); the image is only painted when the fast
renderer needs it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .geometry import MeshPart
from .room import LightSpec, MaterialSpec, RoomSpec
from .textures import material_image


class SceneBuilder:
    """Creates and remembers Blender datablocks for one room."""

    def __init__(self, name: str) -> None:
        import bpy  # defers bpy: only inside Blender

        self.bpy = bpy
        self.created: list[Any] = []
        self.scene = self._track(bpy.data.scenes.new(name))

    def _track(self, datablock: Any) -> Any:
        self.created.append(datablock)
        return datablock

    def remove_all(self) -> None:
        """Delete every datablock this builder made (scene last, after what it uses)."""
        bpy = self.bpy
        alive = [d for d in self.created if d is not None]
        try:
            bpy.data.batch_remove(ids=[d for d in alive if d != self.scene])
        finally:
            if self.scene.name in bpy.data.scenes:
                bpy.data.scenes.remove(self.scene)
        self.created.clear()

    # ------------------------------------------------------------------------------ geometry

    def add_meshes(self, parts: list[MeshPart]) -> None:
        """One object per (material, shadow flag): few objects keep scene building fast."""
        groups: dict[tuple[str, bool], list[MeshPart]] = {}
        for p in parts:
            groups.setdefault((p.material, p.casts_shadow), []).append(p)
        for (material, shadow), members in groups.items():
            vertices, faces, uvs, offset = [], [], [], 0
            for p in members:
                vertices.append(p.vertices)
                faces.append(p.faces + offset)
                uvs.append(p.uvs)
                offset += len(p.vertices)
            mesh = self._mesh(f"{material}{'' if shadow else '_noshadow'}", np.concatenate(vertices),
                              np.concatenate(faces), np.concatenate(uvs))
            mesh.materials.append(self.materials[material])
            obj = self._track(self.bpy.data.objects.new(mesh.name, mesh))
            if not shadow:
                obj.visible_shadow = False  # outside boxes must not block the sun through windows
            self.scene.collection.objects.link(obj)

    def _mesh(self, name: str, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray) -> Any:
        """Mesh datablock through the fast attribute API (blender-notes.md section 5)."""
        mesh = self._track(self.bpy.data.meshes.new(name))
        mesh.vertices.add(len(vertices))
        mesh.attributes["position"].data.foreach_set("vector", vertices.astype(np.float32).ravel())
        mesh.loops.add(faces.size)
        mesh.polygons.add(len(faces))
        mesh.attributes[".corner_vert"].data.foreach_set("value", faces.astype(np.int32).ravel())
        mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
        mesh.update(calc_edges=True)
        layer = mesh.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", uvs.astype(np.float32).ravel())
        return mesh

    # ----------------------------------------------------------------------------- materials

    def add_materials(self, spec: RoomSpec, with_images: bool, image_size: int = 256) -> None:
        self.materials = {}
        for name, m in spec.materials.items():
            self.materials[name] = self._material(m, spec.seed if with_images else None, image_size)

    def _material(self, m: MaterialSpec, image_seed: int | None, image_size: int) -> Any:
        bpy = self.bpy
        mat = self._track(bpy.data.materials.new(m.name))
        nt = mat.node_tree
        nodes, links = nt.nodes, nt.links
        bsdf = nodes.get("Principled BSDF")
        coords = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value = (0.0, 0.0, m.rotation)
        links.new(coords.outputs["Object"], mapping.inputs["Vector"])
        vec = mapping.outputs["Vector"]
        a, b, tint = ([*c, 1.0] for c in m.colors)

        color = self._pattern(nodes, links, m, vec, a, b)
        # Fine noise tinting the colour: texture at the scale of a few pixels, for SIFT and the CNN.
        detail = nodes.new("ShaderNodeTexNoise")
        detail.inputs["Scale"].default_value = m.detail_scale
        detail.inputs["Detail"].default_value = 8.0
        links.new(vec, detail.inputs["Vector"])
        stretch = nodes.new("ShaderNodeMapRange")  # noise Fac sits near 0.5: stretch it to 0..1
        stretch.inputs["From Min"].default_value = 0.3
        stretch.inputs["From Max"].default_value = 0.7
        links.new(detail.outputs["Fac"], stretch.inputs["Value"])
        strength = nodes.new("ShaderNodeMath")
        strength.operation = "MULTIPLY"
        strength.inputs[1].default_value = m.detail_strength
        links.new(stretch.outputs["Result"], strength.inputs[0])
        tinted = self._mix(nodes, links, strength.outputs[0], color, tint)
        if m.speckle_strength > 0:
            # Spots: Voronoi cells whose centre region (distance below a random radius) is darkened.
            cells = nodes.new("ShaderNodeTexVoronoi")
            cells.inputs["Scale"].default_value = m.speckle_scale
            cells.inputs["Randomness"].default_value = 1.0
            links.new(vec, cells.inputs["Vector"])
            spot = nodes.new("ShaderNodeMapRange")  # distance 0.3 -> 0 (outside) ... 0.2 -> 1 (inside)
            spot.inputs["From Min"].default_value = 0.3
            spot.inputs["From Max"].default_value = 0.2
            links.new(cells.outputs["Distance"], spot.inputs["Value"])
            alpha = nodes.new("ShaderNodeMath")
            alpha.operation = "MULTIPLY"
            alpha.inputs[1].default_value = m.speckle_strength
            links.new(spot.outputs["Result"], alpha.inputs[0])
            dark = [min(1.0, 0.35 * c) for c in m.colors[1]] + [1.0]
            tinted = self._mix(nodes, links, alpha.outputs[0], tinted, dark)
        links.new(tinted, bsdf.inputs["Base Color"])
        bsdf.inputs["Roughness"].default_value = m.roughness
        if m.emission > 0:
            links.new(tinted, bsdf.inputs["Emission Color"])
            bsdf.inputs["Emission Strength"].default_value = m.emission

        if image_seed is not None:
            # Workbench shows the active image texture node; it is not linked into the shader.
            pixels = material_image(m, image_seed, image_size)
            image = self._track(bpy.data.images.new(f"tex_{m.name}", image_size, image_size, alpha=False, float_buffer=True))
            rgba = np.concatenate([pixels, np.ones(pixels.shape[:2] + (1,), np.float32)], axis=2)
            image.pixels.foreach_set(rgba[::-1].ravel())  # Blender images start at the bottom row
            tex = nodes.new("ShaderNodeTexImage")
            tex.image = image
            nodes.active = tex
        return mat

    def _pattern(self, nodes, links, m: MaterialSpec, vec, a, b):
        """The two-colour pattern of the material as a colour socket."""
        if m.pattern == "brick":
            brick = nodes.new("ShaderNodeTexBrick")
            brick.inputs["Scale"].default_value = m.scale
            brick.inputs["Color1"].default_value = a
            brick.inputs["Color2"].default_value = b
            brick.inputs["Mortar"].default_value = [0.5 * x for x in a[:3]] + [1.0]
            brick.inputs["Mortar Size"].default_value = 0.01
            links.new(vec, brick.inputs["Vector"])
            return brick.outputs["Color"]
        if m.pattern == "checker":
            checker = nodes.new("ShaderNodeTexChecker")
            checker.inputs["Scale"].default_value = m.scale * 2
            checker.inputs["Color1"].default_value = a
            checker.inputs["Color2"].default_value = b
            links.new(vec, checker.inputs["Vector"])
            return checker.outputs["Color"]
        if m.pattern == "voronoi":
            tex = nodes.new("ShaderNodeTexVoronoi")
            tex.inputs["Scale"].default_value = m.scale * 3
            links.new(vec, tex.inputs["Vector"])
            fac = tex.outputs["Color"]  # random value per cell
        elif m.pattern in ("wave", "marble"):
            tex = nodes.new("ShaderNodeTexWave")
            tex.inputs["Scale"].default_value = m.scale * (2 if m.pattern == "wave" else 1)
            tex.inputs["Distortion"].default_value = 2.0 if m.pattern == "wave" else 8.0
            tex.inputs["Detail"].default_value = 2.0
            links.new(vec, tex.inputs["Vector"])
            fac = tex.outputs["Fac"]
        else:  # noise
            tex = nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = m.scale * 2
            tex.inputs["Detail"].default_value = 6.0
            links.new(vec, tex.inputs["Vector"])
            ramp = nodes.new("ShaderNodeValToRGB")  # stretch noise's narrow range to full contrast
            ramp.color_ramp.elements[0].position = 0.35
            ramp.color_ramp.elements[1].position = 0.65
            links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
            fac = ramp.outputs["Color"]
        return self._mix(nodes, links, fac, a, b)

    @staticmethod
    def _mix(nodes, links, factor, a, b):
        """RGBA mix node; `a`/`b` are sockets or RGBA lists. Returns the result socket."""
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        links.new(factor, mix.inputs[0])
        for index, value in ((6, a), (7, b)):  # RGBA A/B inputs (platform-notes section 2)
            if isinstance(value, list):
                mix.inputs[index].default_value = value
            else:
                links.new(value, mix.inputs[index])
        return mix.outputs[2]

    # -------------------------------------------------------------------------- lights, world

    def add_lights(self, lights: list[LightSpec]) -> None:
        from mathutils import Vector  # defers mathutils: only inside Blender

        for i, spec in enumerate(lights):
            data = self._track(self.bpy.data.lights.new(f"light{i}", spec.kind))
            data.color = spec.color
            data.energy = spec.power
            if spec.kind == "AREA":
                data.size = spec.size
            elif spec.kind == "POINT":
                data.shadow_soft_size = spec.size
            else:
                data.angle = spec.size
            obj = self._track(self.bpy.data.objects.new(f"light{i}", data))
            obj.location = spec.location
            # Lights shine along their local -Z.
            obj.rotation_euler = Vector(spec.direction).to_track_quat("-Z", "Y").to_euler()
            self.scene.collection.objects.link(obj)

    def add_world(self, color: list[float], strength: float) -> None:
        world = self._track(self.bpy.data.worlds.new("room_world"))
        background = world.node_tree.nodes.get("Background")
        background.inputs["Color"].default_value = [*color, 1.0]
        background.inputs["Strength"].default_value = strength
        self.scene.world = world
