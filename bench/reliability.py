"""Reliability report (issue 5): a batch of bad inputs, SIGKILLs at the crash points, and what
was lost. Lost must be 0.

1. One ``worldline curate`` process over every bad input of ``tests.support.BAD_INPUTS`` plus
   good and merely unusual videos (permission bits binding: as root, without the capabilities
   that bypass them), against a run over the good inputs alone.
2. The same batch again in a fresh data root, killed with SIGKILL at each crash point of
   ``tasks/faults.py`` in turn, each run resuming the last, then run to the end; compared with
   the uninterrupted run of step 1.

    .venv/bin/python bench/reliability.py            # a few minutes on 2 busy cores
"""

from __future__ import annotations

import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import flows  # noqa: E402,F401  (Prefect settings before prefect is imported)
from tests.support import (bad_inputs, curate_command, good_videos, lineage_problems, sha256_of,  # noqa: E402
                           shard_digests, unprivileged_prefix, unusual_videos)
from warehouse.store import Warehouse  # noqa: E402

KILLS = ("decode:2", "clip:2", "shard:1", "lineage:3")
COUNTS = {
    "raw videos": "SELECT count(*) FROM artifacts WHERE kind = 'raw_video'",
    "quarantined inputs": "SELECT count(*) FROM rejections WHERE stage IN ('input', 'decode')",
    "clips judged": "SELECT count(*) FROM artifacts WHERE kind = 'clip'",
    "clips encoded": "SELECT count(*) FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL",
    "shards": "SELECT count(*) FROM artifacts WHERE kind = 'shard'",
    "edges": "SELECT count(*) FROM edges",
    "ancestry rows": "SELECT count(*) FROM ancestry",
    "rejections": "SELECT count(*) FROM rejections",
    "stage runs": "SELECT count(*) FROM stage_runs",
}
ROWS = {
    "artifacts": "SELECT artifact_id, kind, uri, sha256 FROM artifacts",
    "edges": "SELECT parent_id, child_id, relation FROM edges",
    "rejections": "SELECT artifact_id, stage, reason FROM rejections",
    "ancestry": "SELECT descendant_id, ancestor_id, depth FROM ancestry",
}


def _query(db: Path, sql: str) -> list[tuple]:
    with Warehouse(db, read_only=True) as wh:
        return wh.query(sql)[1]


def _counts(db: Path) -> dict[str, int]:
    return {name: _query(db, sql)[0][0] for name, sql in COUNTS.items()}


def _files(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): sha256_of(p) for folder in ("clips", "shards") if (root / folder).is_dir()
            for p in (root / folder).rglob("*") if p.is_file()}


def main() -> int:
    from prefect.settings import PREFECT_API_URL
    from prefect.testing.utilities import prefect_test_harness

    t0 = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="worldline-reliability-"))
    batch = work / "batch"
    prefix = unprivileged_prefix()
    expected = bad_inputs(batch)
    good = good_videos(batch) + unusual_videos(batch)
    if prefix is None:
        print("note: root without setpriv: the unreadable file is readable here and counts as good")
        (batch / "locked.mp4").chmod(0o644)
        expected.pop("locked.mp4")
        good.append(batch / "locked.mp4")
    lost = 0
    with prefect_test_harness(server_startup_timeout=180):
        api = PREFECT_API_URL.value()
        whole, alone, crashed = work / "whole", work / "alone", work / "crashed"
        run = curate_command([batch], whole, api_url=api, prefix=prefix or [])
        curate_command(good, alone, api_url=api)
        kills = []
        for fault in KILLS:
            done = curate_command([batch], crashed, fault=fault, api_url=api, prefix=prefix or [])
            kills.append((fault, done.returncode == -signal.SIGKILL))
        resumed = curate_command([batch], crashed, api_url=api, prefix=prefix or [])

    got = {Path(uri).name: (stage, reason) for uri, stage, reason in _query(
        whole / "lineage.duckdb", "SELECT a.uri, r.stage, r.reason FROM rejections r JOIN artifacts a USING (artifact_id) "
                                  "WHERE r.stage IN ('input', 'decode')")}
    right = sum(1 for name, want in expected.items() if got.get(name) == want)
    wrongly = sorted(set(got) - set(expected))
    status = _query(whole / "lineage.duckdb", "SELECT status, message FROM runs")[0]
    print(f"inputs tried: {len(expected) + len(good)} ({len(expected)} bad, {len(good)} good or unusual)")
    print(f"batch run: exit {run.returncode}, {status[0]!r}: {status[1]}")
    print(f"bad inputs quarantined with the expected stage and reason: {right} of {len(expected)}")
    for name, want in sorted(expected.items()):
        mark = "ok " if got.get(name) == want else "BAD"
        print(f"  {mark} {name:28s} {'/'.join(got.get(name, ('-', '-')))}")
    print(f"good or unusual inputs quarantined: {len(wrongly)} {wrongly if wrongly else ''}")
    lost += (len(expected) - right) + len(wrongly)

    same_clips = shard_digests(whole) == shard_digests(alone)
    lost += 0 if same_clips else 1
    clips = [_counts(root / "lineage.duckdb")["clips encoded"] for root in (whole, alone)]
    print(f"good clips: batch {clips[0]}, good-only run {clips[1]}; shards byte-identical: {same_clips}")

    print(f"faults injected: {len(kills)} SIGKILLs, then one run to the end (exit {resumed.returncode})")
    for fault, killed in kills:
        print(f"  {fault:10s} {'killed' if killed else 'NOT KILLED'}")
    lost += sum(1 for _, killed in kills if not killed)
    want, have = _counts(whole / "lineage.duckdb"), _counts(crashed / "lineage.duckdb")
    print(f"{'rows and clips':22s} {'expected':>9s} {'found':>7s} {'lost':>5s} {'extra':>6s}")
    for name in COUNTS:
        print(f"{name:22s} {want[name]:9d} {have[name]:7d} {max(0, want[name] - have[name]):5d} "
              f"{max(0, have[name] - want[name]):6d}")
    for table, sql in ROWS.items():
        a, b = set(_query(whole / "lineage.duckdb", sql)), set(_query(crashed / "lineage.duckdb", sql))
        lost += len(a - b) + len(b - a)
        if a != b:
            print(f"  {table}: {len(a - b)} rows missing, {len(b - a)} rows extra")
    files_same = _files(whole) == _files(crashed)
    shards_same = shard_digests(whole) == shard_digests(crashed)
    problems = lineage_problems(crashed / "lineage.duckdb")
    lost += (0 if files_same and shards_same else 1) + sum(problems.values())
    print(f"after the kills: shards byte-identical {shards_same}, clip and shard files identical {files_same}, "
          f"integrity problems {problems or 'none'}")
    print(f"lost: {lost}   ({time.perf_counter() - t0:.0f} s{f', kept for a look: {work}' if lost else ''})")
    if not lost:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
