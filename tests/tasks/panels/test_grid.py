"""Expanding a manifest over a stressor grid, reading grids, and refusing unlike panels."""

import pytest

from schemas.manifest import DimLight, ForkliftCrossing, manifest_hash
from schemas.panel import StressorCell, StressorGrid, panel_contract
from tasks.manifests import load
from tasks.panels.contract import PanelContractError, check_same_contract, contract_differences
from tasks.panels.grid import GridError, default_grid, expand, parse_grid

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "conveyor_push.yaml")


@pytest.mark.parametrize("path", sorted(MANIFESTS.glob("*.yaml")), ids=lambda p: p.stem)
def test_default_grid_of_every_shipped_manifest_expands(path):
    parent = load(path)
    spec, variants = expand(parent, default_grid(parent))
    assert [v.cell for v in spec.variants] == [c.name for c in spec.grid.cells]
    assert len(variants) == len(spec.variants) >= 6


def test_variants_differ_from_the_parent_only_in_stressors_and_seed():
    grid = StressorGrid(name="g", seed=500, episodes=3, cells=(
        StressorCell(name="nominal"),
        StressorCell(name="clean", drop=("appearance", "distractors")),
        StressorCell(name="dim", stressors=(DimLight(lux=20),)),
        StressorCell(name="more", stressors=(ForkliftCrossing(lane_m=1.2),), drop=("appearance",))))
    spec, variants = expand(PUSH, grid)
    parent = PUSH.model_dump(mode="json")
    for v in variants:
        body = v.model_dump(mode="json")
        changed = {k for k in body if body[k] != parent[k]}
        assert changed <= {"stressors", "seed", "name", "description", "parent"}
        assert v.parent == manifest_hash(PUSH) and v.seed == 500
    kinds = [[s.kind for s in v.stressors] for v in variants]
    assert kinds == [["appearance", "distractors"], [], ["appearance", "dim_light", "distractors"],
                     ["distractors", "forklift_crossing"]]
    assert variants[2].stressor("dim_light").lux == 20
    assert [v.name for v in variants] == ["conveyor-push--nominal", "conveyor-push--clean", "conveyor-push--dim",
                                          "conveyor-push--more"]
    assert all(pv.seeds == (500, 501, 502) for pv in spec.variants)
    assert spec.parent == manifest_hash(PUSH)
    assert [pv.manifest_hash for pv in spec.variants] == [manifest_hash(v) for v in variants]


def test_grid_seed_defaults_to_the_parents():
    spec, variants = expand(PUSH, StressorGrid(name="g", episodes=2, cells=(StressorCell(name="a"),)))
    assert spec.variants[0].seeds == (PUSH.seed, PUSH.seed + 1) and variants[0].seed == PUSH.seed


def test_grid_yaml_round_trip_and_errors():
    grid = parse_grid("name: g\ncells:\n  - name: dim\n    stressors: [{kind: dim_light, lux: 30}]\nepisodes: 4\n")
    assert grid.cells[0].stressors == (DimLight(lux=30),) and grid.episodes == 4
    with pytest.raises(GridError, match=r"<grid>: cells.0.name: [^;]*$"):  # only what is wrong, once
        parse_grid("name: g\ncells:\n  - name: Not Valid\n")
    with pytest.raises(GridError, match=r"<grid>: cells: Tuple should have at least 1 item"):
        parse_grid("name: g\ncells: []\n")
    with pytest.raises(GridError, match="alias"):
        parse_grid("name: g\ncells:\n  - &a {name: x}\n  - *a\n")
    with pytest.raises(GridError, match="blocked term"):  # the text pre-guard reads grids too
        parse_grid("name: g\ndescription: shoot the forklift driver\ncells:\n  - name: x\n")
    with pytest.raises(GridError, match="not valid YAML"):
        parse_grid("name: [g\n")


def test_panels_with_different_contracts_are_refused_naming_what_differs():
    short = PUSH.model_copy(update={"horizon_s": 2.5})
    small = PUSH.model_copy(update={"cameras": (PUSH.cameras[0].model_copy(update={"resolution": (64, 64)}),)})
    other_task = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    contracts = {"push": panel_contract(PUSH), "same": panel_contract(PUSH.model_copy(update={"seed": 3}))}
    assert check_same_contract(contracts)
    with pytest.raises(PanelContractError) as err:
        check_same_contract({"push": panel_contract(PUSH), "short": panel_contract(short)})
    assert str(err.value) == "cannot compare push with short: their contracts differ in horizon: 5.0 vs 2.5"
    with pytest.raises(PanelContractError, match=r"camera overhead .*128x128.* vs overhead .*64x64"):
        check_same_contract({"push": panel_contract(PUSH), "small": panel_contract(small)})
    diff = contract_differences(panel_contract(PUSH), panel_contract(other_task))
    text = "; ".join(diff)
    assert "camera layout: overhead vs front_left, front_right, wrist" in text
    assert "task: 'push' vs 'bin_pick'" in text and "evaluation target: 'push_to_goal' vs 'lift_clear'" in text
    assert "horizon: 5.0 vs 6.0" in text


def test_the_shipped_held_out_grid_is_the_default_grid_on_other_seeds():
    """manifests/grids/push_heldout.yaml: the default push grid, on seeds no `worldline simulate`
    run of a shipped push manifest starts from."""
    from tasks.panels.grid import load_grid

    grid = load_grid(MANIFESTS / "grids" / "push_heldout.yaml")
    closeup = load(MANIFESTS / "push_closeup.yaml")
    assert grid.cells == default_grid(closeup).cells and grid.episodes == 4
    spec, _ = expand(closeup, grid)
    assert spec.variants[0].seeds == (10200, 10201, 10202, 10203)
    assert all(load(p).seed + 2000 < 10200 for p in MANIFESTS.glob("*.yaml") if load(p).task.kind == "push")
