"""Exports of `worldline simulate`'s episodes to the formats other tools read (docs/export.md).

``lerobot``: the LeRobot dataset layout, codebase version v3.0 (what ``lerobot`` 0.4 on PyPI
reads): ``sources`` finds and checks the episodes, ``frames`` resamples their 50 Hz steps to one
row per video frame, ``stats`` computes LeRobot's statistics, ``lerobot`` writes the folder.
"""
