"""Plane-sweep multi-view stereo: a depth and a confidence per keyframe pixel, no learning.

The depths are the domain-independent geometric evidence of the reconstruction
(../shared/design/stereo-evidence.md): fused into a TSDF they are the classical `stereo` method, and
they are the extra input of VoRTX with geometric evidence.

Import from the modules themselves (`engine.stereo.depth_maps`, `.options`, `.fused_tsdf`, ...): this
package loads nothing, so reading `stereo.options` (numpy only) for the settings never pays for, or
needs, the torch and OpenCV that depth_maps imports.
"""
