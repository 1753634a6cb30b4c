"""The confidence layer's vertex attributes and the colour an artist sees them as (issue 11.6).

Computed from the stereo depth maps by engine/stereo/vertex_evidence.py; kept here, numpy only, so
Blender can draw the layer without importing torch (the extension registers before torch is installed).
Red: the surface was seen by few photos or only weak matches (take more photos there), or the network
completed it; green: well observed.
"""

from __future__ import annotations

import numpy as np

OBSERVATIONS = "observations"
STEREO_CONFIDENCE = "stereo_confidence"
COMPLETED = "completed"
EVIDENCE_ATTRIBUTES = (OBSERVATIONS, STEREO_CONFIDENCE, COMPLETED)
# 1 on the faces the finishing stage added where no photo saw surface (engine/finish: a wall behind a
# wardrobe, a stereo gap in a plain wall closed), 0 on seen surface: the artist can select and delete them.
ADDED = "added"

# The colour an artist sees: red where few views or weak matches saw the surface, green where it is
# well observed. A vertex seen by this many depth maps with this confidence counts as fully observed.
WELL_OBSERVED_VIEWS = 5
GOOD_CONFIDENCE = 0.8  # aggregated NCC of a clear match (the sweep keeps matches from 0.5)
LOW_COLOUR = np.array([0.85, 0.10, 0.08], np.float32)  # sRGB red
MID_COLOUR = np.array([0.95, 0.80, 0.10], np.float32)  # sRGB yellow
HIGH_COLOUR = np.array([0.10, 0.75, 0.20], np.float32)  # sRGB green


def observation_score(attributes: dict[str, np.ndarray]) -> np.ndarray:
    """(V,) float32 in [0, 1]: 0 unobserved (or completed), 1 seen by >= WELL_OBSERVED_VIEWS depth maps
    with confidence >= GOOD_CONFIDENCE; the product of the two shares, so both must be good."""
    views = np.clip(np.asarray(attributes[OBSERVATIONS], np.float32) / WELL_OBSERVED_VIEWS, 0.0, 1.0)
    match = np.clip(np.asarray(attributes[STEREO_CONFIDENCE], np.float32) / GOOD_CONFIDENCE, 0.0, 1.0)
    score = views * match
    completed = attributes.get(COMPLETED)
    if completed is not None:
        score = np.where(np.asarray(completed) > 0.5, 0.0, score)
    return score.astype(np.float32)


def observation_colours(attributes: dict[str, np.ndarray]) -> np.ndarray:
    """(V, 3) float32 sRGB in 0..1: red (score 0) -> yellow (0.5) -> green (1) of `observation_score`."""
    score = observation_score(attributes)[:, None]
    low_half = LOW_COLOUR + (MID_COLOUR - LOW_COLOUR) * np.clip(2 * score, 0, 1)
    high_half = MID_COLOUR + (HIGH_COLOUR - MID_COLOUR) * np.clip(2 * score - 1, 0, 1)
    return np.where(score < 0.5, low_half, high_half).astype(np.float32)
