from flows.corpus import corpus
from flows.curate import curate
from schemas.settings import Settings
from tests.warehouse.test_openlineage import check_runs
from warehouse.store import Warehouse


def test_corpus_then_curate_it(prefect_harness, data_root, monkeypatch):
    monkeypatch.setenv("WORLDLINE_REPORT_PAGES", "true")  # (off for the rest of the suite: tests/conftest.py)
    result = corpus(minutes=0.3, seed=4, width=128, height=72)
    assert len(result["videos"]) == 1
    summary = curate([str(data_root / "corpus")])
    assert summary["status"] == "completed" and summary["inputs"] == 1
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, kinds = wh.query("SELECT kind, count(*) FROM artifacts GROUP BY kind ORDER BY kind")
        _, rows = wh.query("SELECT run_id, flow, status FROM runs ORDER BY started_at")
        _, judged = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'clip'")
    kinds = dict(kinds)
    assert kinds["raw_video"] == 1 and kinds["ground_truth"] == 1  # the same video, recorded once by content
    assert judged[0][0] >= 2
    assert [r[1:] for r in rows] == [("corpus", "completed"), ("curate", "completed")]
    check_runs(data_root, rows)  # their OpenLineage events and report pages


def test_corpus_never_writes_over_another_corpus_or_the_users_files(prefect_harness, data_root):
    """The same seed with other settings overwrote the earlier corpus in place (lineage then in
    conflict), a user's files there were replaced without a word, and a re-run never skipped."""
    import pytest

    from schemas.errors import InvalidInput

    small = {"minutes": 0.05, "seed": 1, "width": 64, "height": 64, "fps": 5.0}
    first = corpus(**small)
    folder = data_root / "corpus" / "seed_000001"
    made = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert corpus(**small)["videos"] == first["videos"]  # made before: skipped
    with pytest.raises(InvalidInput, match=r"seed_000001: holds a corpus of other settings \(in lineage\) "
                                           r"\(raw_0000\.mp4, raw_0000\.truth\.json\)"):
        corpus(**{**small, "width": 96})
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == made
    other = data_root / "corpus" / "seed_000002"
    other.mkdir(parents=True)
    (other / "notes.txt").write_text("mine")
    with pytest.raises(InvalidInput, match=r"seed_000002: holds files that are not a corpus's \(notes\.txt\)"):
        corpus(**{**small, "seed": 2})
    (other / "notes.txt").unlink()
    (other / "raw_0000.mp4").write_bytes(b"half written")  # an interrupted run's, never recorded: written over
    assert len(corpus(**{**small, "seed": 2})["videos"]) == 1 and (other / "raw_0000.mp4").stat().st_size > 100
