"""Issue 5: one curate run over a batch of hostile and odd inputs loses nothing.

One ``worldline curate`` process goes over every bad input of ``tests.support.BAD_INPUTS``, the
merely unusual ones (variable frame rate, rotated, odd size, awkward names) and plain good
videos. Each bad input must be quarantined with its precise reason, every good clip must come
out exactly as in a run over the good inputs alone, and the run must end "partial" saying how
many inputs failed. The same run is the concurrency test: its ``analyse-video`` tasks run in
parallel on Prefect's thread pool, and the rows they leave are checked against a serial
reference computed video by video.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, RejectionRecord
from tasks.curate.analyse import analyse_video
from tasks.curate.inputs import discover
from warehouse.store import Warehouse

from tests.support import (LINEAGE_CHECKS, curate_command, good_videos, lineage_problems, shard_digests,
                           unprivileged_prefix, unusual_videos, bad_inputs)


@pytest.fixture(scope="module")
def batch(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("batch")
    prefix = unprivileged_prefix()
    expected = bad_inputs(folder)
    good = good_videos(folder) + unusual_videos(folder)
    if prefix is None:  # root, and no way to drop the capability that ignores permission bits
        os.chmod(folder / "locked.mp4", 0o644)
        expected.pop("locked.mp4")
        good.append(folder / "locked.mp4")
    good.sort()
    return {"folder": folder, "expected": expected, "good": good, "prefix": prefix or []}


@pytest.fixture(scope="module")
def batch_run(prefect_harness, batch, tmp_path_factory) -> dict:
    """The whole batch through the command line, in its own process (permission bits binding)."""
    from prefect.settings import PREFECT_API_URL

    root = tmp_path_factory.mktemp("batch_root")
    done = curate_command([batch["folder"]], root, api_url=PREFECT_API_URL.value(), prefix=batch["prefix"],
                          workers=WORKERS)
    return {"root": root, "process": done, "warehouse": root / "lineage.duckdb"}


WORKERS = 6  # threads of the batch run's task runner (the default is Settings.workers)


def _rows(db: Path, sql: str, params=None) -> list[tuple]:
    with Warehouse(db, read_only=True) as wh:
        return wh.query(sql, params)[1]


def test_every_bad_input_is_quarantined_with_its_reason(batch, batch_run):
    done = batch_run["process"]
    n_inputs = len(batch["expected"]) + len(batch["good"])
    n_bad = len(batch["expected"])
    assert done.returncode == 1, done.stderr[-3000:]
    assert f"{n_bad} of {n_inputs} inputs quarantined" in done.stdout
    rows = _rows(batch_run["warehouse"], "SELECT a.uri, r.stage, r.reason, r.detail FROM rejections r "
                                          "JOIN artifacts a USING (artifact_id) WHERE a.kind = 'raw_video'")
    got = {Path(uri).name: (stage, reason) for uri, stage, reason, _ in rows}
    assert got == batch["expected"]
    for uri, _, _, detail in rows:
        assert uri in detail and len(detail) > len(uri) + 5, detail  # names the file and says what is wrong
    assert _rows(batch_run["warehouse"], "SELECT status, message FROM runs") == [
        ("partial", f"partial: {n_bad} of {n_inputs} inputs failed")]
    assert lineage_problems(batch_run["warehouse"]) == {}


def test_unusual_inputs_are_curated_and_good_clips_match_a_good_only_run(batch, batch_run, data_root):
    from flows.curate import curate

    rows = _rows(batch_run["warehouse"], "SELECT attrs->>'source' FROM stage_runs WHERE stage = 'analyse'")
    assert sorted(Path(r[0]).name for r in rows) == sorted(p.name for p in batch["good"])
    alone = curate([str(p) for p in batch["good"]])
    assert alone["status"] == "completed" and alone["failed"] == 0
    assert alone["clips"] >= 1  # the procedural seeds were checked to give kept clips
    batch_shards = shard_digests(batch_run["root"])
    assert batch_shards and batch_shards == shard_digests(data_root)  # same clips, same bytes
    clips = _rows(batch_run["warehouse"], "SELECT attrs->>'source_id', sha256 FROM artifacts WHERE kind = 'clip' "
                                          "AND uri IS NOT NULL ORDER BY 1, 2")
    assert clips == _rows(data_root / "lineage.duckdb", "SELECT attrs->>'source_id', sha256 FROM artifacts "
                                                        "WHERE kind = 'clip' AND uri IS NOT NULL ORDER BY 1, 2")


def test_parallel_tasks_record_exactly_the_rows_a_serial_pass_predicts(batch, batch_run):
    """The batch's analyse tasks ran at the same time; their rows match a video-by-video reference."""
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterId

    db = batch_run["warehouse"]
    (run_id,), = _rows(db, "SELECT run_id FROM runs")
    with get_client(sync_client=True) as client:
        task_runs = client.read_task_runs(flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[run_id])))
    spans = sorted((t.start_time, t.end_time) for t in task_runs if t.name.startswith("analyse-video") and t.start_time)
    assert len(spans) >= 10
    overlapping = max(sum(1 for s, e in spans if s <= start < e) for start, _ in spans)
    assert 2 <= overlapping <= WORKERS, f"{overlapping} analyse tasks at once with {WORKERS} threads"

    reference = [analyse_video(item.path, item.sha256) for item in discover(batch["good"])]
    clips = [c for r in reference for c in r.clips]
    kept = {c.clip_id for c in clips if c.kept}
    expected = {
        "raw_video": len(reference) + len(batch["expected"]),
        "clip": len(clips),
        "encoded clips": len(kept),
        "clip rejections": len(clips) - len(kept),
        "split_from edges": len(clips),
        "shard_of edges": len(kept),
        "analyse stage runs": len(reference),
        "encode stage runs": len({c.source_id for c in clips if c.kept}),
    }
    found = dict(zip(expected, _rows(db, """SELECT
        (SELECT count(*) FROM artifacts WHERE kind = 'raw_video'),
        (SELECT count(*) FROM artifacts WHERE kind = 'clip'),
        (SELECT count(*) FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL),
        (SELECT count(*) FROM rejections r JOIN artifacts a USING (artifact_id) WHERE a.kind = 'clip'),
        (SELECT count(*) FROM edges WHERE relation = 'split_from'),
        (SELECT count(*) FROM edges WHERE relation = 'shard_of'),
        (SELECT count(*) FROM stage_runs WHERE stage = 'analyse'),
        (SELECT count(*) FROM stage_runs WHERE stage = 'encode')""")[0]))
    assert found == expected
    ids = {r[0] for r in _rows(db, "SELECT artifact_id FROM artifacts WHERE kind = 'clip'")}
    assert ids == {c.clip_id for c in clips}


