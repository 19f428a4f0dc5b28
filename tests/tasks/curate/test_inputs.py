"""Input discovery and the quarantine reasons, without a flow; and the fault hook itself."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys

import pytest

from schemas.errors import EnvironmentFault
from tasks import faults
from tasks.curate.inputs import damage, decode_reason, discover, iso_truncation

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
