"""The loop bench's summary of the cells that failed: gains, the better control, the ceiling."""

import numpy as np

from bench.loop_targeting import failed_summary, repeat_summary


def test_failed_summary_names_the_better_control_and_its_ceiling():
    before = {"nominal": [True] * 4, "dim": [False] * 4, "appearance": [True, True, True, False]}
    after = {"targeted": {"nominal": [True] * 4, "dim": [True] * 4, "appearance": [True] * 4},
             "nominal": {"nominal": [True] * 4, "dim": [False] * 4, "appearance": [True, True, True, False]},
             "uniform": {"nominal": [True] * 4, "dim": [True, True, True, False], "appearance": [True, True, True, False]}}
    gains, pooled, ceiling = failed_summary(before, after, ["dim", "appearance"], np.random.default_rng(0))
    assert gains.startswith("cells that failed (before < 0.9): dim, appearance")
    # before pooled 3/8; targeted 8/8 (+0.62), nominal 3/8 (+0.00), uniform 6/8 (+0.38)
    assert "targeted +0.62, nominal +0.00, uniform +0.38" in gains
    assert gains.endswith("targeted minus the better control (uniform) +0.25")
    assert "targeted 1.00" in pooled and "uniform 0.75" in pooled
    # the uniform control is at 6/8 on the failed cells: no arm can lead it by more than 0.25
    assert ceiling.endswith("(1.00 on every failed cell): +0.25")


def test_repeat_summary_gives_the_failed_cells_and_the_lowest_other_cell():
    outcomes = {"nominal": [True] * 4, "dim": [True, False, False, False], "occluder": [True, True, False, False],
                "appearance": [True, True, True, False]}
    assert repeat_summary(outcomes, ["dim", "appearance"]) == \
        "; after: dim 0.25, appearance 0.75, lowest elsewhere occluder 0.50"
    assert repeat_summary(outcomes, []) == ""
