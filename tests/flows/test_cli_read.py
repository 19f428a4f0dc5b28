"""`worldline sql` and `worldline report` on a small warehouse written with the real writer."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from flows.cli import app
from tests.tasks.report.conftest import build

runner = CliRunner()


def test_sql_reads_lineage_and_refuses_writes(tmp_path, monkeypatch):
    lineage = build(tmp_path / "data")
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(lineage.root))
    done = runner.invoke(app, ["sql", "SELECT run_id, flow FROM runs ORDER BY run_id", "--format", "json"])
    assert done.exit_code == 0, done.output
    assert [r["flow"] for r in json.loads(done.output)] == ["curate", "train"]
    refused = runner.invoke(app, ["sql", "DELETE FROM runs"])
    assert refused.exit_code == 2 and "read-only" in refused.output.lower(), refused.output
    assert json.loads(runner.invoke(app, ["sql", "SELECT count(*) AS n FROM runs", "--format", "json"]).output) == [{"n": 2}]
    warehouse = lineage.root / "lineage.duckdb"
    copied = runner.invoke(app, ["sql", f"COPY (SELECT 1 AS x) TO '{warehouse}' (FORMAT csv)"])
    assert copied.exit_code == 2 and "disabled" in copied.output and len(copied.output.strip().splitlines()) == 1
    assert runner.invoke(app, ["summary"]).exit_code == 0  # the warehouse is still one
    empty = runner.invoke(app, ["sql", " "])
    assert empty.exit_code == 2 and "no SQL statement given" in empty.output
    capped = runner.invoke(app, ["sql", "SELECT * FROM range(50) t(x)", "--format", "csv", "--limit", "5"])
    assert capped.exit_code == 0 and capped.stdout.split() == ["x", "0", "1", "2", "3", "4"]
    assert "more are left" in capped.stderr


def test_report_writes_the_page_or_lists_the_closest_ids(tmp_path, monkeypatch):
    lineage = build(tmp_path / "data")
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(lineage.root))
    done = runner.invoke(app, ["report", lineage.curate_run[:9], "--out", str(tmp_path / "page.html")])
    assert done.exit_code == 0, done.output
    page = (tmp_path / "page.html").read_text()
    assert lineage.curate_run in page and "<img" in page
    unknown = runner.invoke(app, ["report", "run-curate-0009"])
    assert unknown.exit_code == 2 and "closest" in unknown.output and lineage.curate_run in unknown.output
