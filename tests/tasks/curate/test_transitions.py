"""Fades and dissolves on per-frame statistics given directly (the splitter's own tests are in test_scenes*.py)."""

from __future__ import annotations

import numpy as np

from tasks.curate.scene_config import SceneConfig
from tasks.curate.transitions import find_transitions


def test_find_transitions_ignores_a_dark_shot_between_hard_cuts():
    luma = np.concatenate([np.full(50, 120.0), np.full(20, 5.0), np.full(50, 110.0)])
    fade = np.concatenate([np.full(50, 120.0), np.linspace(110, 0, 10), np.linspace(10, 110, 10), np.full(50, 110.0)])
    thumbs = np.zeros((120, 4, 4), np.float32)
    sharp = np.ones(120)
    assert find_transitions(luma, sharp, thumbs, 50, SceneConfig(), ended=True) == []
    # Frames 50..68 are below the shots' level; 69 is back at 110.
    assert find_transitions(fade, sharp, thumbs, 50, SceneConfig(), ended=True) == [(50, 69, "fade")]
