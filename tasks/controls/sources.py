"""What `worldline controls` makes controls of: a video file, an episode folder (each camera's
video), or a folder of videos; and where each one's control files go."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from schemas import paths
from tasks.controls.check import ControlError
from tasks.curate.config import VIDEO_SUFFIXES
from tasks.video.read import DecodeError, probe

OUTPUTS = tuple(f".{c}" for c, suffix in paths.CONTROL_SUFFIX.items() if suffix == "mp4")  # ".edges", ".blur"


@dataclass(frozen=True)
class Source:
    """A video and where its controls go: ``folder/{name}.{control}.mp4``."""

    video: Path
    folder: Path
    name: str
    camera: str | None = None  # an episode's camera
    manifest_hash: str | None = None  # an episode's manifest


def _episode(folder: Path, out: Path | None) -> list[Source]:
    meta = json.loads((folder / Path(paths.EPISODE_META).name).read_text())
    into = out if out is not None else folder / paths.CONTROLS_DIR
    return [Source(folder / paths.CAMERA_VIDEO.format(camera=c), into, c, c, meta.get("manifest_hash"))
            for c in sorted(meta["cameras"])]


def find_sources(path: Path | str, out: Path | str | None = None,
                 problems: list[str] | None = None) -> list[Source]:
    """The videos under ``path``, each probed; ControlError in one line for a path that is not
    a video, an episode folder or a folder holding videos. Given ``problems``, a folder's video
    that does not probe is left out and named there (one line each) instead: a batch goes on
    without it. A video named by itself is always refused."""
    path, out = Path(path), (Path(out) if out is not None else None)
    if not path.exists():
        raise ControlError(f"{path}: no such file or folder")
    if path.is_dir() and (path / Path(paths.EPISODE_META).name).is_file():
        found = _episode(path, out)
    elif path.is_dir():
        videos = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES
                        and not p.stem.endswith(OUTPUTS))
        if not videos:
            raise ControlError(f"{path}: no videos there ({' '.join(VIDEO_SUFFIXES)}), and not an episode folder")
        found = [Source(v, out if out is not None else path, v.stem) for v in videos]
    else:
        found = [Source(path, out if out is not None else path.parent, path.stem)]
    readable = []
    for source in found:
        try:
            probe(source.video)
        except DecodeError as exc:
            if problems is None or not path.is_dir():
                raise ControlError(str(exc)) from None
            problems.append(str(exc))
            continue
        readable.append(source)
    if not readable:
        raise ControlError(f"{path}: no readable video there ({problems[0] if problems else 'none found'})")
    return readable
