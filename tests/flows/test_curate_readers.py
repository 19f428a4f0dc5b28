"""Issue 30, point 3: a curate run with a reader process holding the warehouse open and another
opening it again and again throughout: the flow completes, and every state a reader sees is one
the writer published whole (warehouse/snapshot.py)."""

from __future__ import annotations

from schemas.settings import Settings
from warehouse import snapshot
from warehouse.store import Warehouse

from tests.support import good_videos, lineage_problems
from tests.warehouse.test_snapshot import reader, seen

TABLES = ("runs", "stage_runs", "artifacts", "edges", "ancestry", "rejections", "metrics")
SEE = ("SELECT " + ", ".join(f"(SELECT count(*) FROM {t})" for t in TABLES)
       + ", (SELECT count(*) FROM runs WHERE status = 'running')")


def test_curate_with_readers_held_and_polling(prefect_harness, data_root, tmp_path, monkeypatch):
    from flows.curate import curate

    inbox = tmp_path / "inbox"
    good_videos(inbox, seeds=(0, 2))
    (inbox / "broken.mp4").write_bytes(b"\x00not a video" * 200)
    monkeypatch.setattr(snapshot, "MIN_INTERVAL_S", 0.1)  # many publishes in a short run
    published = set()
    real = snapshot.publish

    def spy(con, path, src):  # the state each publish copies: the writer holds its locks here
        published.add(tuple(con.execute(SEE).fetchall()[0]))
        return real(con, path, src)

    monkeypatch.setattr(snapshot, "publish", spy)
    path, stop = Settings().warehouse_path, tmp_path / "stop"
    Warehouse(path).close()  # the warehouse and its first snapshot, as an earlier run leaves them
    holder, poller = reader(path, stop, "hold", SEE), reader(path, stop, "poll", SEE)
    try:
        result = curate([str(inbox)])
    finally:
        stop.touch()
        held, polled = seen(holder), seen(poller)

    assert result["status"] == "partial" and result["clips"] >= 1  # the broken input, nothing else
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:
        final = (*wh.query(SEE)[1][0], 1)
        assert wh.snapshot
    empty = (0,) * (len(TABLES) + 1) + (1,)
    assert held == [empty, empty]  # the file it opened, unchanged by the run
    assert {p[:-1] for p in polled} <= published | {empty[:-1]}, "a reader saw a state no publish wrote"
    assert all(p[-1] == 1 for p in polled), "a reader opened the main file while the flow ran"
    assert polled[-1] == final and final[TABLES.index("runs")] == 1 and final[len(TABLES)] == 0
    assert len(set(polled)) >= 3, polled  # it saw the run under way
    assert lineage_problems(path) == {}

