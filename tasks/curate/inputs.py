"""Find the input videos of a curation batch; anything unusable is reported, never raised."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from schemas.hashing import sha256_file
from tasks.curate.config import VIDEO_SUFFIXES


@dataclass(frozen=True)
class Input:
    path: Path
    sha256: str | None = None
    bytes: int = 0
    problem: str | None = None  # why it cannot be curated; None when it can


def _check(path: Path) -> Input:
    try:
        if path.is_symlink():
            path.resolve(strict=True)  # raises on a loop or a dangling link
        if path.is_dir():
            return Input(path, problem="is a directory, not a video file")
        if not path.exists():
            return Input(path, problem="does not exist")
        if not os.access(path, os.R_OK):
            return Input(path, problem="permission denied: cannot read")
        size = path.stat().st_size
        if size == 0:
            return Input(path, problem="empty file (0 bytes)")
        return Input(path, sha256=sha256_file(str(path)), bytes=size)
    except RuntimeError as exc:  # pathlib reports symlink loops as RuntimeError on 3.11
        return Input(path, problem=f"symlink loop: {exc}")
    except OSError as exc:
        return Input(path, problem=f"cannot read: {exc.strerror or exc}")


def discover(paths: list[str | Path]) -> list[Input]:
    """Files given directly are taken whatever their suffix; folders contribute their videos.

    Sorted by path so batches are processed in the same order every time.
    """
    found: dict[str, Input] = {}
    for raw in paths:
        path = Path(raw)
        if path.is_dir() and not path.name.lower().endswith(VIDEO_SUFFIXES):
            for child in sorted(path.rglob("*")):
                if child.name.lower().endswith(VIDEO_SUFFIXES):
                    found.setdefault(str(child), _check(child))
        else:
            found.setdefault(str(path), _check(path))
    return [found[k] for k in sorted(found)]
