"""Synthetic training and test rooms rendered with Blender, written in the ScanNet layout.

The only engine package allowed to import bpy, and only lazily inside the rendering functions
(render.py, blender_scene.py), so `engine.data.room` / `trajectory` / `geometry` work without Blender.
"""

from .geometry import MeshPart, merge_parts, room_parts
from .room import RoomSpec, generate_room
from .trajectory import scan_trajectory
from .synth import SynthOptions, room_name, room_poses, synthesize_room, synthesize_rooms
from .render import RenderSettings

__all__ = [
    "MeshPart", "RenderSettings", "RoomSpec", "SynthOptions", "generate_room", "merge_parts",
    "room_name", "room_parts", "room_poses", "scan_trajectory", "synthesize_room", "synthesize_rooms",
]
