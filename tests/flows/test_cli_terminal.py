"""Issue 30, point 5: an honest terminal. Machine-readable output is never wrapped (`manifest
show` piped is valid YAML; `--format csv|json` whole ids, tables ids cut to 12 characters),
every command that prints rows takes `--format`, `--version`, `--data-root`, one console for
progress bars and log lines, Prefect's INFO lines only with `-v`."""

from __future__ import annotations

import csv
import inspect
import io
import json
import logging
import os
import subprocess
import sys

import pytest
import yaml
from rich.console import Console
from typer.testing import CliRunner

from flows import console
from flows.cli import app
from tests.support import MANIFESTS, REPO
from tests.tasks.report.conftest import build

runner = CliRunner()
GOOD = MANIFESTS / "conveyor_push.yaml"


def test_manifest_show_piped_into_a_narrow_terminal_is_valid_yaml():
    env = {**os.environ, "COLUMNS": "40"}  # rich wrapped the 81-character hash comment at 40 (and at 80)
    done = subprocess.run([sys.executable, "-m", "flows.cli", "manifest", "show", str(GOOD)], capture_output=True,
                          text=True, cwd=REPO, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    first = done.stdout.splitlines()[0]
    assert first.startswith("# manifest_hash: ") and len(first.split()[-1]) == 64
    assert yaml.safe_load(done.stdout)["name"] == "conveyor-push"


def test_version_prints_the_package_version():
    from importlib.metadata import version

    done = runner.invoke(app, ["--version"])
    assert done.exit_code == 0 and done.output.strip() == f"worldline {version('worldline')}"


def test_data_root_option_is_the_same_as_the_variable(tmp_path, monkeypatch):
    lineage = build(tmp_path / "data")
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(tmp_path / "empty"))
    monkeypatch.setenv("PREFECT_HOME", str((tmp_path / "empty" / "prefect").resolve()))  # as flows/__init__ sets it
    monkeypatch.delenv("DO_NOT_TRACK", raising=False)
    assert runner.invoke(app, ["summary"]).exit_code == 3  # nothing written there yet
    done = runner.invoke(app, ["--data-root", str(lineage.root), "summary", "--format", "json"])
    assert done.exit_code == 0, done.output
    assert json.loads(done.stdout)["tables"]["runs"] == 2
    assert os.environ["PREFECT_HOME"] == str((lineage.root / "prefect").resolve())  # Prefect's home follows
    assert os.environ["DO_NOT_TRACK"] == "1"  # Prefect's telemetry notice was the first thing a terminal showed


@pytest.fixture
def lineage(tmp_path, monkeypatch):
    built = build(tmp_path / "data")
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(built.root))
    return built


def test_json_and_csv_keep_ids_whole_and_tables_cut_them_to_12(lineage):
    query = "SELECT artifact_id, sha256 FROM artifacts WHERE sha256 IS NOT NULL ORDER BY artifact_id"
    rows = json.loads(runner.invoke(app, ["sql", query, "--format", "json"]).stdout)
    full = rows[0]["sha256"]
    assert len(full) == 64 and len(rows[0]["artifact_id"]) >= 16
    as_csv = list(csv.DictReader(io.StringIO(runner.invoke(app, ["sql", query, "--format", "csv"]).stdout)))
    assert as_csv[0] == rows[0]
    table = runner.invoke(app, ["sql", query]).stdout
    assert full[:12] in table and full[:13] not in table and rows[0]["artifact_id"][:13] not in table


def test_summary_takes_each_format(lineage):
    as_json = json.loads(runner.invoke(app, ["summary", "--format", "json"]).stdout)
    assert as_json["tables"]["runs"] == 2 and {r["flow"] for r in as_json["runs"]} == {"curate", "train"}
    as_csv = list(csv.DictReader(io.StringIO(runner.invoke(app, ["summary", "--format", "csv"]).stdout)))
    assert {r["name"] for r in as_csv if r["section"] == "runs"} == {"curate", "train"}
    assert "runs" in runner.invoke(app, ["summary"]).stdout
    bad = runner.invoke(app, ["summary", "--format", "xml"])
    assert bad.exit_code == 2 and "one of table, csv, json" in bad.output


def _commands(group):
    for info in group.registered_commands:
        yield info
    for sub in group.registered_groups:
        yield from _commands(sub.typer_instance)


def test_every_command_that_prints_rows_takes_format():
    """`demo` prints its showcase (a summary, the loop's table, an audit) and takes no options."""
    listing = []
    for info in _commands(app):
        body = getattr(info.callback, "body", info.callback)
        if "print_rows(" in inspect.getsource(body) and body.__name__ != "demo":
            listing.append(body.__name__)
            assert "fmt" in inspect.signature(info.callback).parameters, f"{body.__name__} takes no --format"
    assert {"audit", "summary", "sql", "verify", "scenes", "inspect", "evaluate_policies_cmd", "loop_cmd"} <= set(listing)


