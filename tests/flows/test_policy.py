"""The train-policy flow: demonstrations -> a behaviour-cloning checkpoint -> held-out success,
all in lineage; a finished training is found done on a re-run."""

from pathlib import Path

import pytest
import torch

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
    # found done, but its weights changed since: it was handed back as it was (exit 0)
    import re

    from schemas.errors import TamperedArtifact

    weights = folder / "model.safetensors"
    data = bytearray(weights.read_bytes())
    data[int(len(data) * 0.9)] ^= 0xFF
    weights.write_bytes(bytes(data))
    with pytest.raises(TamperedArtifact, match=rf"^{re.escape(str(weights))}: sha256 \w+ differs from lineage's"):
        train_policy(str(manifest), episodes=2, steps=20, holdout=1)


def test_train_policy_with_cameras_records_a_vision_checkpoint_that_evaluate_refuses_elsewhere(
        prefect_harness, data_root, tmp_path):
    from flows.evaluate import plan
    from tasks.panels.contract import PanelContractError
    from tasks.policy.specs import load_policy
    from tasks.policy.vision import VisionPolicy

    manifest = tmp_path / "closeup.yaml"
    manifest.write_text((MANIFESTS / "push_closeup.yaml").read_text().replace("horizon_s: 6.0", "horizon_s: 3.0"))
    result = train_policy(str(manifest), episodes=2, steps=6, holdout=1, observe="side", image_size=32, dagger=1)
    policy = VisionPolicy.from_checkpoint(result["folder"])
    assert policy.spec.cameras == ("side",) and policy.meta["dagger_rounds"][0]["seeds"] == [1521, 1522, 1523, 1524]
    # The round is gated by default (HG-DAgger): the checkpoint says how, and how often the expert took over.
    assert policy.meta["dagger_gate"] == 1.0 and 0 <= policy.meta["dagger_rounds"][0]["interventions"] <= 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, (row,) = wh.query("SELECT attrs->>'model', attrs->>'observe' FROM artifacts WHERE artifact_id = $c",
                             {"c": result["checkpoint_id"]})
        _, gate = wh.query("SELECT attrs->>'dagger_gate' FROM artifacts WHERE artifact_id = $c",
                           {"c": result["checkpoint_id"]})
        _, steps = wh.query("SELECT max(step) FROM metrics WHERE subject_id = $c AND name = 'train_loss'",
                            {"c": result["checkpoint_id"]})
    assert row == ("vision-policy", '["side"]') and steps == [(12,)]  # 6 steps, then one DAgger round of 6
    assert gate == [("1.0",)]

    # The state policy of the same manifest is another checkpoint; a panel without its camera is refused.
    assert train_policy(str(manifest), episodes=2, steps=6, holdout=0)["checkpoint_id"] != result["checkpoint_id"]
    other = tmp_path / "overhead.yaml"
    other.write_text(manifest.read_text().replace("name: side", "name: top"))
    with pytest.raises(PanelContractError, match="contracts differ in camera layout: top vs side"):
        plan([str(other)], None, 1, [load_policy(f"vision:{result['folder']}")])

    # It drives recorded episodes (`simulate --policy`), in lineage under its checkpoint; a
    # manifest without its camera is refused in one line.
    from flows.params import ParamsError
    from flows.simulate import simulate

    driven = simulate(str(manifest), 1, policy=f"vision:{result['folder']}")
    assert driven["new"] == 1 and (Path(driven["folder"]) / "episode_000000" / "side.mp4").is_file()
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT a.kind, a.attrs->'policy'->>'kind' FROM edges e JOIN artifacts a "
                            "ON a.artifact_id = e.child_id WHERE e.parent_id = $c AND e.relation = 'policy'",
                            {"c": result["checkpoint_id"]})
    assert edges == [("episode", "vision")]
    with pytest.raises(ParamsError, match="observes camera\\(s\\) side, which"):
        simulate(str(other), 1, policy=f"vision:{result['folder']}")


def test_train_policy_sees_through_a_tokenizer_the_tokenize_flow_trained(prefect_harness, data_root, tmp_path):
    """`--encoder tokenizer:ID`: the vision policy's encoder is that tokenizer's (frozen), the
    checkpoint names it in lineage (``encoder_from``), and frames it cannot tile are refused."""
    from typer.testing import CliRunner

    from flows.cli import app
    from flows.curate import curate
    from flows.simulate import simulate
    from flows.tokenize import tokenize
    from tasks.policy.vision import VisionPolicy
    from tasks.tokenize.tokens import load_checkpoint

    manifest = _manifest(tmp_path)
    mh = simulate(str(manifest), 2)["manifest_hash"]
    config = tmp_path / "curate.yaml"
    config.write_text("overlay_text: {action: tag}\n")
    curate([str(data_root / "episodes")], str(manifest), str(config))
    tok = tokenize(mh, "tiny-dv4x8x8", steps=2, size=32, batch_size=2)
    short = tok["checkpoint_id"][:12]
    result = train_policy(str(manifest), episodes=2, steps=4, holdout=0, observe="overhead", image_size=32,
                          encoder=f"tokenizer:{short}", encoder_layer="hidden")
    policy = VisionPolicy.from_checkpoint(result["folder"])
    tokenizer = load_checkpoint(Path(tok["checkpoint"]))
    assert policy.model.config.tokenizer == tokenizer.config and policy.model.config.tokenizer_layer == "hidden"
    assert all(torch.equal(a, b) for a, b in zip(policy.model.encoders[0].encoder.state_dict().values(),
                                                 tokenizer.encoder.state_dict().values()))
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT parent_id, relation FROM edges WHERE child_id = $c ORDER BY relation",
                            {"c": result["checkpoint_id"]})
        _, (attrs,) = wh.query("SELECT attrs->>'encoder', attrs->>'tokenizer_id' FROM artifacts WHERE artifact_id = $c",
                               {"c": result["checkpoint_id"]})
    assert edges == [(tok["checkpoint_id"], "encoder_from"), (mh, "trained_on")]
    assert attrs == ("tokenizer", tok["checkpoint_id"])
    cnn = train_policy(str(manifest), episodes=2, steps=4, holdout=0, observe="overhead", image_size=32)
    assert cnn["checkpoint_id"] != result["checkpoint_id"]

    with pytest.raises(ValueError, match="compresses 8x spatially; image_size 36 is not a multiple of it"):
        train_policy(str(manifest), episodes=2, steps=4, holdout=0, observe="overhead", image_size=36,
                     encoder=f"tokenizer:{short}")  # as a deployment runs it
    refused = CliRunner().invoke(app, ["train-policy", str(manifest), "--observe", "overhead", "--image-size", "36",
                                       "--encoder", f"tokenizer:{short}"], terminal_width=400)
    assert refused.exit_code == 2, refused.output
    assert "compresses 8x spatially; --image-size 36 is not a multiple of it" in " ".join(refused.output.split())
