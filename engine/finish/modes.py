"""The finishing stage's modes (the `finish` setting): plain names, no imports, so the settings and
Blender read them without loading the finishing code (scipy)."""

FINISH_OFF, FINISH_CLEAN, FINISH_ROOM = "off", "clean", "room"
FINISH_MODES = (FINISH_OFF, FINISH_CLEAN, FINISH_ROOM)
