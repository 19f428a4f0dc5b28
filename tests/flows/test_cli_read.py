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


def test_report_replaces_only_its_own_pages(tmp_path, monkeypatch):
    """`--out` naming the warehouse replaced it with the page, and a folder gave a traceback and
    left a temporary file: a path that is neither new nor a report page is refused in one line."""
    lineage = build(tmp_path / "data")
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(lineage.root))
    warehouse = lineage.root / "lineage.duckdb"
    before = warehouse.read_bytes()
    mine = tmp_path / "notes.html"
    mine.write_text("<html>my own notes</html>")
    folder = tmp_path / "pages"
    folder.mkdir()
    for out, why in ((warehouse, "not a Worldline report page"), (mine, "not a Worldline report page"),
                     (folder, "a folder")):
        refused = runner.invoke(app, ["report", lineage.curate_run, "--out", str(out)])
        assert refused.exit_code == 2 and why in refused.output, refused.output
        assert len(refused.output.strip().splitlines()) == 1 and "Traceback" not in refused.output
    assert warehouse.read_bytes() == before and mine.read_text() == "<html>my own notes</html>"
    assert list(folder.iterdir()) == [] and not list(tmp_path.glob(".*.tmp"))
    page = tmp_path / "page.html"
    for _ in range(2):  # a page written before is replaced
        done = runner.invoke(app, ["report", lineage.curate_run, "--out", str(page)])
        assert done.exit_code == 0, done.output


def test_a_page_links_a_recorded_path_that_loops(tmp_path):
    """A curate run that quarantined a symlink loop: its page named the input as recorded
    instead of failing with "Symlink loop" (worldline report exited 1 with a traceback)."""
    from tasks.report.page import Page

    (tmp_path / "a.mp4").symlink_to(tmp_path / "b.mp4")
    (tmp_path / "b.mp4").symlink_to(tmp_path / "a.mp4")
    page = Page(tmp_path)
    assert page.path("a.mp4") == tmp_path / "a.mp4"
    assert page.link("a.mp4").html == f'<a href="{(tmp_path / "a.mp4").as_uri()}">a.mp4</a> <span class="missing">(missing)</span>'
