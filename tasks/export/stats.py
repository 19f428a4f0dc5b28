"""LeRobot's statistics of a feature: ``min``, ``max``, ``mean``, ``std``, ``count`` and the
quantiles ``q01``, ``q10``, ``q50``, ``q90``, ``q99`` (lerobot/datasets/compute_stats.py).

A vector feature's statistics are per dimension over the rows (shape ``(D,)``; ``(1,)`` for a
scalar such as ``timestamp``). A video's are per RGB channel over sampled pixels scaled to
[0, 1], shape ``(3, 1, 1)`` as LeRobot normalises images; they come from 256-bin histograms of
the pixel values (tasks/export/sources.py samples them), so they are exact for those pixels and
add up across episodes. ``count`` is the number of rows (frames for a video), shape ``(1,)``.
"""

from __future__ import annotations

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


def _quantile_keys() -> list[str]:
    return [f"q{int(round(q * 100)):02d}" for q in QUANTILES]


def vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """Per-dimension statistics of ``N`` rows (``N`` or ``N x D``)."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    stats = {"min": values.min(axis=0), "max": values.max(axis=0), "mean": values.mean(axis=0),
             "std": values.std(axis=0), "count": np.array([len(values)])}
    for key, q in zip(_quantile_keys(), QUANTILES):
        stats[key] = np.quantile(values, q, axis=0)
    return stats


def image_stats(histogram: np.ndarray, frames: int) -> dict[str, np.ndarray]:
    """Per-channel statistics in [0, 1] from a 3 x 256 histogram of pixel values, shape (3, 1, 1)."""
    levels = np.arange(256, dtype=np.float64) / 255.0
    totals = histogram.sum(axis=1).astype(np.float64)
    mean = (histogram * levels).sum(axis=1) / totals
    var = (histogram * (levels[None, :] - mean[:, None]) ** 2).sum(axis=1) / totals
    present = histogram > 0
    stats = {"min": np.array([levels[row].min() for row in present]),
             "max": np.array([levels[row].max() for row in present]),
             "mean": mean, "std": np.sqrt(var)}
    cumulative = np.cumsum(histogram, axis=1)
    for key, q in zip(_quantile_keys(), QUANTILES):
        stats[key] = np.array([levels[np.searchsorted(cumulative[c], q * totals[c])] for c in range(3)])
    stats = {k: v.reshape(3, 1, 1) for k, v in stats.items()}
    stats["count"] = np.array([frames])
    return stats


def as_json(stats: dict[str, dict[str, np.ndarray]]) -> dict:
    """Feature -> statistic -> nested lists, as meta/stats.json holds them."""
    return {feature: {k: np.asarray(v).tolist() for k, v in values.items()} for feature, values in stats.items()}


def flattened(stats: dict[str, dict[str, np.ndarray]]) -> dict[str, list]:
    """``stats/<feature>/<statistic>`` -> nested lists: an episode's columns in meta/episodes."""
    return {f"stats/{feature}/{k}": np.asarray(v).tolist() for feature, values in stats.items()
            for k, v in values.items()}
