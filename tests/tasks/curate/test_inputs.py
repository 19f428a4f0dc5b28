"""Input discovery and the quarantine reasons, without a flow; and the fault hook itself."""

from __future__ import annotations

import errno
import os
import re
import signal
import subprocess
import sys

import pytest

from schemas.errors import EnvironmentFault
from tasks import faults
from tasks.curate.inputs import changed, damage, decode_reason, discover, find, iso_truncation, same_bytes

from tests.support import REPO, scene_frames, write_video


def test_discover_names_each_unusable_path(tmp_path):
    (tmp_path / "empty.mp4").write_bytes(b"")
    (tmp_path / "x.mp4").mkdir()
    (tmp_path / "loop.mp4").symlink_to("loop.mp4")
    (tmp_path / "dangling.mp4").symlink_to("nowhere.mp4")
    whole = write_video(tmp_path / "whole.mp4", scene_frames(0, n=10)).read_bytes()
    (tmp_path / "cut.mp4").write_bytes(whole[:-100])
    found = {i.path.name: i.reason for i in discover([tmp_path])}
    assert found == {"empty.mp4": "empty", "x.mp4": "directory", "loop.mp4": "symlink_loop", "dangling.mp4": "missing",
                     "cut.mp4": "truncated", "whole.mp4": None}