def test_writes_from_many_threads_lose_and_double_nothing(tmp_path):
    """RunContext.write may be called from any thread: the writer serialises the transactions."""
    wh = Warehouse(tmp_path / "w.duckdb")
    n_threads, n_batches, per_batch = 6, 5, 25

    def work(t: int) -> None:
        for b in range(n_batches):
            ids = [f"t{t}-b{b}-{i}" for i in range(per_batch)]
            batch = LineageBatch(
                artifacts=[ArtifactRecord(artifact_id=i, kind="clip", uri=None, sha256=None) for i in ids],
                edges=[EdgeRecord(parent_id=ids[0], child_id=i) for i in ids[1:]],
                rejections=[RejectionRecord(artifact_id=i, stage="motion", reason="static") for i in ids[::5]])
            wh.write(batch)
            wh.write(batch)  # a retried task hands in the same records again
            wh.completed_stage_runs("analyse", ids[:3])

    threads = [threading.Thread(target=work, args=(t,)) for t in range(n_threads)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    counts = wh.counts()
    wh.close()
    total = n_threads * n_batches
    assert counts["artifacts"] == total * per_batch
    assert counts["edges"] == total * (per_batch - 1)
    assert counts["rejections"] == total * 5
    with Warehouse(tmp_path / "w.duckdb", read_only=True) as wh:
        for name, sql in LINEAGE_CHECKS.items():
            if name.startswith(("duplicate", "edges", "ancestry")) and "span" not in name:
                assert wh.query(sql)[1] == [(0,)], name


def test_a_second_writer_waits_for_the_first_then_gives_up_in_one_line(tmp_path):
    """Issue 26: two curate runs on one data root. The second waits for the data root's lock
    (taken before Prefect starts, so the two never race on Prefect's database migration), then
    exits 4 naming the first; the first finishes as if alone."""
    import subprocess
    import time

    from warehouse.lock import LOCK_FILE

    from tests.support import REPO

    inbox = tmp_path / "inbox"
    good_videos(inbox, seeds=(0,))
    root = tmp_path / "root"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("WORLDLINE_", "PREFECT_"))}
    env |= {"WORLDLINE_DATA_ROOT": str(root), "PYTHONDONTWRITEBYTECODE": "1"}
    command = [str(REPO / ".venv" / "bin" / "worldline"), "curate", str(inbox)]
    first = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (root / LOCK_FILE).is_file() or f"pid {first.pid}," not in (root / LOCK_FILE).read_text():
        assert time.monotonic() < deadline and first.poll() is None, "the first curate never took the lock"
        time.sleep(0.05)
    t0 = time.monotonic()
    second = subprocess.run(command, env={**env, "WORLDLINE_LOCK_TIMEOUT": "2"}, cwd=REPO, capture_output=True,
                            text=True, timeout=120)
    waited = time.monotonic() - t0
    out, errors = first.communicate(timeout=600)
    holder = f"{root}: another worldline process (pid {first.pid}, command worldline curate {inbox})"
    assert second.returncode == 4, second.stdout + second.stderr
    assert second.stderr.strip().splitlines() == [f"{holder} is writing; waiting up to 2 s",
                                                  f"{holder} is writing; waited 2 s (WORLDLINE_LOCK_TIMEOUT)"]
    assert second.stdout == "" and 2 <= waited < 30
    assert first.returncode == 0, out + errors
    assert lineage_problems(root / "lineage.duckdb") == {}
