"""Find the input videos of a curation batch and say, precisely, why one cannot be curated.

Nothing here raises on a bad input: ``discover`` reports unusable paths (``Input.problem``
and a short ``Input.reason``), ``decode_reason`` names what a DecodeError was about, and
``damage`` decides whether a decoded video is too damaged to curate. Each reason ends up in
the ``rejections`` table of the quarantined input.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, replace
from pathlib import Path

from schemas.hashing import sha256_file
from tasks import faults
from tasks.curate.config import VIDEO_SUFFIXES


@dataclass(frozen=True)
class Input:
    path: Path
    sha256: str | None = None
    bytes: int = 0
    problem: str | None = None  # why it cannot be curated; None when it can
    reason: str | None = None  # the problem as a short code (rejections.reason)
    stamp: tuple[int, int] | None = None  # (size, mtime in ns) when it was hashed
    other_names: tuple[str, ...] = ()  # other paths given with the same bytes (``same_bytes``)

    @property
    def attrs(self) -> dict:
        """What its raw_video artifact records of it beyond the path and the bytes."""
        return {"other_names": list(self.other_names)} if self.other_names else {}


def _stamp(path: Path) -> tuple[int, int]:
    status = path.stat()
    return status.st_size, status.st_mtime_ns


def changed(item: Input) -> tuple[str, str] | None:
    """(reason, detail) when the file at ``item.path`` is no longer the one hashed (its size or
    modification time moved): what was analysed or encoded from it may not be those bytes."""
    if item.stamp is None:
        return None
    try:
        now = _stamp(item.path)
    except OSError as exc:
        return "changed", f"changed while being curated: it cannot be read any more ({exc.strerror or exc})"
    if now == item.stamp:
        return None
    return "changed", (f"changed while being curated ({item.stamp[0]} bytes when it was hashed, {now[0]} now, "
                       "modified since); its clips are not kept: curate it again once it is complete")


def same_bytes(found: list[Input]) -> list[Input]:
    """One input per content: the same bytes under several names are curated once, under the
    name of a regular file before a symlink's (then the first by path), with the others in
    ``other_names``. Inputs without a hash pass through."""
    groups: dict[str, list[Input]] = {}
    out = []
    for item in found:
        if item.sha256 is None:
            out.append(item)
        else:
            groups.setdefault(item.sha256, []).append(item)
    for group in groups.values():
        group.sort(key=lambda i: (i.path.is_symlink(), str(i.path)))
        out.append(replace(group[0], other_names=tuple(sorted(str(i.path) for i in group[1:]))))
    return sorted(out, key=lambda i: str(i.path))


def _bad(path: Path, reason: str, problem: str) -> Input:
    return Input(path, problem=problem, reason=reason)


def _check(path: Path) -> Input:
    try:
        if path.is_symlink():
            path.resolve(strict=True)  # raises on a loop or a dangling link
        if path.is_dir():
            return _bad(path, "directory", "is a directory, not a video file")
        if not path.exists():
            return _bad(path, "missing", "does not exist")
        if not path.is_file():
            return _bad(path, "not_a_file", "not a regular file (a device, pipe or socket)")
        if not os.access(path, os.R_OK):  # root may read anything: then the open below decides
            return _bad(path, "permission_denied", "permission denied: cannot read")
        size = path.stat().st_size
        if size == 0:
            return _bad(path, "empty", "empty file (0 bytes)")
        with open(path, "rb") as handle:  # opening, not os.access, is what proves we may read
            cut = iso_truncation(handle, size)
        if cut:
            return _bad(path, "truncated", cut)
        before = _stamp(path)
        digest = sha256_file(str(path))
        if _stamp(path) != before:
            return _bad(path, "changing", "changed while it was read (still being written?); "
                        "curate it once it is complete")
        return Input(path, sha256=digest, bytes=before[0], stamp=before)
    except RuntimeError as exc:  # pathlib reports symlink loops as RuntimeError on 3.11
        return _bad(path, "symlink_loop", f"symlink loop: {exc}")
    except FileNotFoundError:
        return _bad(path, "missing", "does not exist (a dangling symlink)" if path.is_symlink() else "does not exist")
    except PermissionError as exc:
        return _bad(path, "permission_denied", f"permission denied: {exc.strerror or exc}")
    except OSError as exc:
        if (fault := faults.disk_full(exc, path, "reading inputs")) is not None:
            raise fault from exc  # the machine's fault, not the input's: never quarantined
        if "too many levels of symbolic links" in str(exc).lower():
            return _bad(path, "symlink_loop", f"symlink loop: {exc.strerror or exc}")
        return _bad(path, "unreadable", f"cannot read: {exc.strerror or exc}")


def iso_truncation(handle, size: int) -> str | None:
    """For an ISO media file (MP4, MOV: it starts with an 'ftyp' box), the problem when a
    top-level box runs past the end of the file, i.e. the file was cut off; else None.

    Reads only box headers. A file cut inside 'mdat' either lost the index ('moov' comes last)
    or keeps an index of frames that are not there; either way it is still being copied or
    was damaged, and the demuxer alone would report the first as "invalid data".
    """
    offset, kinds = 0, set()
    while offset + 8 <= size:
        handle.seek(offset)
        head = handle.read(16)
        box_size, kind = struct.unpack(">I4s", head[:8])
        if not kinds and kind != b"ftyp":
            return None  # not an ISO media file: the decoder judges it
        kinds.add(kind)
        if box_size == 1 and len(head) == 16:
            box_size = struct.unpack(">Q", head[8:16])[0]
        elif box_size == 0:  # "to the end of the file"
            offset = size
            break
        if box_size < 8:
            return f"box {kind!r} at byte {offset} has an impossible size {box_size}"
        if offset + box_size > size:
            name = kind.decode("latin-1")
            return (f"cut off: the file ends at byte {size} inside its '{name}' box "
                    f"(which declares {offset + box_size} bytes)")
        offset += box_size
    if kinds and offset < size:
        return f"cut off: the file ends at byte {size} inside a box header"
    if kinds and b"moov" not in kinds:
        return "cut off: no 'moov' box (the index of the frames) before the end of the file"
    return None


def find(paths: list[str | Path], skip: list[Path] = ()) -> list[Path]:
    """The paths of a batch: files given directly whatever their suffix; folders contribute
    their videos, except those inside a folder of ``skip`` that the folder walked is not inside
    itself (the data root's outputs, ``paths.output_folders``: curating a folder that holds the
    data root must not take its own clips and episode videos back in). Sorted, each once."""
    found: set[str] = set()
    skipped = [Path(folder).resolve() for folder in skip]
    for raw in paths:
        path = Path(raw)
        if path.is_dir() and not path.name.lower().endswith(VIDEO_SUFFIXES):
            walked = path.resolve()
            left_out = [folder for folder in skipped if not walked.is_relative_to(folder)]
            for child in path.rglob("*"):
                if child.name.lower().endswith(VIDEO_SUFFIXES) and not _inside(child, left_out):
                    found.add(str(child))
        else:
            found.add(str(path))
    return [Path(p) for p in sorted(found)]


def _inside(path: Path, folders: list[Path]) -> bool:
    parent = path.parent.resolve() if folders else None
    return any(parent.is_relative_to(folder) for folder in folders)


def discover(paths: list[str | Path], skip: list[Path] = ()) -> list[Input]:
    """``find``'s paths, each checked and hashed (``Input``), sorted by path so batches are
    processed in the same order every time."""
    return [_check(path) for path in find(paths, skip)]


# DecodeError messages (tasks/video/read.py, tasks/curate/decode.py) -> rejection reason; first match wins.
DECODE_REASONS = (
    ("no video stream", "no_video_stream"),
    ("absurd frame size", "absurd_frame_size"),
    ("absurd or missing frame rate", "absurd_frame_rate"),
    ("absurd sample aspect ratio", "absurd_aspect_ratio"),
    ("empty file", "empty"),
    ("no such file", "missing"),
)


def decode_reason(message: str) -> str:
    """The rejection reason of a DecodeError; "unreadable" when it names nothing more precise."""
    for phrase, reason in DECODE_REASONS:
        if phrase in message:
            return reason
    return "unreadable"


def damage(decode: dict) -> tuple[str, str] | None:
    """(reason, detail) when a decoded video is damaged; None when it decoded cleanly.

    ``decode`` is ``VideoAnalysis.decode``. Any damage quarantines the whole input: a clip cut
    from a file that lost frames would carry a jump the filters never saw, and a truncated
    file is often still being copied.
    """
    frames = int(decode.get("frames", 0))
    problems = "; ".join(decode.get("problems") or [])
    if decode.get("truncated"):
        return "truncated", f"the file ends mid-stream after {frames} frames ({problems})"
    bad = int(decode.get("corrupt", 0)) + int(decode.get("missing", 0)) + int(decode.get("decode_errors", 0))
    if bad:
        return "corrupt_frames", (f"{decode.get('corrupt', 0)} corrupt and {decode.get('missing', 0)} missing frames, "
                                  f"{decode.get('decode_errors', 0)} packets rejected ({problems})")
    if frames < 2:
        return "single_frame", f"only {frames} decodable frame: a still image, not a video"
    return None
