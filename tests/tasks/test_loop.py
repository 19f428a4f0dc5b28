"""The loop's pure helpers: worst cells, episode weights, derived manifests."""

import numpy as np
import pytest

from schemas.manifest import manifest_hash
from schemas.panel import contract_hash
from tasks.loop import SEED_OFFSET, before_after, derive_manifests, episode_counts, merge, worst_cells
from tasks.manifests import load
from tasks.panels.grid import default_grid, expand
from tasks.policy.bc import Demonstrations

from tests.support import MANIFESTS

TABLE = [{"cell": "nominal", "sim": 0.5}, {"cell": "dim", "sim": 0.0}, {"cell": "forklift", "sim": 0.5},
         {"cell": "jitter", "sim": 0.0}, {"cell": "odd", "sim": None}, {"cell": "all", "sim": 0.0}]


def test_worst_cells_lowest_first_ties_in_grid_order():
    assert worst_cells(TABLE, 1) == [("dim", 0.0)]
    assert worst_cells(TABLE, 2) == [("dim", 0.0), ("jitter", 0.0)]
    assert worst_cells(TABLE, 3) == [("dim", 0.0), ("jitter", 0.0), ("nominal", 0.5)]
    assert worst_cells(TABLE, 0) == []


@pytest.mark.parametrize("success,total,expected", [
    ([0.0, 0.5], 3, [2, 1]),        # failure 1.0 vs 0.5
    ([0.0, 0.0], 4, [2, 2]),
    ([1.0, 0.0], 5, [1, 4]),        # a cell that never fails still gets one
    ([0.0, 0.5], 1, [1, 1]),        # at least one each
    ([1.0, 1.0], 4, [2, 2]),        # nothing fails: equal shares
    ([0.25, 0.5, 0.75], 9, [4, 3, 2]),
    ([], 4, []),
])
def test_episode_counts_follow_failure_rate(success, total, expected):
    counts = episode_counts(success, total)
    assert counts == expected
    assert sum(counts) == max(total, len(success)) if success else counts == []


def test_derived_manifests_differ_only_in_stressors_and_keep_the_contract():
    parent = load(MANIFESTS / "conveyor_push.yaml")
    grid = default_grid(parent)
    spec, variants = expand(parent, grid)
    derived = derive_manifests(parent, grid, ["dim", "jitter"])
    assert [d.name.rsplit("--", 1)[1] for d in derived] == ["dim", "jitter"]
    panel_hashes = {manifest_hash(v) for v in variants}
    for d in derived:
        assert d.parent == manifest_hash(parent) and d.seed == parent.seed + SEED_OFFSET
        assert manifest_hash(d) != manifest_hash(parent) and manifest_hash(d) not in panel_hashes
        assert contract_hash(d) == contract_hash(parent) == spec.contract_hash
        bookkeeping = {"name", "description", "seed", "parent", "stressors", "meta"}
        assert d.model_dump(exclude=bookkeeping) == parent.model_dump(exclude=bookkeeping)
    kinds = {d.name.rsplit("--", 1)[1]: {s.kind for s in d.stressors} for d in derived}
    assert "dim_light" in kinds["dim"] and "camera_jitter" in kinds["jitter"]
    # the nominal cell keeps the parent's stressors: only the seeds (so the hash) differ
    (nominal,) = derive_manifests(parent, grid, ["nominal"])
    assert nominal.stressors == parent.stressors and manifest_hash(nominal) != manifest_hash(parent)


def test_merge_renumbers_episodes():
    a = Demonstrations(np.zeros((2, 3), np.float32), np.zeros((2, 5), np.float32), np.array([0, 0]), (7,), (True,))
    b = Demonstrations(np.ones((3, 3), np.float32), np.ones((3, 5), np.float32), np.array([0, 1, 1]), (8, 9), (True, True))
    m = merge([a, b])
    assert m.obs.shape == (5, 3) and list(m.episode) == [0, 0, 1, 2, 2] and m.seeds == (7, 8, 9)



def test_before_after_covers_every_cell_in_order():
    before = [{"cell": "a", "episodes": 1, "sim": 0.0}, {"cell": "b", "episodes": 1, "sim": 1.0},
              {"cell": "all", "episodes": 2, "sim": 0.5}]
    after = [{"cell": "a", "episodes": 1, "sim": 1.0}, {"cell": "b", "episodes": 1, "sim": 1.0},
             {"cell": "all", "episodes": 2, "sim": 1.0}]
    rows = before_after(before, after, ["a"])
    assert [(r["cell"], r["before"], r["after"], r["targeted"]) for r in rows] == [
        ("a", 0.0, 1.0, True), ("b", 1.0, 1.0, False), ("all", 0.5, 1.0, False)]
