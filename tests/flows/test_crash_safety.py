"""Issue 5: SIGKILL the curate command at its crash points, run it again, and lose nothing;
issue 26: a full disk stops the run naming the file, blames no input, leaves no temporary.

One folder (three good videos and one unreadable file) is curated without interruption in
this process, and in a second data root by ``worldline curate`` processes that are killed in
turn while a video decodes, while a clip and then a shard sit complete in their temporary
files, and inside a lineage transaction (tasks/faults.py). Each run resumes from what the
killed one left. The last run must give byte-identical shards and the same lineage rows, with
no duplicate or orphan row and no stray file.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
from pathlib import Path

import pytest

from schemas.errors import EnvironmentFault
from tasks import faults
from tasks.curate.shards import SWEPT_FOLDERS
from warehouse.store import Warehouse

from tests.support import curate_command, good_videos, lineage_problems, sha256_of, shard_digests

# Crash points in the order one run after another reaches them (tasks/faults.py); "lineage:3" is
# the shard batch: the 3rd write of a run that finds analyses and clips done (quarantine, dedup, shard).
KILLS = ("decode:2", "clip:1", "shard:1", "lineage:3")
TABLES = {
    "artifacts": "SELECT artifact_id, kind, uri, sha256 FROM artifacts ORDER BY ALL",
    "edges": "SELECT parent_id, child_id, relation FROM edges ORDER BY ALL",
    "rejections": "SELECT artifact_id, stage, reason FROM rejections ORDER BY ALL",
    "ancestry": "SELECT descendant_id, ancestor_id, depth FROM ancestry ORDER BY ALL",
    "stage_runs": "SELECT stage_run_id, stage, status, n_in, n_out FROM stage_runs ORDER BY ALL",
}


@pytest.fixture(scope="module")
def inbox(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("crash_inbox")
    good_videos(folder, seeds=(0, 2))
    (folder / "broken.mp4").write_bytes(b"\x00not a video" * 200)
    return folder


def _tables(db: Path) -> dict[str, list[tuple]]:
    with Warehouse(db, read_only=True) as wh:
        return {name: wh.query(sql)[1] for name, sql in TABLES.items()}


def _final_files(root: Path) -> dict[str, str]:
    """Every clip and shard under its final name (temporaries start with a dot)."""
    return {p.relative_to(root).as_posix(): sha256_of(p) for folder in ("clips", "shards") if (root / folder).is_dir()
            for p in (root / folder).rglob("*") if p.is_file() and not p.name.startswith(".")}


def test_killed_runs_resume_to_identical_shards_and_clean_lineage(prefect_harness, inbox, data_root, tmp_path):
    from prefect.settings import PREFECT_API_URL

    from flows.curate import curate

    reference = curate([str(inbox)])
    assert reference["status"] == "partial" and reference["clips"] >= 1
    want_files, want_rows = _final_files(data_root), _tables(data_root / "lineage.duckdb")

    root = tmp_path / "crashing"
    for fault in KILLS:
        done = curate_command([inbox], root, fault=fault, api_url=PREFECT_API_URL.value())
        assert done.returncode == -signal.SIGKILL, (fault, done.returncode, done.stderr[-2000:])
        files = _final_files(root)
        # Written atomically: whatever has its final name is whole, and the same bytes as uninterrupted.
        assert all(want_files.get(rel) == digest for rel, digest in files.items()), fault
        if fault.startswith("shard"):
            assert any(p.name.startswith(".") for p in (root / "shards").rglob("*.tmp")), "no shard was in flight"
        if fault.startswith("lineage"):  # killed inside the shard batch's transaction: files yes, rows no
            assert any(rel.startswith("shards/") for rel in files)
            with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
                assert wh.query("SELECT count(*) FROM artifacts WHERE kind = 'shard'")[1] == [(0,)]

    done = curate_command([inbox], root, api_url=PREFECT_API_URL.value())
    assert done.returncode == 1 and "partial" in done.stdout, done.stderr[-2000:]
    assert shard_digests(root) == shard_digests(data_root)
    assert _final_files(root) == want_files
    assert _tables(root / "lineage.duckdb") == want_rows
    assert lineage_problems(root / "lineage.duckdb") == {}
    with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
        runs = wh.query("SELECT status, message FROM runs ORDER BY started_at")[1]
    assert [s for s, _ in runs] == ["failed"] * len(KILLS) + ["partial"]
    assert all("interrupted" in m for _, m in runs[:-1])


# -- a full disk (issue 26) --------------------------------------------------------------------
def _temporaries(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for folder in SWEPT_FOLDERS if (root / folder).is_dir()
                  for p in (root / folder).rglob("*") if p.name.startswith("."))


def _after_a_full_disk(root: Path, stage: str) -> None:
    """What a run stopped by a full disk leaves: no temporary, only the broken input quarantined
    (the good ones were not at fault), and the run failed with the one-line reason."""
    assert _temporaries(root) == []
    with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
        rejected = wh.query("SELECT a.uri FROM rejections r JOIN artifacts a USING (artifact_id) WHERE a.kind = 'raw_video'")[1]
        (status, message), = wh.query("SELECT status, message FROM runs")[1]
    assert [Path(uri).name for uri, in rejected] == ["broken.mp4"]
    assert status == "failed" and message.endswith(f": disk full while {stage}"), message


@pytest.mark.parametrize("point, stage", [("analysis", "saving the analysis"), ("clip", "encoding clips"),
                                          ("shard", "writing shards")])
def test_a_full_disk_stops_the_run_naming_the_file_and_blames_no_input(point, stage, prefect_harness, inbox, data_root,
                                                                       monkeypatch):
    """A full disk once ended curate with "1 of 1 inputs quarantined" and no reason (or a Prefect
    500), and left a temporary behind."""
    from flows.curate import curate

    faults.reset()
    monkeypatch.setenv(faults.ENV, f"enospc@{point}")
    with pytest.raises(EnvironmentFault, match=rf"^{re.escape(str(data_root))}/\S+\.tmp: disk full while {stage}$"):
        curate([str(inbox)])
    _after_a_full_disk(data_root, stage)


@pytest.mark.parametrize("folder, stage", [("clips", "encoding clips"), ("shards/unscoped", "writing shards")])
def test_a_file_where_a_data_root_folder_belongs_stops_the_run_and_blames_no_input(folder, stage, prefect_harness,
                                                                                   inbox, data_root):
    """A folder of the data root that cannot be written once quarantined every input ("2 of 2
    inputs failed") or ended in a traceback after all the work; it is the machine's fault, one
    line. Files where the layout's next folders belong fail their mkdir as they would for any user."""
    from flows.curate import curate

    place = data_root / folder
    place.mkdir(parents=True)
    names = [f"{i:02x}" for i in range(256)] if folder == "clips" else ["lt240p", *(f"{r}p" for r in (240, 360, 480, 720))]
    for name in names:
        (place / name).write_text("mine\n")
    with pytest.raises(EnvironmentFault, match=rf"^{re.escape(str(place))}/\S+: (File exists|Not a directory) while {stage}; the data "
                                               rf"root {re.escape(str(data_root))} must be a folder this user can write$"):
        curate([str(inbox)])
    assert _temporaries(data_root) == [] and all((place / name).read_text() == "mine\n" for name in names)
    with Warehouse(data_root / "lineage.duckdb", read_only=True) as wh:
        rejected = wh.query("SELECT a.uri FROM rejections r JOIN artifacts a USING (artifact_id) WHERE a.kind = 'raw_video'")[1]
        (status, message), = wh.query("SELECT status, message FROM runs")[1]
    assert [Path(uri).name for uri, in rejected] == ["broken.mp4"] and status == "failed", (rejected, message)


@pytest.mark.parametrize("folder, stage", [("clips", "encoding clips"), ("shards", "writing shards")])
def test_a_real_full_disk_under_a_small_tmpfs(folder, stage, prefect_harness, inbox, data_root):
    """The same on a real 4 kB file system (clips or shards on it; lineage beside it). Needs root
    and a kernel that lets it mount tmpfs here: skipped otherwise."""
    from flows.curate import curate

    mount = data_root / folder
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4k", "tmpfs", str(mount)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here (not root, or not allowed)")
    try:
        with pytest.raises(EnvironmentFault, match=rf"^{re.escape(str(mount))}/\S+: disk full while {stage}$"):
            curate([str(inbox)])
        _after_a_full_disk(data_root, stage)
    finally:  # lazily when a file there is still open: never leave the mount behind
        if subprocess.run(["umount", str(mount)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mount)], check=True)
