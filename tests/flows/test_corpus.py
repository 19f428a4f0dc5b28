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
