"""The train-policy flow: demonstrations -> a behaviour-cloning checkpoint -> held-out success,
all in lineage; a finished training is found done on a re-run."""

from pathlib import Path

from flows.policy import train_policy
from schemas.settings import Settings
from tasks.policy.bc import BCPolicy
from warehouse.store import Warehouse

from tests.support import MANIFESTS


def _manifest(tmp_path: Path) -> Path:
    path = tmp_path / "push.yaml"
    path.write_text((MANIFESTS / "conveyor_push.yaml").read_text().replace("horizon_s: 5.0", "horizon_s: 3.0")
                    .replace("[128, 128]", "[64, 64]"))
    return path


def test_train_policy_records_checkpoint_loss_and_held_out_success(prefect_harness, data_root, tmp_path):
    manifest = _manifest(tmp_path)
    result = train_policy(str(manifest), episodes=2, steps=20, holdout=1)
    folder = Path(result["folder"])
    assert BCPolicy.from_checkpoint(folder).meta["checkpoint_id"] == result["checkpoint_id"]
    assert len(result["history"]) >= 1 and result["held_out_success_rate"] in (0.0, 1.0)

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, (row,) = wh.query("SELECT uri, attrs->>'model', attrs->>'config' FROM artifacts WHERE artifact_id = $c",
                             {"c": result["checkpoint_id"]})
        _, metrics = wh.query("SELECT DISTINCT name FROM metrics WHERE subject_id = $c ORDER BY 1",
                              {"c": result["checkpoint_id"]})
        _, edges = wh.query("SELECT relation FROM edges WHERE child_id = $c", {"c": result["checkpoint_id"]})
    uri, model, config = row
    assert model == "bc-policy" and (data_root / uri).is_file() and (data_root / config).is_file()
    assert [m for (m,) in metrics] == ["held_out_success_rate", "train_loss"] and edges == [("trained_on",)]

    again = train_policy(str(manifest), episodes=2, steps=20, holdout=1)
    assert again["checkpoint_id"] == result["checkpoint_id"] and again["history"] == []  # found done
