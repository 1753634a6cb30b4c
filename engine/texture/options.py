"""The texture bake's knobs and the VR preset's defaults, in one place.

User-facing ones (texture size, face budget) are also ReconSettings fields, so the CLI, the batch
script and Blender offer them (engine/recon/settings.py reads the defaults from here).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import VortxError

TEXTURE_SIZES = (512, 1024, 2048, 4096, 8192)
TEXTURE_FORMATS = ("png", "ktx2-etc1s", "ktx2-uastc")  # how a GLB stores the texture (presets.py)
GEOMETRY_COMPRESSIONS = ("none", "draco")  # how a GLB stores the mesh (presets.py)
MOBILE_TEXTURE_SIZE = 2048  # standalone headsets (Quest class): 2048 keeps a room's texture at 16 MB of GPU memory


@dataclass(frozen=True)
class TextureOptions:
    """texture_size: the square texture's side in texels (4096 for desktop VR, 2048 for mobile headsets).
    face_budget: the VR preset decimates to at most this many faces before the atlas (0 = keep all).
    min_piece_fraction: pieces with less than this share of the faces are dropped before the atlas
    (specks in the air cost charts and draw calls).
    padding: texels between charts, filled with the chart's border colour so mipmaps do not bleed.
    blend_power: view weights are raised to this power before blending: 1 blends the views by their
    footprint weight, large values pick the best view (sharper where poses and geometry are exact,
    steps at view changes). Measured on held-out photos (engine eval-texture, 2048 px): demo room
    PSNR 29.81 / 28.88 dB at 1 / 4 (vertex colours 27.60), fox photos 21.87 / 20.89 (20.89).
    occlusion_long_side: the long side of the depth maps used for the occlusion test (pixels).
    occlusion_tolerance: metres a point may lie behind the rendered depth and still count as seen (two
    voxels of the reconstruction, as for the vertex colours: ReconSettings sets it from its voxel size).
    exposure: even out exposure and white balance between the photos (exposure.py).
    texture_format, geometry: how a GLB stores the texture and the mesh (TEXTURE_FORMATS,
    GEOMETRY_COMPRESSIONS); preset: the headset preset they came from (presets.py, `with_preset`).
    """

    texture_size: int = 4096
    face_budget: int = 100_000
    min_piece_fraction: float = 0.001
    padding: int = 4
    blend_power: float = 1.0
    occlusion_long_side: int = 320
    occlusion_tolerance: float = 0.08
    exposure: bool = True
    texture_format: str = "png"
    geometry: str = "none"
    preset: str = "desktop"

    def validate(self) -> None:
        if self.texture_size not in TEXTURE_SIZES:
            raise VortxError(f"texture size must be one of {', '.join(map(str, TEXTURE_SIZES))}, got {self.texture_size}")
        if self.face_budget < 0:
            raise VortxError(f"face budget must be 0 (keep every face) or positive, got {self.face_budget}")
        if self.face_budget and self.face_budget < 100:
            raise VortxError(f"face budget {self.face_budget} is too small for a room; use at least 100 (or 0 to keep all)")
        if not 0.0 <= self.min_piece_fraction < 1.0:
            raise VortxError(f"min piece fraction must be in [0, 1), got {self.min_piece_fraction}")
        if self.padding < 0 or self.blend_power <= 0 or self.occlusion_long_side < 16 or self.occlusion_tolerance <= 0:
            raise VortxError("texture padding must be >= 0, blend power and occlusion tolerance > 0, the occlusion size >= 16 pixels")
        if self.texture_format not in TEXTURE_FORMATS or self.geometry not in GEOMETRY_COMPRESSIONS:
            raise VortxError(f"texture format must be one of {', '.join(TEXTURE_FORMATS)} and geometry compression one of "
                             f"{', '.join(GEOMETRY_COMPRESSIONS)}, got {self.texture_format!r} / {self.geometry!r}")
