"""Fixtures of the curation tests. ``make_video`` (tiny generated H.264 MP4s) is in
``tests/tasks/conftest.py``, shared with the video I/O tests."""

from __future__ import annotations

import numpy as np
import pytest


REAL_VIDEOS = ("bikes.mp4", "chaplin.mp4", "aloha_sim_transfer_cube.mp4", "smpte-2997.mp4", "carphone_pristine.mp4")


@pytest.fixture(scope="session")
def real_frames() -> dict[str, np.ndarray]:
    """Analysis frames (256 px, as the curate flow decodes them) of the real footage in
    ../shared/data/videos: file name -> T x h x w x 3 uint8 RGB, for checking fast paths
    against their slow references on pictures no generator made. Skips when absent."""
    from tasks.curate.decode import analysis_frames
    from tests.support import SHARED_DATA

    folder = SHARED_DATA / "videos"
    if not folder.is_dir():
        pytest.skip("../shared/data is absent")
    return {name: np.stack([f.image for f in analysis_frames(folder / name)])
            for name in REAL_VIDEOS if (folder / name).exists()}
