"""USDZ: the textured result for Apple Vision Pro and iOS / macOS Quick Look, with Pixar's USD (usd-core).

One package holding `room.usdc` and its PNG texture: the stage is Y up in metres (upAxis "Y",
metersPerUnit 1), as Apple's tools expect, so the engine's Z-up world (x, y, z) is written as
(x, z, -y), as in the GLB. The mesh is one `UsdGeom.Mesh` with normals and face-varying texture
coordinates `st` (origin at the bottom left, as TexturedMesh keeps them), bound to a UsdPreviewSurface
whose diffuse colour reads the texture (sRGB, roughness 1, no metal: the photos carry the light).
The confidence layer travels as float primvars (`observations`, ...).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from ..errors import VortxError
from ..mesh_io import PathLike
from .encoders import import_usd
from .file_parts import encode_png, staged, z_up_to_y_up
from .textured_mesh import TexturedMesh

ROOT, MESH, MATERIAL = "/VoRTX", "/VoRTX/Room", "/VoRTX/Materials/Texture"
TEXTURE_NAME = "texture.png"


def write_usdz(path: PathLike, mesh: TexturedMesh, needed_by: str = "a USDZ file") -> Path:
    """Write `mesh` as a USDZ package at `path` (written under a temporary name, then renamed)."""
    import_usd(needed_by)
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdUtils, Vt  # defers pxr (usd-core): optional encoder

    path = Path(path)
    if len(mesh.faces) == 0:
        raise VortxError("the mesh has no faces; there is nothing to write")
    with tempfile.TemporaryDirectory(prefix="vortx_usdz_") as folder:
        layer = Path(folder) / (path.stem + ".usdc")
        (Path(folder) / TEXTURE_NAME).write_bytes(encode_png(mesh.texture))
        stage = Usd.Stage.CreateNew(str(layer))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        root = UsdGeom.Xform.Define(stage, ROOT)
        stage.SetDefaultPrim(root.GetPrim())

        faces = np.asarray(mesh.faces, np.int32)
        geometry = UsdGeom.Mesh.Define(stage, MESH)
        points = z_up_to_y_up(mesh.vertices)
        geometry.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        geometry.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
        geometry.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
        geometry.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(z_up_to_y_up(mesh.normals)))
        geometry.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        geometry.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geometry.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        geometry.CreateDoubleSidedAttr(False)
        lo, hi = points.min(axis=0), points.max(axis=0)
        geometry.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        primvars = UsdGeom.PrimvarsAPI(geometry)
        st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(mesh.uvs, np.float32)[faces.reshape(-1)]))
        for name, values in mesh.attributes.items():
            primvars.CreatePrimvar(name, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
                Vt.FloatArray.FromNumpy(np.asarray(values, np.float32).reshape(-1)))

        material = UsdShade.Material.Define(stage, MATERIAL)
        surface = UsdShade.Shader.Define(stage, MATERIAL + "/PreviewSurface")
        surface.CreateIdAttr("UsdPreviewSurface")
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
        surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
        reader = UsdShade.Shader.Define(stage, MATERIAL + "/StReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        texture = UsdShade.Shader.Define(stage, MATERIAL + "/Texture")
        texture.CreateIdAttr("UsdUVTexture")
        texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(TEXTURE_NAME)
        texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        texture.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
        texture.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
        texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        rgb = texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
        material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(geometry.GetPrim()).Bind(material)
        stage.GetRootLayer().Save()

        with staged([path]) as (temporary,):
            # The packager names the file by its suffix: the temporary name keeps .usdz at its end.
            package = temporary.with_name(temporary.name + ".usdz")
            try:
                if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer)), str(package)):
                    raise VortxError(f"USD could not package {path.name}")
                package.replace(temporary)
            finally:
                package.unlink(missing_ok=True)
    return path