def test_truncation_is_read_from_box_headers(tmp_path):
    data = write_video(tmp_path / "v.mp4", scene_frames(1, n=10)).read_bytes()
    for size in (len(data) - 1, len(data) // 2, 40):
        with open(tmp_path / "v.mp4", "rb") as handle:
            assert "cut off" in iso_truncation(handle, size)
    with open(tmp_path / "v.mp4", "rb") as handle:
        assert iso_truncation(handle, len(data)) is None
    (tmp_path / "r.bin").write_bytes(b"\x00\x00\x00\x10notaboxatall" * 10)
    with open(tmp_path / "r.bin", "rb") as handle:
        assert iso_truncation(handle, 160) is None  # not an ISO file: left to the decoder


@pytest.mark.parametrize("decode, reason", [
    ({"frames": 40, "corrupt": 0, "missing": 0, "decode_errors": 0, "truncated": False}, None),
    ({"frames": 40, "corrupt": 0, "missing": 0, "decode_errors": 0, "truncated": True}, "truncated"),
    ({"frames": 37, "corrupt": 1, "missing": 2, "decode_errors": 0, "truncated": False}, "corrupt_frames"),
    ({"frames": 39, "corrupt": 0, "missing": 0, "decode_errors": 1, "truncated": False}, "corrupt_frames"),
    ({"frames": 1, "corrupt": 0, "missing": 0, "decode_errors": 0, "truncated": False}, "single_frame"),
])
def test_damage(decode, reason):
    got = damage(decode)
    assert (got and got[0]) == reason


def test_decode_reasons():
    assert decode_reason("/x.mp4: no video stream") == "no_video_stream"
    assert decode_reason("/x.mp4: absurd frame size 0x0") == "absurd_frame_size"
    assert decode_reason("/x.mp4: absurd or missing frame rate 10000") == "absurd_frame_rate"
    assert decode_reason("/x.mp4: not a readable video (Invalid data)") == "unreadable"


def _point_twice(spec: str) -> subprocess.CompletedProcess:
    code = "from tasks import faults; faults.point('here'); print('one', flush=True); faults.point('here'); print('two')"
    return subprocess.run([sys.executable, "-c", code], env={"WORLDLINE_FAULT": spec, "PYTHONPATH": str(REPO)},
                          capture_output=True, text=True, cwd=REPO, timeout=60)


def test_fault_point_kills_at_the_named_hit_only():
    assert faults.parse("shard:3") == ("shard", 3, "kill") and faults.parse("shard") == ("shard", 1, "kill")
    assert faults.parse("") is None
    first, second, other = _point_twice("here"), _point_twice("here:2"), _point_twice("elsewhere")
    assert first.returncode == -signal.SIGKILL and first.stdout == ""
    assert second.returncode == -signal.SIGKILL and second.stdout == "one\n"
    assert other.returncode == 0 and other.stdout == "one\ntwo\n"


def test_an_injected_full_disk_raises_from_the_named_hit_on(monkeypatch, tmp_path):
    assert faults.parse("enospc@shard:2") == ("shard", 2, "enospc")
    with pytest.raises(ValueError, match="unknown fault kind 'boom'"):
        faults.parse("boom@shard")
    faults.reset()
    monkeypatch.setenv(faults.ENV, "enospc@here:2")
    faults.point("here", tmp_path / "a")
    faults.point("elsewhere")
    for _ in range(2):  # a full disk stays full
        with pytest.raises(OSError) as caught:
            faults.point("here", tmp_path / "a")
        assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(tmp_path / "a")


def test_a_full_disk_is_the_machines_fault_and_other_errors_pass(tmp_path):
    with pytest.raises(EnvironmentFault, match=r"^/x/bad\\xff\.mp4: disk full while testing$") as caught:
        with faults.fatal_when_disk_full(os.fsdecode(b"/x/bad\xff.mp4"), "testing"):
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
    assert caught.value.exit_code == 5 and isinstance(caught.value.__cause__, OSError)
    with pytest.raises(PermissionError):
        with faults.fatal_when_disk_full(tmp_path, "testing"):
            raise PermissionError(errno.EACCES, "Permission denied")
    assert faults.disk_full(ValueError("no"), tmp_path, "testing") is None


def test_a_place_under_the_data_root_that_cannot_be_written_is_the_machines_fault(tmp_path):
    root, outside = tmp_path / "root", tmp_path / "inputs" / "a.mp4"
    for error in (PermissionError(errno.EACCES, "Permission denied", str(root / "clips" / "1f")),
                  OSError(errno.EROFS, "Read-only file system", str(root / "x.tmp")),
                  FileExistsError(errno.EEXIST, "File exists", str(root / "shards" / "abc"))):
        fault = faults.unwritable(error, root, "testing")
        assert fault is not None and fault.exit_code == 5 and str(fault).startswith(f"{error.filename}: ")
        assert str(fault).endswith(f"while testing; the data root {root} must be a folder this user can write")
    assert faults.unwritable(PermissionError(errno.EACCES, "Permission denied", str(outside)), root, "x") is None
    assert faults.unwritable(PermissionError(errno.EACCES, "Permission denied"), root, "x") is None  # names nothing
    assert faults.unwritable(OSError(errno.EIO, "I/O error", str(root / "a")), root, "x") is None
    # an error without a file (PyAV's) is given the file written, and so found under the root
    with pytest.raises(EnvironmentFault, match=rf"^{re.escape(str(root))}/c\.tmp: Permission denied while writing"):
        with faults.fatal_when_disk_full(root / "c.tmp", "writing", root):
            raise PermissionError(errno.EACCES, "Permission denied")
    with pytest.raises(PermissionError) as caught:  # without the root: named, passed on
        with faults.fatal_when_disk_full(root / "c.tmp", "writing"):
            raise PermissionError(errno.EACCES, "Permission denied")
    assert caught.value.filename == str(root / "c.tmp")


def test_a_walked_folder_leaves_out_the_data_roots_outputs_unless_it_is_inside_them(tmp_path):
    from schemas.paths import output_folders

    root = tmp_path / ".worldline"
    for name in ("raw/a.mp4", ".worldline/clips/1f/c.mp4", ".worldline/episodes/e/side.mp4",
                 ".worldline/corpus/seed_000001/raw_0000.mp4"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"x")
    skip = output_folders(root)
    assert "corpus" not in {p.name for p in skip} and root / "clips" in skip
    assert find([tmp_path], skip) == [tmp_path / ".worldline/corpus/seed_000001/raw_0000.mp4", tmp_path / "raw/a.mp4"]
    assert find([root / "episodes"], skip) == [root / "episodes/e/side.mp4"]  # walked from inside: taken
    assert find([root / "clips/1f/c.mp4"], skip) == [root / "clips/1f/c.mp4"]  # named: taken
    assert len(find([tmp_path])) == 4


def test_the_same_bytes_are_one_input_named_by_a_regular_file_first(tmp_path):
    (tmp_path / "b.mp4").write_bytes(b"same")
    (tmp_path / "c.mp4").write_bytes(b"same")
    (tmp_path / "a.mp4").symlink_to(tmp_path / "b.mp4")
    (tmp_path / "d.mp4").write_bytes(b"other")
    found = [i for i in discover([tmp_path]) if i.sha256]
    assert len(found) == 4
    once = same_bytes(found)
    assert [(i.path.name, i.other_names) for i in once] == [
        ("b.mp4", (str(tmp_path / "a.mp4"), str(tmp_path / "c.mp4"))), ("d.mp4", ())]
    assert once[0].attrs == {"other_names": [str(tmp_path / "a.mp4"), str(tmp_path / "c.mp4")]} and once[1].attrs == {}


def test_a_file_changed_since_it_was_hashed_is_said_to_have_changed(tmp_path):
    video = tmp_path / "a.mp4"
    video.write_bytes(b"first")
    item, = discover([video])
    assert item.stamp == (5, video.stat().st_mtime_ns) and changed(item) is None
    video.write_bytes(b"second!")
    reason, detail = changed(item)
    assert reason == "changed" and detail.startswith("changed while being curated (5 bytes when it was hashed, 7 now")
    video.unlink()
    assert changed(item)[1].startswith("changed while being curated: it cannot be read any more")
