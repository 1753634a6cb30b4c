"""Textured results: a UV atlas for the mesh, a texture baked from the full-resolution photos, and the
files an engine or a headset loads (GLB with the texture embedded, OBJ + MTL + PNG).

The pipeline (`bake.bake_texture`): atlas (`atlas.py`, xatlas) -> the surface point of every texel
(`texels.py`) -> per photo: occlusion test, view weight, exposure gain (`views.py`, `exposure.py`) ->
blended colour, gutters filled (`bake.py`). The VR preset (`vr.py`) decimates to a face budget and
drops small pieces first. Writers: `files.py`. No bpy here: Blender's layer is vortx_blender/texture.py.
"""

from .options import TextureOptions
from .textured_mesh import TexturedMesh

__all__ = ["TextureOptions", "TexturedMesh"]
