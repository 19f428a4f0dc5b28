"""``worldline export lerobot``: sources to a LeRobot dataset folder, checked before it is written.

Every episode is read and checked first (a damaged one is named and left out, the rest go on);
episodes that do not share one set of features (cameras, joints, action size, objects) are
refused in one line; then the dataset is written to a temporary folder beside ``out`` and
renamed into place, so ``out`` is never left half written and is replaced only when asked.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from schemas.errors import InvalidInput
from tasks.export import lerobot
from tasks.export.sources import Episode, check_same_shape, episode_folders, read_all


@dataclass
class Result:
    exported: lerobot.Exported
    skipped: list[str] = field(default_factory=list)  # one line per damaged episode


def export_lerobot(sources: Sequence[str], out: Path, root: Path, overwrite: bool = False,
                   instruction_of: Callable[[str], tuple[str | None, str | None]] | None = None,
                   on_damaged: Callable[[str], None] | None = None,
                   on_episode: Callable[[Episode], None] | None = None) -> Result:
    """Export the episodes ``sources`` name (tasks/export/sources.py) to ``out``.

    ``instruction_of(manifest_hash)`` gives (the task's instruction, the robot) of a manifest
    not given as a YAML file (the CLI looks it up in lineage), or (None, None); an episode
    whose instruction is unknown gets its task kind from meta.json as its task text."""
    out = Path(out)
    lerobot.check_destination(out, overwrite)
    folders, loaded = episode_folders(sources, root)
    skipped: list[str] = []

    def damaged(line: str) -> None:
        skipped.append(line)
        if on_damaged is not None:
            on_damaged(line)

    episodes = read_all(folders, damaged)
    if not episodes:
        raise InvalidInput(f"{', '.join(sources)}: none of the {len(folders)} episodes could be exported "
                           f"(first: {skipped[0]})")
    shape = check_same_shape(episodes)
    known: dict[str, tuple[str | None, str | None]] = {
        h: (m.task.instruction, m.embodiment.robot) for h, m in loaded.items()}
    for digest in {e.manifest_hash for e in episodes} - set(known):
        known[digest] = instruction_of(digest) if instruction_of is not None else (None, None)
    robots = {known[e.manifest_hash][1] for e in episodes}
    robot_type = robots.pop() if len(robots) == 1 else None

    def task_of(episode: Episode) -> str:
        return known[episode.manifest_hash][0] or episode.task_kind or "unknown task"

    staging = lerobot.staging_for(out)
    try:
        exported = lerobot.write_lerobot(episodes, shape, staging, task_of, robot_type, on_episode)
        lerobot.publish(staging, out, overwrite)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    exported.out = out
    return Result(exported=exported, skipped=skipped)
