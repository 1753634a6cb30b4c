"""The Capture model and loaders for each on-disk layout.

`load_capture(path, **options)` detects the layout (photo folder, COLMAP, transforms.json, ScanNet,
video) and returns a `Capture`; `load_image(path)` decodes one photo as uint8 RGB (H, W, 3), `load_depth(path)` a 16-bit
millimetre depth map as float32 metres.
"""

from .detect import FORMATS, detect_format
from .images import load_depth, load_image
from .load import load_capture
from .model import Capture, Frame
from .options import LoadOptions

__all__ = ["Capture", "Frame", "FORMATS", "LoadOptions", "detect_format", "load_capture", "load_depth", "load_image"]
