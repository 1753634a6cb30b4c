"""VoRTX engine: capture loading, poses, the VoRTX network, reconstruction, training.

Pure Python + torch + numpy + OpenCV + pycolmap. This package never imports bpy, so it runs
from the command line (`python -m engine ...`), in training and in CI exactly as inside Blender.
"""

__version__ = "0.1.0"
