"""Issue 26, point 5: a command ends promptly on SIGINT and SIGTERM, and leaves no process behind.

Each test runs the real ``worldline simulate`` in a session of its own, with its own data root
and Prefect's temporary server, waits until episodes are being written, and signals it:
SIGINT to the whole process group (what Ctrl-C in a terminal does), SIGTERM to the command,
SIGTERM to the group, SIGKILL to the command. Before issue 26 a Ctrl-C took 3 to 3.5 minutes
(the server died first and the command retried it) and ended with exit 1; a SIGTERM or SIGKILL
left the server listening.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from warehouse.store import Warehouse

from tests.support import REPO, small_manifest

START_TIMEOUT_S = 300  # Prefect's temporary server takes 10-40 s to start on a busy two-core machine
EXIT_WITHIN_S = 10.0


def processes_of(root: Path) -> list[str]:
    """'pid command' of every process whose environment names this data root (the command and
    whatever it started, the temporary Prefect server included), found in /proc."""
    marker = f"WORLDLINE_DATA_ROOT={root}\0".encode()
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if marker in Path(f"/proc/{pid}/environ").read_bytes():
                command = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                found.append(f"{pid} {command[:160]}")
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return found


def _finished(root: Path) -> int:
    return len(list((root / "episodes").rglob("meta.json")))


def _start(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    root = tmp_path / "root"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("WORLDLINE_", "PREFECT_"))}
    env |= {"WORLDLINE_DATA_ROOT": str(root), "PYTHONDONTWRITEBYTECODE": "1"}
    command = [str(REPO / ".venv" / "bin" / "worldline"), "simulate", str(small_manifest(tmp_path)),
               "--episodes", "500"]
    # As a terminal starts it: SIGINT not ignored. A suite launched in the background by a shell
    # without job control (`cmd &` in a script) ignores SIGINT, and children inherit that.
    proc = subprocess.Popen(command, env=env, cwd=REPO, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + START_TIMEOUT_S
    while _finished(root) < 3:  # the flow is running and recording episodes
        assert proc.poll() is None, proc.stdout.read()[-3000:]
        assert time.monotonic() < deadline, "simulate did not start writing episodes"
        time.sleep(0.2)
    return proc, root


@pytest.mark.slow
@pytest.mark.parametrize("how, code", [("SIGINT to the group", 130), ("SIGTERM", 143), ("SIGTERM to the group", 143)])
def test_an_interrupted_command_ends_within_seconds_recording_what_it_finished(tmp_path, how, code):
    proc, root = _start(tmp_path)
    sig = signal.SIGINT if "SIGINT" in how else signal.SIGTERM
    finished_before = _finished(root)
    sent = time.monotonic()
    (os.killpg if "group" in how else os.kill)(proc.pid, sig)
    try:
        output, _ = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    took = time.monotonic() - sent
    assert proc.returncode == code, output[-3000:]
    assert took < EXIT_WITHIN_S, f"{how}: exited {took:.1f} s after the signal"
    assert "Traceback" not in output, output[-3000:]
    said = [line for line in output.splitlines() if line.strip()]  # what it surfaced as is not the last word
    assert said and (said[-1] == f"interrupted by {sig.name}" or said[-1].endswith("stopping now")), output[-3000:]
    assert "Query interrupted" not in output, output[-3000:]
    time.sleep(0.5)  # the server notices its parent's exit within POLL_S
    assert processes_of(root) == []

    with Warehouse(root / "lineage.duckdb", read_only=True) as wh:
        runs = wh.query("SELECT status, message FROM runs")[1]
        recorded = wh.query("SELECT count(*) FROM stage_runs WHERE stage = 'simulate'")[1][0][0]
        files = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'episode'")[1][0][0]
    assert runs == [("failed", f"interrupted by {sig.name}")]
    # every episode finished by the signal is in lineage (two may have been finishing as it came)
    assert recorded == files and recorded >= finished_before - 2 and recorded >= 1
    assert recorded <= _finished(root)


@pytest.mark.slow
def test_a_killed_command_leaves_no_temporary_server_behind(tmp_path):
    proc, root = _start(tmp_path)
    assert len(processes_of(root)) >= 2, "the command and its temporary Prefect server"
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    deadline = time.monotonic() + 5
    while processes_of(root) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert processes_of(root) == []


def test_after_a_signal_the_command_leaves_without_waiting_for_its_worker_threads():
    """A task still running in a worker thread (native code, in simulate) neither delays nor
    crashes the exit once the command has ended after a signal; without a signal, nothing changes."""
    script = ("import threading, time\n"
              "import flows.ephemeral as e\n"
              "threading.Thread(target=time.sleep, args=(30,)).start()\n"
              "e.leave_after_signal(143)\n"
              "e._first_signal = 15\n"
              "e.leave_after_signal(143)\n"
              "print('not reached')\n")
    started = time.monotonic()
    done = subprocess.run([str(REPO / ".venv" / "bin" / "python"), "-c", script], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 143 and "not reached" not in done.stdout, done.stderr[-2000:]
    assert time.monotonic() - started < 20
