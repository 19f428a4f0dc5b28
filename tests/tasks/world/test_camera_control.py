"""The camera-control check and its paired interval (tasks/world/camera_control.py)."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.world.camera_control import check_beats_copy_last, motion_table, paired_difference, report_body


def _rows(model_offset: float, episodes: int = 6, windows: int = 4, noise: float = 0.5, seed: int = 1) -> list[dict]:
    """Per window at horizons 4 and 8: floor reads the true rotation, the model that plus an
    offset and noise."""
    rng = np.random.default_rng(seed)
    rows = []
    for e in range(episodes):
        for w in range(windows):
            for h in (4, 8):
                true = h * 1.0
                key = f"seed{e}@{8 * w}"
                rows.append({"window": key, "horizon": h, "source": "floor", "rotation_deg": true, "direction_deg": 90.0,
                             "true_rotation_deg": true, "estimated": True})
                for source, offset in (("model", model_offset), ("shuffled", 0.0)):
                    rows.append({"window": key, "horizon": h, "source": source,
                                 "rotation_deg": true + offset + noise * rng.standard_normal(), "direction_deg": 45.0,
                                 "true_rotation_deg": true, "estimated": True})
    return rows


def test_a_model_clearly_better_than_copy_last_has_an_interval_below_zero():
    rows = _rows(-1.0)
    d = paired_difference(rows, 4, "model", "floor")
    assert d["episodes"] == 6 and d["windows"] == 24
    assert d["high"] < 0 and d["low"] <= d["mean"] <= d["high"]
    assert d["mean"] == pytest.approx(np.mean([r["rotation_deg"] for r in rows
                                               if r["source"] == "model" and r["horizon"] == 4]) - 4.0)
    check = check_beats_copy_last(motion_table(rows), rows=rows)
    assert check["passed"] and set(check["model_minus_floor_deg"]) == {"4", "8"}
    body = report_body(motion_table(rows), check, {"windows": 24, "episodes": 6, "seeds": "0..5", "camera": "front",
                                                   "rollout_s_per_frame": 0.01})
    assert "model minus copy-last" in body and "model minus shuffled actions" in body


def test_no_difference_gives_an_interval_across_zero_and_a_missing_source_none():
    rows = _rows(0.0, noise=1.0)
    d = paired_difference(rows, 8, "model", "floor")
    assert d["low"] < 0 < d["high"]
    assert paired_difference(rows, 8, "model", "ceiling") is None
    assert paired_difference(rows, 16, "model", "floor") is None
    # Without the rows the check stays what it was: means only, no interval.
    assert "model_minus_floor_deg" not in check_beats_copy_last(motion_table(rows))
