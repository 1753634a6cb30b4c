"""The preview page beside a GLB: `room.html`, Google's <model-viewer> showing `room.glb` (orbit with the
mouse or a finger, an AR button on phones and headsets that offer AR), with nothing fetched from the
network when it is viewed.

The page inlines model-viewer (npm @google/model-viewer, which bundles three.js) and loads the GLB next
to it by its relative name. A GLB with Draco geometry or KTX2 textures needs three.js's decoders:
they are copied once into `vortx-viewer/` beside it (draco/, basis/) and the page points model-viewer
there instead of its default CDN. A room.usdz beside it becomes the AR model of iOS Quick Look.

Browsers load a page's model only over http(s) (a page opened from file:// may not read other files):
serve the folder (`python3 -m http.server` in it, then http://localhost:8000/room.html, or from a
headset's browser at the computer's address). Opened from file://, the page says so.
"""

from __future__ import annotations

import html
import json
import shutil
from pathlib import Path

from .encoders import model_viewer_files
from .file_parts import staged, unpack_glb

VIEWER_FOLDER = "vortx-viewer"
DECODER_FILES = {"draco": ("draco_wasm_wrapper.js", "draco_decoder.wasm", "draco_decoder.js"),
                 "basis": ("basis_transcoder.js", "basis_transcoder.wasm")}
LOADED_ATTRIBUTE = "data-model"  # "loaded" or "error" on <body> once model-viewer has tried (the tests read it)


def preview_path(glb: Path) -> Path:
    return Path(glb).with_suffix(".html")


def write_preview(glb: Path, title: str = "") -> list[Path]:
    """Write `<glb stem>.html` (and `vortx-viewer/` when the GLB needs decoders). -> the files written."""
    glb = Path(glb)
    needed_by = f"the preview page of {glb.name}"
    files = model_viewer_files(needed_by)
    document, _ = unpack_glb(glb.read_bytes())
    used = set(document.get("extensionsUsed", []))
    decoders = [name for name, extension in (("draco", "KHR_draco_mesh_compression"), ("basis", "KHR_texture_basisu"))
                if extension in used]
    written = []
    for name in decoders:
        folder = glb.parent / VIEWER_FOLDER / name
        folder.mkdir(parents=True, exist_ok=True)
        for file in DECODER_FILES[name]:
            target = folder / file
            if not target.is_file() or target.stat().st_size != (files[name] / file).stat().st_size:
                with staged([target]) as (temporary,):
                    shutil.copyfile(files[name] / file, temporary)
            written.append(target)
    page = preview_path(glb)
    usdz = glb.with_suffix(".usdz")
    script = files["model-viewer"].read_text(encoding="utf-8").replace("</script", "<\\/script")
    with staged([page]) as (temporary,):
        temporary.write_text(page_html(glb.name, title or glb.stem, script, usdz.name if usdz.is_file() else None),
                             encoding="utf-8")
    return [page, *written]


def page_html(glb_name: str, title: str, model_viewer_js: str, usdz_name: str | None = None) -> str:
    config = {"dracoDecoderLocation": f"{VIEWER_FOLDER}/draco/", "ktx2TranscoderLocation": f"{VIEWER_FOLDER}/basis/"}
    ios = f' ios-src="{html.escape(usdz_name)}"' if usdz_name else ""
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)} - VoRTX preview</title>
<style>
  html, body {{ margin: 0; height: 100%; background: #20242a; color: #e8e8e8; font: 14px sans-serif; }}
  model-viewer {{ width: 100%; height: 100%; --poster-color: transparent; }}
  #note {{ position: absolute; left: 12px; bottom: 12px; right: 12px; opacity: 0.85; }}
</style>
<script>
{model_viewer_js}
</script>
<script>
  // The decoders beside the page, not model-viewer's default CDN: nothing is fetched from the network.
  // model-viewer reads them from self.ModelViewerElement (the UMD build's exports) when an element is made.
  for (const [key, value] of Object.entries({json.dumps(config)}))
    self.ModelViewerElement[key] = new URL(value, location.href).href;
</script>
</head>
<body>
<model-viewer id="room" src="{html.escape(glb_name)}"{ios} alt="{html.escape(title)}: the textured room"
  camera-controls camera-orbit="-30deg 50deg 75%" touch-action="pan-y" ar ar-modes="webxr scene-viewer quick-look" shadow-intensity="0"
  tone-mapping="neutral" interaction-prompt="none"></model-viewer>
<div id="note">{html.escape(glb_name)}: drag to orbit, scroll or pinch to zoom; the AR button shows on devices that offer AR.</div>
<script>
  const viewer = document.getElementById("room"), note = document.getElementById("note");
  viewer.addEventListener("load", () => document.body.setAttribute("{LOADED_ATTRIBUTE}", "loaded"));
  viewer.addEventListener("error", () => {{
    document.body.setAttribute("{LOADED_ATTRIBUTE}", "error");
    note.textContent = location.protocol === "file:"
      ? "A browser does not load the model into a page opened from a file. In this folder run: python3 -m http.server, then open http://localhost:8000/" + location.pathname.split("/").pop()
      : "The model {html.escape(glb_name)} could not be loaded.";
  }});
</script>
</body>
</html>
"""
