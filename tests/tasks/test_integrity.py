"""tasks/integrity.py: a file checked against the rows lineage holds for it (issue 26)."""

import hashlib

import pytest

from schemas.errors import EXIT_ENVIRONMENT, InvalidInput, TamperedArtifact
from tasks import integrity
from tasks.integrity import Recorded


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_file_sha256_is_the_hash_of_the_bytes(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"x" * (3 << 20))  # more than one streamed block
    assert integrity.file_sha256(path) == _sha(b"x" * (3 << 20))


def test_match_uses_the_row_at_the_uri_or_a_copy_elsewhere_and_refuses_changed_bytes(tmp_path):
    row = Recorded("a" * 24, "shard", "shards/a.parquet", _sha(b"one"), "m" * 64)
    assert integrity.match("x", "shards/a.parquet", _sha(b"one"), "shard", [row]) == row
    assert integrity.match("x", "/elsewhere/a.parquet", _sha(b"one"), "shard", [row]) == row  # a copy
    assert integrity.match("x", "/elsewhere/a.parquet", _sha(b"one"), "token_shard", [row]) is None  # another kind
    assert integrity.match("x", "shards/b.parquet", _sha(b"two"), "shard", []) is None  # unknown: caller decides
    older = Recorded("b" * 24, "shard", "shards/a.parquet", _sha(b"two"))
    assert integrity.match("x", "shards/a.parquet", _sha(b"two"), "shard", [row, older]) == older  # any version
    with pytest.raises(TamperedArtifact) as caught:
        integrity.match(tmp_path / "a.parquet", "shards/a.parquet", _sha(b"three"), "shard", [row])
    message = str(caught.value)
    assert "\n" not in message and str(tmp_path / "a.parquet") in message
    assert _sha(b"three")[:12] in message and _sha(b"one")[:12] in message and "a" * 12 in message
    assert "worldline verify" in message and caught.value.exit_code == EXIT_ENVIRONMENT


def test_check_and_unknown(tmp_path):
    path = tmp_path / "w.safetensors"
    path.write_bytes(b"weights")
    row = Recorded("c" * 24, "checkpoint", "w.safetensors", _sha(b"weights"))
    assert integrity.check(path, row) == _sha(b"weights")
    path.write_bytes(b"weightz")
    with pytest.raises(TamperedArtifact, match="w.safetensors: sha256 .* differs from lineage's"):
        integrity.check(path, row)
    error = integrity.unknown(path, _sha(b"weightz"), "curated shard", "run curate")
    assert isinstance(error, InvalidInput) and "lineage has no curated shard with these bytes" in str(error)


def test_uri_and_path_agree(tmp_path):
    root = tmp_path / "root"
    (root / "shards").mkdir(parents=True)
    inside, outside = root / "shards" / "a.parquet", tmp_path / "b.parquet"
    assert integrity.uri_of(inside, root) == "shards/a.parquet" and integrity.uri_of(outside, root) == str(outside)
    assert integrity.path_of("shards/a.parquet", root) == root / "shards" / "a.parquet"
    assert integrity.path_of(str(outside), root) == outside


def test_audit_hashes_each_file_once_and_names_missing_changed_and_conflicting(tmp_path):
    for name, data in (("same", b"1"), ("changed", b"2"), ("twice", b"3")):
        (tmp_path / name).write_bytes(data)
    rows = [Recorded("s1", "clip", "same", _sha(b"1")), Recorded("s2", "clip", "same", _sha(b"1")),
            Recorded("c", "clip", "changed", _sha(b"old")), Recorded("m", "shard", "gone", _sha(b"x")),
            Recorded("t1", "token_shard", "twice", _sha(b"3")), Recorded("t2", "token_shard", "twice", _sha(b"4"))]
    findings, checked, hashed = integrity.audit(rows, tmp_path)
    assert checked == 6 and hashed == 3
    assert [(f.problem, f.artifact_id) for f in findings] == [
        ("missing", "m"), ("changed", "c"), ("conflict", "t1"), ("conflict", "t2")]
    assert findings[1].file_sha256 == _sha(b"2") and findings[0].file_sha256 is None
    assert integrity.audit(rows[:2], tmp_path)[0] == []


def test_an_input_rewritten_in_place_and_curated_again_is_superseded_not_a_conflict(tmp_path):
    (tmp_path / "in.mp4").write_bytes(b"new")
    old, new = Recorded("r1", "raw_video", "in.mp4", _sha(b"old")), Recorded("r2", "raw_video", "in.mp4", _sha(b"new"))
    findings, _, _ = integrity.audit([old, new], tmp_path)
    assert [(f.problem, f.artifact_id) for f in findings] == [("superseded", "r1")]
    (tmp_path / "in.mp4").write_bytes(b"third")  # bytes no row records: lineage cannot say which is right
    assert [f.problem for f in integrity.audit([old, new], tmp_path)[0]] == ["conflict", "conflict"]
    (tmp_path / "in.mp4").write_bytes(b"new")  # a file Worldline wrote is never superseded
    clip = [Recorded("c1", "clip", "in.mp4", _sha(b"old")), Recorded("c2", "clip", "in.mp4", _sha(b"new"))]
    assert [f.problem for f in integrity.audit(clip, tmp_path)[0]] == ["conflict", "conflict"]
