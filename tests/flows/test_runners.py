"""The curate flow on a process pool writes the same shards and lineage as on threads."""

import hashlib

from prefect.task_runners import ProcessPoolTaskRunner

from flows.curate import curate
from flows.runners import task_runner
from schemas.settings import Settings
from tasks.manifests import load
from tasks.mp4 import write_mp4
from tasks.sim.episode import rollout
from warehouse.store import Warehouse

from tests.support import MANIFESTS

MANIFEST = MANIFESTS / "conveyor_push.yaml"
LINEAGE = """SELECT kind, count(*) FROM artifacts GROUP BY kind
             UNION ALL SELECT 'edges', count(*) FROM edges
             UNION ALL SELECT 'rejections', count(*) FROM rejections ORDER BY 1"""


def _curate(root, monkeypatch, inbox, runner):
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(root))
    summary = curate.with_options(task_runner=runner)([str(inbox)], str(MANIFEST))
    shards = {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
              for p in sorted((root / "shards").rglob("*.parquet"))}
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query(LINEAGE)
    return summary, shards, rows


def test_process_runner_gives_the_same_shards_and_lineage(prefect_harness, tmp_path, monkeypatch):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    scenario = load(MANIFEST).model_copy(update={"horizon_s": 3.0})
    for seed in (1, 2):
        write_mp4(inbox / f"episode_{seed}.mp4", rollout(scenario, seed).frames["overhead"], 30)
    (inbox / "broken.mp4").write_bytes(b"not a video" * 50)
    runner = task_runner(Settings(task_runner="process", workers=2))
    assert isinstance(runner, ProcessPoolTaskRunner)
    threads = _curate(tmp_path / "threads", monkeypatch, inbox, task_runner(Settings()))
    processes = _curate(tmp_path / "processes", monkeypatch, inbox, runner)
    assert threads[0]["status"] == processes[0]["status"] == "partial" and processes[0]["failed"] == 1
    assert threads[0]["counts"] == processes[0]["counts"] and processes[0]["clips"] >= 1
    assert threads[1] and threads[1] == processes[1]  # byte-identical shards under the same paths
    assert threads[2] == processes[2]  # the same lineage rows, written once by the flow process
