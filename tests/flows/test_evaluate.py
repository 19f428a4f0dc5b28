"""The evaluate flow: success per stressor cell and policy, lineage, contract refusal, and a
vision policy driven closed loop in a world model."""

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from flows.cli import app
from flows.evaluate import evaluate
from schemas.settings import Settings
from tasks.manifests import load
from tasks.panels.contract import PanelContractError
from tasks.policy.bc import TrainConfig, collect, save_checkpoint, train_bc
from warehouse import audit as audits
from warehouse.store import Warehouse

from tests.support import MANIFESTS

GRID = """
name: duo
cells:
  - name: nominal
  - name: dim
    stressors: [{kind: dim_light, lux: 60}]
episodes: 1
"""


def _manifest(tmp_path: Path, name: str, horizon: str = "3.0") -> Path:
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    path = tmp_path / f"{name}.yaml"
    path.write_text(text.replace("horizon_s: 5.0", f"horizon_s: {horizon}").replace("[128, 128]", "[64, 64]"))
    return path


def _bc(tmp_path: Path, manifest: Path) -> Path:
    """A barely trained policy: the flow's mechanics, not its skill, are under test here."""
    scenario = load(manifest)
    model, _ = train_bc(collect(scenario, [5]), TrainConfig(steps=20))
    folder = tmp_path / f"bc-{manifest.stem}"
    save_checkpoint(model, folder, scenario, TrainConfig(steps=20))
    return folder


def test_policies_on_a_panel_table_and_lineage(prefect_harness, data_root, tmp_path):
    manifest, grid = _manifest(tmp_path, "push"), tmp_path / "grid.yaml"
    grid.write_text(GRID)
    bc = _bc(tmp_path, manifest)
    result = evaluate(str(manifest), str(grid), policies=["scripted", "scripted:0.8", f"bc:{bc}"])

    tables = {e["policy"]: {r["cell"]: r for r in e["table"]} for e in result["evaluations"]}
    assert len(tables) == 3 and {"scripted", "scripted@0.8"} < set(tables) and any(p.startswith("bc:") for p in tables)
    scripted = tables["scripted"]
    assert [scripted[c]["episodes"] for c in ("nominal", "dim", "all")] == [1, 1, 2]
    assert scripted["all"]["sim"] == 1.0  # the scripted controller at the manifest's noise pushes it home
    assert all(r["world"] is None for t in tables.values() for r in t.values())  # no world model given
    assert scripted["nominal"]["detector"] is not None  # the frame detector judged the render
    assert set(result["spearman"]) == {"sim_vs_world", "sim_vs_detector", "sim_vs_world_cells", "sim_vs_detector_cells"}
    assert result["spearman"]["sim_vs_world"] is None
    detector, world = result["agreement"]["detector"], result["agreement"]["world"]
    assert detector["episodes"] == world["episodes"] == 6 and world["decided"] == 0
    assert 0 < detector["decided"] <= 6 and detector["agree"] <= detector["decided"]

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, evals = wh.query("SELECT artifact_id, attrs->>'role' FROM artifacts WHERE kind = 'evaluation'")
        _, edges = wh.query("SELECT relation, count(*) FROM edges e JOIN artifacts a ON a.artifact_id = e.child_id "
                            "WHERE a.kind = 'evaluation' GROUP BY relation ORDER BY relation")
        _, metrics = wh.query("SELECT name, value FROM metrics WHERE subject_id = $e ORDER BY name",
                              {"e": next(e["evaluation_id"] for e in result["evaluations"] if e["policy"] == "scripted")})
        _, compared = wh.query("SELECT name FROM metrics WHERE subject_id = $c", {"c": result["comparison_id"]})
        _, ancestry = wh.query("SELECT DISTINCT ancestor_kind FROM ancestry WHERE descendant_id = $c",
                               {"c": result["comparison_id"]})
        counts = wh.counts()
    assert sorted(role or "policy" for _, role in evals) == ["comparison", "policy", "policy", "policy"]
    assert dict(edges) == {"compared": 3, "evaluated_on": 3, "policy": 1}
    assert dict(metrics)["sim_success_rate"] == 1.0 and dict(metrics)["sim_success_rate/dim"] == 1.0
    assert {"evaluation", "panel", "checkpoint", "episode", "manifest"} <= {k for (k,) in ancestry}
    assert {"agreement_detector_decided", "agreement_detector_rate"} <= {n for (n,) in compared}
    assert not any(n.startswith("agreement_world") for (n,) in compared)

    # The shipped failure audit: the failed cells (below the manifest's pass bar), then what lies behind.
    bar = load(manifest).evaluation.min_success_rate
    for evaluation in result["evaluations"]:
        with Warehouse(Settings().warehouse_path, read_only=True) as wh:
            _, rows = wh.query(*audits.bind("failure", {"artifact": evaluation["evaluation_id"]}))
        failed = sorted(r["cell"] for r in evaluation["table"] if r["cell"] != "all" and r["sim"] < bar)
        assert sorted(row[2] for row in rows if row[1] == "failed_cell") == failed
        kinds = [row[1] for row in rows if row[1] != "failed_cell"]
        assert {"panel", "episode", "manifest"} <= set(kinds)
        assert ("checkpoint" in kinds) == evaluation["policy"].startswith("bc:")
        assert kinds.index("panel") < kinds.index("episode") < kinds.index("manifest")

    again = evaluate(str(manifest), str(grid), policies=["scripted", "scripted:0.8", f"bc:{bc}"])
    assert again["comparison_id"] == result["comparison_id"]
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert {k: v for k, v in wh.counts().items() if k != "runs"} == {k: v for k, v in counts.items() if k != "runs"}
        _, ((checkpoint_id,),) = wh.query("SELECT parent_id FROM edges WHERE relation = 'policy'")

    # The command line takes the policy by its checkpoint id too: the same evaluation, nothing new.
    by_id = CliRunner().invoke(app, ["evaluate", "policies", str(manifest), "--grid", str(grid), "--policy", "scripted",
                                     "--policy", "scripted:0.8", "--policy", f"bc:{checkpoint_id[:12]}"])
    assert by_id.exit_code == 0, by_id.output
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert {k: v for k, v in wh.counts().items() if k != "runs"} == {k: v for k, v in counts.items() if k != "runs"}