def test_prefect_info_lines_only_when_verbose_warnings_always(monkeypatch):
    """Prefect's console handler is swapped for one printing through the shared stderr console;
    its INFO lines pass only with -v."""
    from prefect.logging.handlers import PrefectConsoleHandler

    root = logging.getLogger()
    kept = list(root.handlers)
    try:
        root.addHandler(PrefectConsoleHandler(level=logging.NOTSET))
        console.route_prefect_logs()
        ours = [h for h in root.handlers if isinstance(h, console.ConsoleLog)]
        assert ours and not any(isinstance(h, PrefectConsoleHandler) for h in root.handlers)
        shown = Console(file=io.StringIO(), width=60)
        monkeypatch.setattr(console, "err", shown)

        def says(level, message):
            ours[-1].handle(logging.LogRecord("prefect", level, __file__, 1, message, None, None))

        console.set_verbose(False)
        says(logging.INFO, "Beginning flow run 'quiet-fox'")
        says(logging.WARNING, "a warning stays " + "x" * 80)  # longer than the console: one line all the same
        console.set_verbose(True)
        says(logging.INFO, "Finished in state Completed()")
        lines = shown.file.getvalue().splitlines()
        assert "quiet-fox" not in shown.file.getvalue()
        assert any(line.endswith("a warning stays " + "x" * 80) for line in lines)
        assert any("Finished in state Completed()" in line for line in lines)
    finally:
        console.set_verbose(False)
        root.handlers[:] = kept


def test_a_log_line_during_a_progress_bar_prints_above_it_through_one_console(monkeypatch):
    from flows import report

    terminal = Console(file=io.StringIO(), force_terminal=True, width=80, color_system=None)
    monkeypatch.setattr(console, "err", terminal)
    monkeypatch.setattr(report, "create_progress_artifact", lambda *a, **k: None)
    handler = console.ConsoleLog(logging.Formatter("%(levelname)s %(message)s"))
    with report.progress(3, "face guard") as bar:
        assert bar._bar is not None and bar._bar.console is terminal
        handler.handle(logging.LogRecord("prefect.task_runs", logging.WARNING, __file__, 1, "slow clip", None, None))
        bar.advance(3)
    # The bar's line cleared (ESC[2K), the log line written whole, then the bar drawn again below it.
    assert "\x1b[2KWARNING slow clip" in terminal.file.getvalue().replace("\r", "\n").splitlines()


def test_a_bar_moved_by_a_topic_follows_what_the_task_reports(monkeypatch, tmp_path):
    """Training steps and the face guard's clips move their bars from inside the task
    (tasks/progress.py): curate's encode bar once stood at 0/1 through a 64 s face guard."""
    from flows import report
    from tasks import progress as ticks
    from tasks.guard.clip import guard_clips
    from tasks.guard.config import GuardConfig
    from tasks.world.phases import _tensorboard

    terminal = Console(file=io.StringIO(), force_terminal=True, width=100, color_system=None)
    monkeypatch.setattr(console, "err", terminal)
    monkeypatch.setattr(report, "create_progress_artifact", lambda *a, **k: pytest.fail("a topic bar has no artifact"))
    with report.progress(200, "pre-train (steps)", topic=ticks.WORLD_MODEL_STEPS) as bar:
        writer, log = _tensorboard(tmp_path / "tensorboard")
        with writer:
            log({"step": 120, "loss": 1.0, "accuracy": 0.5, "copy_accuracy": 0.4, "lr": 1e-3})
        assert bar._bar.tasks[0].completed == 120
    monkeypatch.setattr(report, "create_progress_artifact", lambda *a, **k: None)
    with report.progress(2, "kept clips encoded and guarded", {ticks.GUARDED: ("face guard", 2)}) as bar:
        guard_clips(["a.mp4", "b.mp4"], GuardConfig(enabled=False))  # off: nothing read, each clip still counted
        assert [t.completed for t in bar._bar.tasks] == [0, 2]
    ticks.advance(ticks.GUARDED)  # nobody listens now: nothing happens
    with report.progress(3, "corpus seed 0 (frames)", topic=ticks.CORPUS_FRAMES) as bar:
        assert list(ticks.counted("abc", ticks.CORPUS_FRAMES)) == ["a", "b", "c"]  # as the corpus writer takes frames
        assert bar._bar.tasks[0].completed == 3


def test_scenes_and_inspect_take_each_format(tmp_path):
    from tests.support import scene_frames, write_video

    video = write_video(tmp_path / "clip.mp4", scene_frames(0, n=24))
    scenes = json.loads(runner.invoke(app, ["scenes", str(video), "--format", "json"]).stdout)
    assert scenes["video"] == str(video) and scenes["scenes"]
    rows = list(csv.DictReader(io.StringIO(runner.invoke(app, ["scenes", str(video), "--format", "csv"]).stdout)))
    assert len(rows) == len(scenes["scenes"]) and set(rows[0]) == set(scenes["scenes"][0])
    assert json.loads(runner.invoke(app, ["scenes", str(video), "--json"]).stdout) == scenes  # the older spelling
    clips = list(csv.DictReader(io.StringIO(runner.invoke(app, ["inspect", str(video), "--format", "csv"]).stdout)))
    assert clips and json.loads(clips[0]["scores"])  # scores as JSON text, every one there


def test_a_table_keeps_each_id_on_one_line_in_80_columns(monkeypatch):
    """Issue 30: audit tables wrapped 64-hex hashes into 9-character columns in 80 columns."""
    from datetime import datetime

    shown = Console(file=io.StringIO(), width=80, color_system=None)
    monkeypatch.setattr(console, "out", shown)
    sha, artifact = "3a659c383a89" + "0" * 52, "d0ad0110e0268d778f43c663"
    row = ("clip", artifact, "clips/" + "x" * 40 + ".mp4", sha, 6102, "encode", datetime(2026, 11, 26, 3, 6, 30, 172288))
    console.print_rows(["kind", "artifact_id", "uri", "sha256", "bytes", "stage", "recorded_at"], [row], "table")
    text = shown.file.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 80
    first = next(line for line in text.splitlines() if line.startswith("clip"))
    assert "d0ad0110e026 " in first and "3a659c383a89 " in first and "6102" in first  # whole, 12 characters each
    assert sha[:13] not in text and ".172288" not in text  # cut; a time to the second
