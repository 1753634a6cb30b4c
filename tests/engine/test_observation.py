"""The confidence layer's colour scale: red where the photos barely saw the surface, green where they did."""

from __future__ import annotations

import numpy as np

from engine.observation import COMPLETED, OBSERVATIONS, STEREO_CONFIDENCE, observation_colours, observation_score


def test_colours_run_from_red_for_unseen_to_green_for_well_observed() -> None:
    attributes = {
        OBSERVATIONS: np.float32([0, 1, 5, 8, 8]),
        STEREO_CONFIDENCE: np.float32([0, 0.9, 0.9, 0.4, 0.95]),
        COMPLETED: np.float32([1, 0, 0, 0, 0]),
    }
    score = observation_score(attributes)
    assert score[0] == 0 and score[2] == 1 and score[4] == 1
    assert 0 < score[1] < score[3] < 1  # one view is worse than many views with weak matches
    colours = observation_colours(attributes)
    red, green = colours[0], colours[4]
    assert red[0] > 0.7 and red[1] < 0.2  # red
    assert green[1] > 0.7 and green[0] < 0.2  # green
    assert colours.min() >= 0 and colours.max() <= 1