def test_unlike_contracts_are_refused_before_any_work(prefect_harness, data_root, tmp_path):
    manifest, short = _manifest(tmp_path, "push"), _manifest(tmp_path, "short", "2.5")
    with pytest.raises(PanelContractError, match=r"contracts differ in horizon: 3.0 vs 2.5"):
        evaluate(str(manifest), compare=[str(short)], policies=["scripted"])
    with pytest.raises(PanelContractError, match=r"policy bc:.* differ in horizon: 3.0 vs 2.5"):
        evaluate(str(manifest), policies=[f"bc:{_bc(tmp_path, short)}"])
    assert not (data_root / "lineage.duckdb").exists()

    result = CliRunner().invoke(app, ["evaluate", "policies", str(manifest), "--compare", str(short),
                                      "--policy", "scripted"])
    assert result.exit_code == 2 and "horizon: 3.0 vs 2.5" in result.output
    result = CliRunner().invoke(app, ["evaluate", "policies", str(manifest), "--policy", "bc:/nowhere"])
    assert result.exit_code == 2 and "not a behaviour-cloning checkpoint" in result.output


def vision_checkpoint(tmp_path: Path, manifest: Path, camera: str = "overhead") -> Path:
    """An untrained tiny vision policy on one of the manifest's cameras, saved as train-policy saves it."""
    import torch

    from models.vision_policy import VisionPolicyNet, preset
    from tasks.policy.vision_obs import ObservationSpec, proprio_size
    from tasks.policy.vision_train import save_checkpoint as save_vision
    from tasks.sim.control import ArmController
    from tasks.sim.scene import build_scene

    scenario = load(manifest)
    torch.manual_seed(0)
    arm = ArmController(build_scene(scenario, 0), 0)
    folder = tmp_path / f"vision-{camera}"
    save_vision(VisionPolicyNet(preset("tiny", 1, 32, proprio_size(arm))),
                ObservationSpec(cameras=(camera,), image_size=32), folder, scenario, TrainConfig(steps=1))
    return folder


def push_verdict(reason: str) -> bool | None:
    """The verdict that a reason of the push detector (tasks.panels.detect.judge_push) comes with."""
    if re.match(r"undecided: |goal marker not (found in|drawn in) |camera \S+ is not world-mounted", reason):
        return None
    if re.match(r"goal marker covered at the end ", reason):
        return True
    if re.match(r"goal marker (uncovered|partly covered) at the end ", reason):
        return False
    raise AssertionError(f"not a reason the push detector gives: {reason!r}")


def test_a_vision_policy_driven_closed_loop_in_the_world_model(prefect_harness, data_root, tmp_path):
    from tests.flows.test_panels import random_world_model

    manifest, grid = _manifest(tmp_path, "push", "1.0"), tmp_path / "grid.yaml"
    grid.write_text("name: one\ncells: [{name: nominal}]\nepisodes: 1\n")
    policy, wm = f"vision:{vision_checkpoint(tmp_path, manifest)}", str(random_world_model(tmp_path))
    replayed = evaluate(str(manifest), str(grid), policies=[policy], world_model=wm)
    result = evaluate(str(manifest), str(grid), policies=[policy], world_model=wm, in_world_model=True)

    (plain,), (closed,) = replayed["evaluations"], result["evaluations"]
    assert plain["evaluation_id"] != closed["evaluation_id"]  # the closed loop is another evaluation
    assert not any("closed" in r for r in plain["table"]) and "sim_vs_closed" not in replayed["spearman"]
    assert [r["cell"] for r in closed["table"]] == ["nominal", "all"] and all("closed" in r for r in closed["table"])
    body = json.loads((data_root / "evaluations" / closed["evaluation_id"] / "result.json").read_text())
    (episode,) = body["episodes"]
    assert body["closed_loop"] is True
    # The push detector judged both rollouts' frames, and each verdict is the one its reason gives.
    assert episode["closed"] is push_verdict(episode["closed_reason"])
    assert episode["world"] is push_verdict(episode["world_reason"])
    assert {"sim_vs_closed", "sim_vs_closed_cells"} <= set(result["spearman"])
    assert result["agreement"]["closed"]["episodes"] == 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        counts = wh.counts()

    # The command line shows the closed loop beside the replay, and reads the finished evaluation back.
    said = CliRunner().invoke(app, ["evaluate", "policies", str(manifest), "--grid", str(grid), "--policy", policy,
                                    "--world-model", wm, "--in-world-model", "--format", "csv"])
    assert said.exit_code == 0, said.output
    assert "world model closed loop" in said.output and "world model closed loop vs simulator" in said.output
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert {k: v for k, v in wh.counts().items() if k != "runs"} == {k: v for k, v in counts.items() if k != "runs"}
