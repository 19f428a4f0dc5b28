"""Checkpoints named by id or folder are checked against lineage before anything loads them (issue 26)."""

import hashlib

import pytest

from tasks.lookup import checkpoint_folder, verified_policy, verified_world_model, world_model_folder
from schemas.errors import TamperedArtifact
from schemas.records import ArtifactRecord, LineageBatch
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE
from warehouse.store import Warehouse

WM = "attrs->>'model' = 'world_model' AND attrs->>'phase' = 'posttrain'"


def _checkpoint(root, name: str, config: str) -> tuple[str, object]:
    folder = root / "checkpoints" / name
    folder.mkdir(parents=True)
    (folder / WEIGHTS_FILE).write_bytes(b"weights of " + name.encode())
    (folder / CONFIG_FILE).write_text(config)
    return hashlib.sha256(name.encode()).hexdigest()[:24], folder


@pytest.fixture
def lineage(tmp_path):
    root = tmp_path / "root"
    tok_id, tok = _checkpoint(root, "tok", '{"tokenizer": {}}')
    wm_id, wm = _checkpoint(root, "wm", '{"world_model": {}, "tokenizer": "checkpoints/tok", "size": 32}')
    wh = Warehouse(root / "lineage.duckdb")
    wh.write(LineageBatch(artifacts=[
        ArtifactRecord(artifact_id=i, kind="checkpoint", uri=f"checkpoints/{n}/{WEIGHTS_FILE}",
                       sha256=hashlib.sha256((f / WEIGHTS_FILE).read_bytes()).hexdigest(),
                       attrs={"model": "world_model", "phase": "posttrain"} if n == "wm" else {"preset": "x"})
        for i, n, f in ((tok_id, "tok", tok), (wm_id, "wm", wm))]))
    yield wh, root, wm_id, wm, tok
    wh.close()


def test_an_intact_checkpoint_is_found_by_id_and_by_folder(lineage):
    wh, root, wm_id, wm, _ = lineage
    assert checkpoint_folder(wh, root, wm_id[:12], WM, "world model") == wm
    assert checkpoint_folder(wh, root, str(wm), WM, "world model") == wm
    assert world_model_folder(wh, root, None) == wm
    assert verified_world_model(wh, root, str(wm)) == wm_id


def test_a_changed_checkpoint_is_refused_by_id_and_by_folder(lineage):
    wh, root, wm_id, wm, tok = lineage
    (wm / WEIGHTS_FILE).write_bytes(b"weights of wm, retrained elsewhere")
    for name in (wm_id[:12], str(wm)):
        with pytest.raises(TamperedArtifact) as caught:
            checkpoint_folder(wh, root, name, WM, "world model")
        message = str(caught.value)
        assert "\n" not in message and str(wm / WEIGHTS_FILE) in message and wm_id[:12] in message
    for name in (wm_id[:12], None):
        with pytest.raises(TamperedArtifact):
            world_model_folder(wh, root, name)


def test_a_world_models_changed_tokenizer_is_refused(lineage):
    wh, root, _, wm, tok = lineage
    (tok / WEIGHTS_FILE).write_bytes(b"other weights")
    with pytest.raises(TamperedArtifact, match=f"{tok / WEIGHTS_FILE}: sha256"):
        verified_world_model(wh, root, str(wm))


def test_a_checkpoint_lineage_does_not_know_is_an_external_input(lineage, tmp_path):
    wh, root, _, _, _ = lineage
    _, elsewhere = _checkpoint(tmp_path / "elsewhere", "own", '{"world_model": {}, "size": 32}')
    assert checkpoint_folder(wh, root, str(elsewhere), WM, "world model") == elsewhere
    assert verified_world_model(wh, root, str(elsewhere)) is None
    _, copy = _checkpoint(tmp_path / "copy", "wm", '{"world_model": {}, "size": 32}')  # the same bytes elsewhere
    assert verified_world_model(wh, root, str(copy)) == lineage[2]


def test_a_policy_whose_weights_changed_is_refused(lineage):
    wh, root, wm_id, wm, _ = lineage

    class Loaded:  # what BCPolicy.from_checkpoint holds: the folder and the sha256 of the bytes it read
        source, meta = str(wm), {"weights_sha256": hashlib.sha256(b"weights of wm").hexdigest()}

    verified_policy(wh, root, Loaded())
    Loaded.meta = {"weights_sha256": hashlib.sha256(b"something else").hexdigest()}
    with pytest.raises(TamperedArtifact):
        verified_policy(wh, root, Loaded())
