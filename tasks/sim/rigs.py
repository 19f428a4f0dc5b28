"""Rig videos (issue 33 point 4): several cameras' frames tiled into one picture, so a world model
trained on the rig's video generates every view together, and the generated picture cut back into
its views. ``layout`` is the manifest's (`schemas.manifest.Rig`): rows of camera names."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def tile(frames: Mapping[str, np.ndarray], layout: Sequence[Sequence[str]]) -> np.ndarray:
    """Per camera ``F x H x W x 3`` -> ``F x (rows H) x (cols W) x 3``; views with fewer frames
    than the others cut every view to the shortest."""
    missing = [n for row in layout for n in row if n not in frames]
    if missing:
        raise ValueError(f"no frames of camera(s) {', '.join(missing)} to tile")
    n = min(len(frames[name]) for row in layout for name in row)
    return np.concatenate([np.concatenate([frames[name][:n] for name in row], axis=2) for row in layout], axis=1)


def untile(picture: np.ndarray, layout: Sequence[Sequence[str]]) -> dict[str, np.ndarray]:
    """``... x (rows H) x (cols W) x C`` (a frame or a stack of frames) -> each camera's view."""
    rows, cols = len(layout), len(layout[0])
    height, width = picture.shape[-3], picture.shape[-2]
    if height % rows or width % cols:
        raise ValueError(f"a {width}x{height} picture does not split into {rows} x {cols} views")
    h, w = height // rows, width // cols
    return {name: picture[..., r * h:(r + 1) * h, c * w:(c + 1) * w, :]
            for r, row in enumerate(layout) for c, name in enumerate(row)}


def ring_pairs(layout: Sequence[Sequence[str]]) -> list[tuple[str, str]]:
    """Neighbouring views of the layout (left-right within a row, top-bottom within a column), in
    reading order: the pairs whose pictures should agree with the cameras' geometry."""
    pairs = []
    for r, row in enumerate(layout):
        for c, name in enumerate(row):
            if c + 1 < len(row):
                pairs.append((name, row[c + 1]))
            if r + 1 < len(layout):
                pairs.append((name, layout[r + 1][c]))
    return pairs
