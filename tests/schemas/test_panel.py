"""The panel contract: what panels must share to be compared, hashed once."""

import pytest
from pydantic import ValidationError

from schemas.manifest import DimLight, Distractors
from schemas.panel import StressorCell, StressorGrid, contract_hash, grid_hash, panel_contract, panel_hash
from tasks.manifests import load
from tasks.panels.grid import default_grid, expand

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "conveyor_push.yaml")


def _with(manifest, **update):
    return manifest.model_copy(update=update)


def test_contract_ignores_what_a_panel_varies():
    task = PUSH.task.model_copy(update={"controller_noise": 0.7})
    evaluation = PUSH.evaluation.model_copy(update={"min_success_rate": 0.1})
    same = [_with(PUSH, stressors=()), _with(PUSH, stressors=(DimLight(lux=5),)), _with(PUSH, seed=999),
            _with(PUSH, task=task), _with(PUSH, evaluation=evaluation), _with(PUSH, description="other words"),
            _with(PUSH, name="another-name")]
    assert {contract_hash(m) for m in same} == {contract_hash(PUSH)}


@pytest.mark.parametrize("change", [
    lambda m: _with(m, horizon_s=4.0),
    lambda m: _with(m, cameras=(m.cameras[0].model_copy(update={"resolution": (64, 64)}),)),
    lambda m: _with(m, cameras=(m.cameras[0].model_copy(update={"position": (0.5, 0.0, 1.4)}),)),
    lambda m: _with(m, task=m.task.model_copy(update={"instruction": "push it elsewhere"})),
    lambda m: _with(m, evaluation=m.evaluation.model_copy(update={"goal_tolerance_m": 0.02})),
    lambda m: _with(m, embodiment=m.embodiment.model_copy(update={"action_space": "velocity"})),
], ids=["horizon", "resolution", "camera_pose", "task", "tolerance", "action_space"])
def test_contract_changes_with_layout_horizon_task_and_target(change):
    assert contract_hash(change(PUSH)) != contract_hash(PUSH)


def test_contract_hash_is_the_hash_of_the_contract_model():
    assert contract_hash(PUSH) == contract_hash(panel_contract(PUSH))
    assert len(contract_hash(PUSH)) == 64


def test_panel_hash_follows_meaning_not_description_or_listing_order():
    a = StressorGrid(name="g", cells=(StressorCell(name="x", stressors=(DimLight(lux=5), Distractors(count=2))),))
    b = StressorGrid(name="g", description="words", cells=(StressorCell(name="x", stressors=(Distractors(count=2),
                                                                                            DimLight(lux=5))),))
    assert grid_hash(a) == grid_hash(b)
    assert panel_hash(expand(PUSH, a)[0]) == panel_hash(expand(PUSH, b)[0])
    more = b.model_copy(update={"episodes": 3})
    assert panel_hash(expand(PUSH, more)[0]) != panel_hash(expand(PUSH, b)[0])


def test_every_variant_of_a_panel_shares_its_contract():
    spec, variants = expand(PUSH, default_grid(PUSH))
    assert {contract_hash(v) for v in variants} == {spec.contract_hash} == {contract_hash(PUSH)}


@pytest.mark.parametrize("bad", [
    {"name": "x", "stressors": [{"kind": "dim_light"}], "drop": ["dim_light"]},
    {"name": "x", "stressors": [{"kind": "dim_light"}, {"kind": "dim_light", "lux": 3}]},
    {"name": "Bad Name"},
    {"name": "x", "drop": ["gravity"]},
])
def test_bad_cells_are_refused(bad):
    with pytest.raises(ValidationError):
        StressorCell.model_validate(bad)


def test_cell_names_must_be_unique():
    with pytest.raises(ValidationError, match="cell names repeat"):
        StressorGrid(name="g", cells=(StressorCell(name="a"), StressorCell(name="a")))
