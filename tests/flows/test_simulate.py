from flows.simulate import simulate
from schemas.settings import Settings
from warehouse import audit
from warehouse.store import Warehouse

from tests.support import small_manifest


def test_simulate_records_episodes_and_skips_finished_ones(prefect_harness, data_root, tmp_path):
    manifest = small_manifest(tmp_path)
    assert simulate(str(manifest), 2)["new"] == 2
    assert simulate(str(manifest), 3)["new"] == 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, kinds = wh.query("SELECT kind, count(*) FROM artifacts GROUP BY kind ORDER BY kind")
        _, video = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'episode_video' LIMIT 1")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, chain = wh.query(sql, {"artifact": video[0][0]})
    assert dict(kinds) == {"episode": 3, "episode_video": 3, "manifest": 1}
    assert [r[1] for r in chain] == ["episode_video", "episode", "manifest"]
    assert len(list((data_root / "episodes").rglob("meta.json"))) == 3


def test_curating_episode_videos_extends_their_lineage(prefect_harness, data_root, tmp_path):
    from flows.curate import curate

    manifest = small_manifest(tmp_path)
    digest = simulate(str(manifest), 1)["manifest_hash"]
    curate([str(data_root / "episodes")], str(manifest))
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, clips = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'clip'")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, chain = wh.query(sql, {"artifact": clips[0][0]})
    kinds = [r[1] for r in chain]
    assert kinds[:2] == ["clip", "episode_video"] and "episode" in kinds and chain[-1][2] == digest


def test_an_episode_finished_before_another_fails_is_recorded(prefect_harness, data_root, tmp_path, monkeypatch):
    """Issue 26: lineage is written as each episode finishes, not in seed order at the end, so a
    run that fails (or is interrupted) keeps every episode it finished. Episode 0 fails only
    once episode 1 is on disk; before, episode 1 stayed on disk and out of lineage."""
    import time

    import pytest

    import flows.simulate
    from tasks.sim import episode

    manifest = small_manifest(tmp_path)
    real = episode.rollout

    def rollout(scenario, seed):
        if seed == scenario.seed:
            while not list(data_root.rglob("episode_000001/meta.json")):
                time.sleep(0.05)
            time.sleep(0.5)  # episode 1's task returns meanwhile
            raise RuntimeError("the simulator failed")
        return real(scenario, seed)

    monkeypatch.setattr(flows.simulate.episode, "rollout", rollout)
    with pytest.raises(RuntimeError, match="the simulator failed"):
        simulate(str(manifest), 2)
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, runs = wh.query("SELECT status, message FROM runs")
        _, recorded = wh.query("SELECT attrs->>'index' FROM stage_runs WHERE stage = 'simulate'")
    assert runs == [("failed", "RuntimeError: the simulator failed")]
    assert recorded == [("1",)]


def test_a_policy_drives_episodes_into_a_folder_of_their_own(prefect_harness, data_root, tmp_path):
    import json

    from tasks.world.inputs import episode_folders

    manifest = small_manifest(tmp_path)
    plain = simulate(str(manifest), 1)
    driven = simulate(str(manifest), 1, policy="scripted:0.9")
    folder = data_root / "episodes" / f"{plain['manifest_hash'][:12]}-{driven['folder'].rsplit('-', 1)[1]}"
    assert driven["new"] == 1 and driven["folder"] == str(folder) and (folder / "episode_000000/meta.json").is_file()
    meta = json.loads((folder / "episode_000000/meta.json").read_text())
    own = data_root / "episodes" / plain["manifest_hash"][:12]
    plain_meta = json.loads((own / "episode_000000/meta.json").read_text())
    assert meta["policy"] == {"kind": "scripted", "name": "scripted@0.9", "noise": 0.9} and "policy" not in plain_meta
    assert meta["seed"] == plain_meta["seed"]  # the same seed, another driver
    # the manifest's own episodes stay the scripted controller's; the policy's are found by folder
    assert episode_folders(str(manifest), data_root)[0] == [own / "episode_000000"]
    assert episode_folders(str(folder), data_root)[0] == [folder / "episode_000000"]
    assert simulate(str(manifest), 1, policy="scripted:0.9")["new"] == 0  # found done
    assert simulate(str(manifest), 1, policy="scripted:0.5")["new"] == 1  # another policy, another folder
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT attrs->'policy'->>'name' FROM artifacts WHERE kind = 'episode' ORDER BY 1")
    assert rows == [("scripted@0.5",), ("scripted@0.9",), (None,)]


def test_a_policy_checkpoint_whose_weights_changed_drives_no_episode(prefect_harness, data_root, tmp_path):
    """`simulate --policy bc:PATH` drove episodes with tampered weights and recorded them, edge and
    all, where `evaluate policies` refuses the same checkpoint (exit 5)."""
    import re
    from pathlib import Path

    import pytest

    from flows.policy import train_policy
    from schemas.errors import TamperedArtifact

    manifest = small_manifest(tmp_path)
    folder = Path(train_policy(str(manifest), episodes=1, steps=4, holdout=0)["folder"])
    weights = folder / "model.safetensors"
    data = bytearray(weights.read_bytes())
    data[int(len(data) * 0.9)] ^= 0xFF
    weights.write_bytes(bytes(data))
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        before = wh.counts()["artifacts"]
    with pytest.raises(TamperedArtifact, match=rf"^{re.escape(str(weights))}: sha256 \w+ differs from lineage's"):
        simulate(str(manifest), 1, policy=f"bc:{folder}")
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        assert wh.counts()["artifacts"] == before
    assert not list((data_root / "episodes").glob("*-*"))  # no policy folder of episodes


def test_an_episode_whose_files_were_deleted_is_simulated_again(prefect_harness, data_root, tmp_path):
    """Its stage was done in lineage, so simulate said "0 new episodes" and the loop's curate then
    quarantined the missing video, exit 0; the same seed makes the same bytes again."""
    import shutil

    manifest = small_manifest(tmp_path)
    first = simulate(str(manifest), 2)
    episode = data_root / "episodes" / first["manifest_hash"][:12] / "episode_000001"
    before = {p.name: p.read_bytes() for p in episode.iterdir() if p.suffix == ".mp4"}
    shutil.rmtree(episode)
    again = simulate(str(manifest), 2)
    assert again["new"] == 1 and {p.name: p.read_bytes() for p in episode.iterdir() if p.suffix == ".mp4"} == before
    assert simulate(str(manifest), 2)["new"] == 0
