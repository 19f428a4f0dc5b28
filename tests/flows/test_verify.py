"""`worldline verify`: every file lineage recorded against its sha256, read-only (issue 26)."""

import hashlib
import json

from typer.testing import CliRunner

from flows.cli import app
from schemas.errors import EXIT_ENVIRONMENT
from schemas.records import ArtifactRecord, LineageBatch, ManifestRow
from schemas.settings import Settings
from warehouse.store import Warehouse

runner = CliRunner()
MH = "ab" * 32


def _record(data_root, files: dict[str, bytes], manifest_hash: str = MH) -> list[ArtifactRecord]:
    rows = []
    for name, data in files.items():
        path = data_root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        rows.append(ArtifactRecord(artifact_id=hashlib.sha256(name.encode()).hexdigest()[:24], kind="clip", uri=name,
                                   sha256=hashlib.sha256(data).hexdigest(), bytes=len(data),
                                   manifest_hash=manifest_hash))
    return rows


def _lineage(data_root) -> None:
    batch = LineageBatch(manifests=[ManifestRow(manifest_hash=h, name="m", schema_version=1, body="{}")
                                    for h in (MH, "cd" * 32)],
                         artifacts=[ArtifactRecord(artifact_id=MH, kind="manifest", uri="nowhere.yaml", sha256=MH,
                                                   manifest_hash=MH),
                                    ArtifactRecord(artifact_id="judged", kind="clip", uri=None, sha256=None,
                                                   manifest_hash=MH)])
    batch.artifacts += _record(data_root, {"clips/a.mp4": b"a", "clips/b.mp4": b"b", "shards/s.parquet": b"s"})
    batch.artifacts += _record(data_root, {"clips/other.mp4": b"o"}, "cd" * 32)
    with Warehouse(Settings().warehouse_path) as wh:
        wh.write(batch)


def test_verify_exits_0_when_every_file_matches(data_root):
    _lineage(data_root)
    before = (data_root / "lineage.duckdb").stat().st_mtime_ns
    result = runner.invoke(app, ["verify"])
    assert result.exit_code == 0, result.output
    assert "4 artifacts checked, 4 files hashed: all match lineage" in " ".join(result.output.split())
    assert (data_root / "lineage.duckdb").stat().st_mtime_ns == before  # read-only


def test_verify_lists_changed_missing_and_conflicting_files_and_exits_5(data_root):
    _lineage(data_root)
    (data_root / "clips" / "a.mp4").write_bytes(b"tampered")
    (data_root / "shards" / "s.parquet").unlink()
    result = runner.invoke(app, ["verify", "--format", "json"])
    assert result.exit_code == EXIT_ENVIRONMENT, result.output
    body = json.loads(result.stdout)
    assert [(r["problem"], r["uri"]) for r in body] == [("missing", "shards/s.parquet"), ("changed", "clips/a.mp4")]
    assert body[1]["file_sha256"] == hashlib.sha256(b"tampered").hexdigest()
    assert body[1]["lineage_sha256"] == hashlib.sha256(b"a").hexdigest()
    assert "2 differ from lineage (1 missing, 1 changed, 0 conflict)" in result.stderr

    table = runner.invoke(app, ["verify"])
    said = " ".join(table.output.split())
    assert table.exit_code == EXIT_ENVIRONMENT and "changed" in said and "missing" in said  # uris fold at 80 columns
    assert said.rstrip().endswith("4 artifacts checked, 3 files hashed: 2 differ from lineage "
                                  "(1 missing, 1 changed, 0 conflict)")

    # One manifest only (by a prefix of its hash): the other manifest's file is not checked.
    (data_root / "clips" / "other.mp4").unlink()
    scoped = runner.invoke(app, ["verify", "--manifest", MH[:12], "--format", "csv"])
    assert scoped.exit_code == EXIT_ENVIRONMENT and "other.mp4" not in scoped.stdout
    assert scoped.stdout.splitlines()[0] == "problem,kind,artifact_id,uri,lineage_sha256,file_sha256"
    assert "3 artifacts checked" in scoped.stderr
    other = runner.invoke(app, ["verify", "--manifest", "cd" * 6, "--format", "csv"])
    assert other.exit_code == EXIT_ENVIRONMENT and "other.mp4" in other.stdout and "1 artifacts checked" in other.stderr


def test_verify_names_a_path_two_rows_claim_with_different_bytes(data_root):
    _lineage(data_root)
    with Warehouse(Settings().warehouse_path) as wh:
        wh.write(LineageBatch(artifacts=[ArtifactRecord(artifact_id="rewritten", kind="clip", uri="clips/b.mp4",
                                                        sha256="0" * 64, manifest_hash=MH)]))
    result = runner.invoke(app, ["verify", "--format", "csv"])
    assert result.exit_code == EXIT_ENVIRONMENT
    assert sorted(line.split(",")[:3] for line in result.stdout.splitlines()[1:]) == [
        ["conflict", "clip", hashlib.sha256(b"clips/b.mp4").hexdigest()[:24]], ["conflict", "clip", "rewritten"]]


def test_verify_lists_an_input_curated_again_after_a_rewrite_but_passes(data_root):
    """An input edited in place and curated again left verify at exit 5 for good ("conflict")."""
    _lineage(data_root)
    (data_root / "in.mp4").write_bytes(b"second")
    with Warehouse(Settings().warehouse_path) as wh:
        wh.write(LineageBatch(artifacts=[
            ArtifactRecord(artifact_id=i, kind="raw_video", uri=str(data_root / "in.mp4"),
                           sha256=hashlib.sha256(data).hexdigest(), manifest_hash=MH)
            for i, data in (("first", b"first"), ("second", b"second"))]))
    result = runner.invoke(app, ["verify", "--format", "csv"])
    assert result.exit_code == 0, result.output
    assert [line.split(",")[:3] for line in result.stdout.splitlines()[1:]] == [["superseded", "raw_video", "first"]]
    assert "all match lineage; 1 superseded (inputs rewritten in place and curated again)" in result.stderr


def test_verify_refuses_bad_arguments(data_root):
    nothing = runner.invoke(app, ["verify"])
    assert nothing.exit_code == 3 and "no warehouse here yet" in nothing.output  # not built
    _lineage(data_root)
    assert runner.invoke(app, ["verify", "--format", "xml"]).exit_code == 2
    unknown = runner.invoke(app, ["verify", "--manifest", "0" * 12])
    assert unknown.exit_code == 2 and "no such manifest in lineage" in unknown.output
