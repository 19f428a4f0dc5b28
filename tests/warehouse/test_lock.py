"""Issue 26, point 6: one writer per data root; a second one waits, then gives up with one line."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from schemas.errors import EXIT_BUSY, Busy
from warehouse import lock

from tests.support import REPO

HOLD = """
import sys, time
from warehouse import lock
with lock.writer(sys.argv[1], 0):
    print("held", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def hold_in_another_process(root: Path, seconds: float) -> subprocess.Popen:
    """A process holding ``root``'s writer lock for ``seconds``; returns once it holds it."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(root), str(seconds)], cwd=REPO, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_reentrant_within_a_process_and_released_at_the_end(tmp_path):
    with lock.writer(tmp_path, 0):
        with lock.writer(tmp_path, 0):  # a nested flow's recorded_run inside the command's hold
            assert lock.holds(tmp_path)
        assert lock.holds(tmp_path)
    assert not lock.holds(tmp_path)
    done = subprocess.run([sys.executable, "-c", HOLD, str(tmp_path), "0"], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "held"  # another process takes it now


def test_a_second_writer_waits_then_is_busy_naming_the_holder(tmp_path):
    holder = hold_in_another_process(tmp_path, 30)
    told = []
    try:
        t0 = time.monotonic()
        with pytest.raises(Busy) as caught:
            with lock.writer(tmp_path, 1.0, on_wait=told.append):
                pass
        waited = time.monotonic() - t0
    finally:
        holder.kill()
        holder.wait()
    message = str(caught.value)
    assert 1.0 <= waited < 5, waited
    assert message.startswith(f"{tmp_path}: another worldline process (pid {holder.pid}, command ")
    assert message.endswith("is writing; waited 1 s (WORLDLINE_LOCK_TIMEOUT)") and "\n" not in message
    assert caught.value.exit_code == EXIT_BUSY == 4
    assert len(told) == 1 and f"pid {holder.pid}" in told[0]


def test_a_writer_that_waits_gets_the_lock_when_the_other_ends(tmp_path):
    holder = hold_in_another_process(tmp_path, 1.0)
    t0 = time.monotonic()
    with lock.writer(tmp_path, 30):
        waited = time.monotonic() - t0
    holder.wait()
    assert 0.3 < waited < 10, waited


def test_a_killed_holder_leaves_the_lock_free(tmp_path):
    holder = hold_in_another_process(tmp_path, 60)
    os.kill(holder.pid, 9)
    holder.wait()
    with lock.writer(tmp_path, 0):
        assert (tmp_path / lock.LOCK_FILE).read_text().startswith(f"pid {os.getpid()}, command ")


def test_a_data_root_that_cannot_be_written_is_the_machines_fault_in_one_line(tmp_path):
    """A read-only root gave an 82-line traceback (PermissionError opening worldline.lock)."""
    from schemas.errors import EXIT_ENVIRONMENT, EnvironmentFault

    taken = tmp_path / "a file"
    taken.write_text("mine\n")
    for root in (taken, taken / "below"):  # mkdir: File exists, Not a directory
        with pytest.raises(EnvironmentFault, match=r"the data root cannot be written \((File exists|Not a directory)\); "
                                                   "WORLDLINE_DATA_ROOT") as caught:
            with lock.writer(root, timeout=1):
                pass
        assert caught.value.exit_code == EXIT_ENVIRONMENT and "\n" not in str(caught.value)
    assert taken.read_text() == "mine\n"
