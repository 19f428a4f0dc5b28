"""The curate flow's inputs on disk as a hostile user leaves them: the same video under several
names (a copy, a symlink), a folder that holds the data root itself, and a video overwritten
while it is being curated (its clips once carried the new bytes' frames under the old bytes'
sha256 in lineage)."""

import os
import shutil
from pathlib import Path

import av
import pytest
from prefect import task

import flows.curate
from flows.curate import curate
from tasks.curate.encode import encode_clips
from warehouse.store import Warehouse

from tests.support import good_videos, lineage_problems


def _rows(root: Path, sql: str) -> list[tuple]:
    with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
        return wh.query(sql)[1]


def test_the_same_bytes_under_several_names_are_curated_once_under_the_real_file(prefect_harness, tmp_path,
                                                                                 data_root):
    inbox = tmp_path / "inbox"
    good, = good_videos(inbox, seeds=(0,))
    shutil.copyfile(good, inbox / "a_copy.mp4")
    (inbox / "z_link.mp4").symlink_to(good)
    (inbox / "0_link.mp4").symlink_to(good)  # sorts first, but a symlink: not the name kept
    result = curate([str(inbox)])
    assert result["status"] == "completed" and result["failed"] == 0 and result["clips"] >= 1, result
    (uri, names), = _rows(data_root, "SELECT uri, attrs->'other_names' FROM artifacts WHERE kind = 'raw_video'")
    assert uri == str(inbox / "a_copy.mp4")  # regular files first, then by path
    assert sorted(eval(names)) == sorted(str(inbox / n) for n in ("0_link.mp4", "good_0.mp4", "z_link.mp4"))
    assert lineage_problems(data_root / "lineage.duckdb") == {}


def test_a_folder_that_holds_the_data_root_is_curated_without_the_data_roots_videos(prefect_harness, tmp_path,
                                                                                   monkeypatch):
    inbox = tmp_path / "inbox"
    good_videos(inbox, seeds=(0, 2))
    root = inbox / ".worldline"
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(root))
    first = curate([str(inbox)])
    assert first["inputs"] == 2 and first["clips"] >= 2 and list((root / "clips").rglob("*.mp4"))
    again = curate([str(inbox)])  # its own clips were taken as inputs: "0 of 3", then "0 of 4"
    assert again["inputs"] == 2 and again["failed"] == 0 and again["clips"] == first["clips"], again
    uris = [u for u, in _rows(root, "SELECT uri FROM artifacts WHERE kind = 'raw_video'")]
    assert sorted(uris) == sorted(str(inbox / f"good_{s}.mp4") for s in (0, 2))


@pytest.mark.parametrize("when", ["after_analysis", "while_encoding"])
def test_a_video_overwritten_while_it_is_curated_keeps_no_clip_from_the_new_bytes(prefect_harness, tmp_path,
                                                                                  data_root, monkeypatch, when):
    inbox, spare = tmp_path / "inbox", tmp_path / "spare"
    good_videos(inbox, seeds=(0,))
    victim = good_videos(inbox, seeds=(2,))[0].rename(inbox / "victim.mp4")
    other, = good_videos(spare, seeds=(3,))

    done = []

    def overwrite():  # once: the re-run below sees the new bytes from the start
        if done:
            return
        done.append(True)
        victim.write_bytes(other.read_bytes())
        os.utime(victim, ns=(victim.stat().st_atime_ns, victim.stat().st_mtime_ns + 10**9))  # even on a coarse clock

    if when == "after_analysis":
        dedup = flows.curate.deduplicate
        monkeypatch.setattr(flows.curate, "deduplicate", lambda *a: (overwrite(), dedup(*a))[1])
    else:
        def encode_then_overwrite(source, *args, **kwargs):
            out = encode_clips(source, *args, **kwargs)
            if Path(source) == victim:
                overwrite()
            return out

        monkeypatch.setattr(flows.curate, "encode_video", task(encode_then_overwrite, name="encode-clips"))
    result = curate([str(inbox)])
    assert result["status"] == "partial" and result["failed"] == 1 and result["clips"] >= 1, result
    (message,), = _rows(data_root, "SELECT message FROM runs")
    assert message == "partial: 1 of 2 inputs failed"
    sources = {u for u, in _rows(data_root, "SELECT DISTINCT r.uri FROM artifacts c JOIN edges e ON e.child_id = "
                                            "c.artifact_id JOIN artifacts r ON r.artifact_id = e.parent_id "
                                            "WHERE c.kind = 'clip' AND c.uri IS NOT NULL")}
    assert sources == {str(inbox / "good_0.mp4")}  # no clip file recorded from the victim
    clip_files = sorted((data_root / "clips").rglob("*.mp4"))
    recorded = {u for u, in _rows(data_root, "SELECT uri FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL")}
    assert {str(p.relative_to(data_root)) for p in clip_files} <= recorded | {str(p) for p in clip_files}
    for path in clip_files:  # every clip file left on disk is one lineage records
        assert str(path) in recorded or str(path.relative_to(data_root)) in recorded, path
        with av.open(str(path)) as clip:
            assert clip.streams.video[0].frames > 0
    again = curate([str(inbox)])  # the new bytes are a new video: curated in full
    assert again["failed"] == 0 and again["status"] == "completed", again


def test_a_video_renamed_between_runs_is_encoded_from_its_new_name(prefect_harness, tmp_path, data_root):
    """Its analysis comes from the cache (same bytes); the clips in it named the old path, so an
    encode the first run had not made (another crf here) opened a file that was gone."""
    inbox = tmp_path / "inbox"
    good, = good_videos(inbox, seeds=(0,))
    assert curate([str(inbox)])["status"] == "completed"
    good.rename(inbox / "renamed.mp4")
    config = tmp_path / "crf.yaml"
    config.write_text("encode: {crf: 30}\n")
    again = curate([str(inbox)], config=str(config))
    assert again["status"] == "completed" and again["failed"] == 0 and again["clips"] >= 1, again
