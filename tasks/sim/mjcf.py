"""Robot MJCF files the scene may hand to MuJoCo: every file they make it read stays inside the
robots root (issue 26), and none declares a DOCTYPE or ENTITY."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

MAX_MJCF_FILES = 256  # one robot's MJCF files, includes and nested models together
MAX_MJCF_BYTES = 8 * 1024 * 1024
ASSET_DIRS = ("meshdir", "texturedir", "assetdir")


class RobotFileError(FileNotFoundError):
    """A robot file the scene will not hand to MuJoCo: missing, not plain XML, or reaching
    outside the robots root. A FileNotFoundError, so what handles a missing robot file (the
    CLI: one line, exit 2) handles these too."""


def check_mjcf(path: Path, root: Path) -> None:
    """RobotFileError unless every file MuJoCo may read to load the MJCF at ``path`` lies inside
    ``root``, symlinks followed: the file, its <include>s and nested <model>s (recursively), and
    each file* attribute (mesh, texture, hfield, skin...) under any compiler meshdir, texturedir
    or assetdir. MuJoCo looks beside the main file and beside the including file; rather than
    copy one version's order, every place it may look must lie inside (issue 26)."""
    root = root.resolve()
    mains, models, read = [path], set(), 0
    while mains:  # the top MJCF, then each nested <model file=...>, its paths from its own folder
        main = mains.pop()
        if _inside(main, root, "") in models:
            continue
        models.add(main.resolve())
        files, trees = [main], {}
        for current in files:  # grows as includes are found
            real = _inside(current, root, "")
            if real in trees:
                continue
            read += 1
            if read > MAX_MJCF_FILES:
                raise RobotFileError(f"{_name(path, root)}: reads more than {MAX_MJCF_FILES} MJCF files")
            tree = trees[real] = _parse(current, root)
            files += [_found(e, "file", current, [main.parent, current.parent], root) for e in tree.iter("include")]
        dirs = {""} | {c.get(a) for t in trees.values() for c in t.iter("compiler") for a in ASSET_DIRS if c.get(a)}
        for current in dict.fromkeys(files):
            bases = [b / d for b in dict.fromkeys((main.parent, current.parent)) for d in sorted(dirs)]
            for element in trees[current.resolve()].iter():
                for attr in element.attrib:
                    if attr.startswith("file") and element.tag != "include":
                        found = _found(element, attr, current, bases, root)
                        if element.tag == "model" and found is not None:
                            mains.append(found)


def _name(path: Path, root: Path) -> str:
    real = path.resolve()
    return str(real.relative_to(root)) if real.is_relative_to(root) else str(path)


def _inside(path: Path, root: Path, where: str) -> Path:
    real = path.resolve()
    if not real.is_relative_to(root):
        raise RobotFileError(f"{where}resolves to {real}, outside the robots root {root}")
    return real


def _found(element: ET.Element, attr: str, current: Path, bases: list[Path], root: Path) -> Path | None:
    """The first of ``bases`` joined with the attribute's path that exists, each checked inside."""
    where = f"<{element.tag} {attr}={element.get(attr)!r}> in {_name(current, root)} "
    candidates = [base / element.get(attr) for base in bases]
    for candidate in candidates:
        _inside(candidate, root, where)
    found = next((c for c in candidates if c.is_file()), None)
    if found is None and element.tag in ("include", "model"):
        raise RobotFileError(f"{where}names no file")
    return found


def _parse(path: Path, root: Path) -> ET.Element:
    name = _name(path, root)
    try:
        if path.stat().st_size > MAX_MJCF_BYTES:
            raise RobotFileError(f"{name}: larger than {MAX_MJCF_BYTES} bytes")
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise RobotFileError(f"{name}: cannot read: {exc}") from None
    # Entities can pull other files in (or blow up); MJCF never needs them, so refuse unread.
    if re.search(r"<!(DOCTYPE|ENTITY)", text, re.IGNORECASE):
        raise RobotFileError(f"{name}: declares a DOCTYPE or ENTITY, which an MJCF never needs")
    try:
        return ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotFileError(f"{name}: not well-formed XML ({exc})") from None
