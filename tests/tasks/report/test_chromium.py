"""The report page in a real browser: headless Chromium (Debian's `chromium`, which `make test`
installs when it is missing) renders it to a screenshot that is not blank, and logs no console
message (the page has no scripts, so any console line is an error: a blocked resource, an
uncaught exception). A page with a deliberate error checks that such lines are seen at all.
Skipped, with the reason, where no Chromium is on PATH."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tasks.report import write_report

BROWSER = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.slow,  # another process, a browser: an integration test (tests/conftest.py), not in make test-fast
    pytest.mark.skipif(BROWSER is None, reason="no `chromium` on PATH: `make test` installs Debian's chromium "
                       "(apt-get install -y chromium) where apt-get may; without it the page is not rendered in a browser"),
]
# How Chromium logs a page's console output with --enable-logging=stderr:
# [pid:tid:time:INFO:CONSOLE:1] "Uncaught ReferenceError: ...", source: file:///... (1)
CONSOLE = re.compile(r":CONSOLE[^\]]*\]\s*(.*)")


def render(page: Path, tmp_path: Path, size: str = "1280,2000") -> tuple[Image.Image, list[str]]:
    """(screenshot, console lines and other page errors) of ``page`` in headless Chromium."""
    shot = tmp_path / f"{page.stem}.png"
    command = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", f"--window-size={size}",
               "--enable-logging=stderr", "--v=0", page.resolve().as_uri()]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stderr.splitlines()
    errors = [m[1] for line in lines if (m := CONSOLE.search(line))]
    errors += [line for line in lines if "Uncaught" in line and not CONSOLE.search(line)]
    assert shot.is_file() and shot.stat().st_size > 0, f"no screenshot; stderr: {done.stderr[-2000:]}"
    image = Image.open(shot)
    image.load()
    return image, errors


def test_chromium_renders_the_run_page_without_console_errors(lineage, tmp_path):
    page = write_report(lineage.warehouse, lineage.curate_run, tmp_path / "run.html")
    image, errors = render(page, tmp_path)
    assert errors == []
    assert image.size == (1280, 2000)
    pixels = np.asarray(image.convert("RGB"))
    assert pixels.std() > 10 and len(np.unique(pixels.reshape(-1, 3), axis=0)) > 100  # text, plots, frames: not blank
    assert (pixels[:200] < 128).any()  # the title, dark on white, at the top


def test_chromium_renders_the_artifact_page_without_console_errors(lineage, tmp_path):
    image, errors = render(write_report(lineage.warehouse, lineage.shard, tmp_path / "shard.html"), tmp_path)
    assert errors == []
    assert np.asarray(image.convert("L")).std() > 10


def test_console_errors_are_seen(tmp_path):
    """The check above is not blind: a script error and a console.error are both reported."""
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><body><p>x</p><script>console.error("deliberate");'
                   "undefinedFunction();</script></body></html>")
    _, errors = render(bad, tmp_path, "400,300")
    assert any("deliberate" in e for e in errors)
    assert any("Uncaught ReferenceError" in e for e in errors)
