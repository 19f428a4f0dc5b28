"""`worldline controls`: edge and blur controls of videos (docs/transfer.md)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import typer

from flows.cli_command import command
from flows.cli_shell import app, fail, out, say, writing
from schemas.errors import EXIT_PARTIAL
from flows.params_data import ControlsParams


def check_out(folder: str) -> None:
    """Refuse, in one line naming --out, a folder that is not one or cannot be made, before any
    work; nothing is left behind (a folder made to try it is removed at once)."""
    path = Path(folder)
    if os.path.lexists(path) and not path.is_dir():
        fail(f"--out {folder}: exists and is not a folder")
    base = path
    while not os.path.lexists(base) and base != base.parent:  # the nearest part that exists
        base = base.parent
    if not base.is_dir():
        fail(f"--out {folder}: cannot be created: {base} is not a folder")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".worldline-out-", dir=base))
    except OSError as exc:
        what = "cannot be written" if base == path else f"cannot be created in {base}"
        fail(f"--out {folder}: {what}: {exc.strerror}")


@command(app, ControlsParams)
def controls(params: ControlsParams) -> None:
    """Edge (Canny) and blur controls of a video, an episode's cameras or a folder of videos, as
    MP4s beside each video (an episode's in its controls/ folder) or under --out (Prefect flow
    `controls`); what is not a video is refused in one line."""
    from tasks.controls.check import ControlError
    from tasks.controls.sources import find_sources

    if params.out is not None:
        check_out(params.out)
    try:
        find_sources(params.source, params.out, problems=[])  # a folder's unreadable videos: named by the flow
    except ControlError as exc:
        fail(str(exc))
    from flows.controls import controls as controls_flow

    writing()
    result = controls_flow(**params.model_dump())
    for problem in result["failed"]:
        say(problem)
    out.print(f"{result['videos']} videos, {result['new']} given controls: {len(result['written'])} files written"
              + (f"; {len(result['failed'])} not readable, left out" if result["failed"] else ""), highlight=False)
    if result["failed"]:
        raise typer.Exit(EXIT_PARTIAL)
