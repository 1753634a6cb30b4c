"""The assumed height of the camera above the floor, the one place it is written.

A capture without metric poses has no scale; the poses stage finds the floor in the sparse points
and scales the world so the median camera sits this high above it. A hand-held phone or camera is
held at roughly chest to eye height, about 1.5 m. Every entry point (CLI flags, the batch script,
the Blender property) takes its default from here.
"""

DEFAULT_CAMERA_HEIGHT_M = 1.5
