"""Episodes written as a LeRobot dataset, codebase version v3.0: the layout ``lerobot`` 0.4 reads
with ``LeRobotDataset(repo_id, root=DIR)`` (lerobot/datasets/utils.py and lerobot_dataset.py)::

    meta/info.json                      codebase_version, fps, totals, paths, features
    meta/stats.json                     statistics of every feature (tasks/export/stats.py)
    meta/tasks.parquet                  task text (index) -> task_index
    meta/episodes/chunk-000/file-000.parquet
                                        one row per episode: tasks, length, its rows' range
                                        (dataset_from_index, dataset_to_index), its data file,
                                        its video files and times, its stats/<feature>/<stat>
    meta/worldline.json                 where each episode came from (not read by lerobot)
    data/chunk-000/file-000.parquet     one row per video frame: timestamp, frame_index,
                                        episode_index, index, task_index, float32
                                        observation.state, observation.environment_state, action
    videos/observation.images.<camera>/chunk-000/file-000.mp4
                                        one MP4 per episode and camera (file index = episode
                                        index within its chunk of 1000)

Rows are the episode's control steps resampled to the video frames (tasks/export/frames.py).
A camera's MP4 is copied as simulate wrote it when it is H.264 in yuv420p with every frame at
i / fps (what LeRobot's decoders seek by); otherwise its decoded frames are encoded again with
PyAV's libx264 (tasks/video/write.py). Everything is written under a temporary folder beside
the destination and renamed into place at the end (``publish``).
"""

from __future__ import annotations

import glob
import json
import os
import re
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.errors import InvalidInput
from schemas.hashing import sha256_file
from tasks.export import stats as statistics
from tasks.export.frames import Rows, resample
from tasks.export.sources import Episode, Shape, Video
from tasks.video import stored_frames, write_mp4

CODEBASE_VERSION = "v3.0"
CHUNK_SIZE = 1000  # files per chunk folder
DATA_FILE_MB = 100  # a data file takes episodes until about this size
VIDEO_FILE_MB = 200  # recorded in info.json; each episode has a video file of its own here
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
POSE_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")
INDEX_FEATURES = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64", "index": "int64",
                  "task_index": "int64"}


def video_key(camera: str) -> str:
    return f"observation.images.{camera}"


def chunk_file(number: int) -> dict[str, int]:
    """The chunk and file index of the ``number``-th file of a kind (CHUNK_SIZE files a chunk)."""
    return {"chunk_index": number // CHUNK_SIZE, "file_index": number % CHUNK_SIZE}


@dataclass
class Exported:
    out: Path
    episodes: int = 0
    frames: int = 0
    tasks: list[str] = field(default_factory=list)
    copied: int = 0  # videos copied as they were
    encoded: int = 0  # videos encoded again


def features(shape: Shape, fps: int) -> dict[str, dict]:
    """info.json's features: the float32 vectors, each camera's video, LeRobot's index columns."""
    found: dict[str, dict] = {
        "observation.state": {"dtype": "float32", "shape": [2 * len(shape.joints)],
                              "names": [f"{j}.pos" for j in shape.joints] + [f"{j}.vel" for j in shape.joints]},
    }
    if shape.objects:
        found["observation.environment_state"] = {
            "dtype": "float32", "shape": [len(POSE_NAMES) * len(shape.objects)],
            "names": [f"{o}.{p}" for o in shape.objects for p in POSE_NAMES]}
    found["action"] = {"dtype": "float32", "shape": [shape.actions], "names": None}
    for cam in shape.cameras:
        found[video_key(cam.name)] = {
            "dtype": "video", "shape": [cam.height, cam.width, 3], "names": ["height", "width", "channels"],
            "info": {"video.height": cam.height, "video.width": cam.width, "video.codec": "h264",
                     "video.pix_fmt": "yuv420p", "video.is_depth_map": False, "video.fps": fps,
                     "video.channels": 3, "has_audio": False}}
    for name, dtype in INDEX_FEATURES.items():
        found[name] = {"dtype": dtype, "shape": [1], "names": None}
    return found


def _row_columns(rows: Rows, shape: Shape, episode_index: int, first_index: int, task_index: int) -> dict:
    n = len(rows)
    columns = {"observation.state": rows.state}
    if shape.objects:
        columns["observation.environment_state"] = rows.environment_state
    columns["action"] = rows.action
    columns.update({"timestamp": rows.timestamp, "frame_index": rows.frame_index,
                    "episode_index": np.full(n, episode_index, np.int64),
                    "index": np.arange(first_index, first_index + n, dtype=np.int64),
                    "task_index": np.full(n, task_index, np.int64)})
    return columns


def _arrow(columns: dict[str, np.ndarray]) -> pa.Table:
    """Vectors as fixed-size float32 lists (LeRobot's ``Sequence(length=D)``), scalars as they are."""
    arrays = {}
    for name, values in columns.items():
        if values.ndim == 2:
            flat = pa.array(values.reshape(-1), pa.float32())
            arrays[name] = pa.FixedSizeListArray.from_arrays(flat, values.shape[1])
        else:
            arrays[name] = pa.array(values)
    return pa.table(arrays)


def _episode_stats(columns: dict[str, np.ndarray], episode: Episode) -> dict[str, dict[str, np.ndarray]]:
    found = {name: statistics.vector_stats(values) for name, values in columns.items()}
    for name, video in sorted(episode.videos.items()):
        found[video_key(name)] = statistics.image_stats(video.histogram, video.frames)
    return found


def _dataset_stats(per_column: dict[str, list[np.ndarray]], episodes: Sequence[Episode]) -> dict:
    found = {name: statistics.vector_stats(np.concatenate(parts)) for name, parts in per_column.items()}
    for name in sorted(episodes[0].videos):
        histogram = sum(e.videos[name].histogram for e in episodes)
        found[video_key(name)] = statistics.image_stats(histogram, sum(e.videos[name].frames for e in episodes))
    return found


def _write_video(video: Video, dest: Path, fps: int) -> bool:
    """The camera's MP4 at ``dest``: copied (True) or, when LeRobot could not seek it by frame
    time, its frames encoded again with libx264 at ``fps`` (False)."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    if video.copyable:
        shutil.copyfile(video.path, dest)
        return True

    write_mp4(dest, stored_frames(video.path), fps)
    return False


def write_lerobot(episodes: Sequence[Episode], shape: Shape, staging: Path, task_of: Callable[[Episode], str],
                  robot_type: str | None = None, on_episode: Callable[[Episode], None] | None = None) -> Exported:
    """Write ``episodes`` (all of one ``shape``, checked) as a LeRobot dataset under ``staging``."""
    rate = episodes[0].fps
    if rate.denominator != 1:
        raise InvalidInput(f"{episodes[0].folder}: {float(rate):g} fps; a LeRobot dataset has a whole-number fps")
    fps = int(rate)
    found = features(shape, fps)
    row_bytes = sum(4 * (f["shape"][0] if f["dtype"] == "float32" else 2 * f["shape"][0])
                    for f in found.values() if f["dtype"] != "video")
    rows_per_file = max(1, DATA_FILE_MB * 1_000_000 // row_bytes)
    result = Exported(out=staging)
    task_index: dict[str, int] = {}
    per_column: dict[str, list[np.ndarray]] = {}
    episode_rows, provenance = [], []
    pending: list[pa.Table] = []
    data_file, pending_rows, total = 0, 0, 0

    def flush() -> None:
        nonlocal data_file, pending_rows
        if pending:
            path = staging / DATA_PATH.format(**chunk_file(data_file))
            path.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(pa.concat_tables(pending), path, compression="snappy")
            pending.clear()
            data_file, pending_rows = data_file + 1, 0

    for number, episode in enumerate(episodes):
        rows = resample(episode)
        if pending_rows and pending_rows + len(rows) > rows_per_file:
            flush()
        task = task_of(episode)
        task_index.setdefault(task, len(task_index))
        columns = _row_columns(rows, shape, number, total, task_index[task])
        pending.append(_arrow(columns))
        pending_rows += len(rows)
        for name, values in columns.items():
            per_column.setdefault(name, []).append(values)
        entry = {"episode_index": number, "tasks": [task], "length": len(rows),
                 **{f"data/{k}": v for k, v in chunk_file(data_file).items()},
                 "dataset_from_index": total, "dataset_to_index": total + len(rows)}
        for name, video in sorted(episode.videos.items()):
            key = video_key(name)
            place = chunk_file(number)
            copied = _write_video(video, staging / VIDEO_PATH.format(video_key=key, **place), fps)
            result.copied, result.encoded = result.copied + copied, result.encoded + (not copied)
            entry.update({f"videos/{key}/chunk_index": place["chunk_index"],
                          f"videos/{key}/file_index": place["file_index"],
                          f"videos/{key}/from_timestamp": 0.0, f"videos/{key}/to_timestamp": len(rows) / fps})
        entry.update({f"meta/episodes/{k}": v for k, v in chunk_file(0).items()})
        entry.update(statistics.flattened(_episode_stats(columns, episode)))
        episode_rows.append(entry)
        provenance.append({"episode_index": number, "folder": str(episode.folder), "manifest_hash": episode.manifest_hash,
                           "index": episode.index, "steps_sha256": sha256_file(str(episode.folder / "steps.parquet")),
                           "steps": len(episode.time), "control_hz": episode.control_hz})
        total += len(rows)
        if on_episode is not None:
            on_episode(episode)
    flush()

    meta = staging / "meta"
    (meta / "episodes").mkdir(parents=True, exist_ok=True)
    episodes_path = staging / EPISODES_PATH.format(**chunk_file(0))
    episodes_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), episodes_path, compression="snappy")
    tasks = list(task_index)
    pd.DataFrame({"task_index": range(len(tasks))}, index=tasks).to_parquet(meta / "tasks.parquet")
    _write_json(meta / "stats.json", statistics.as_json(_dataset_stats(per_column, episodes)))
    info = {"codebase_version": CODEBASE_VERSION, "robot_type": robot_type, "total_episodes": len(episodes),
            "total_frames": total, "total_tasks": len(tasks), "chunks_size": CHUNK_SIZE,
            "data_files_size_in_mb": DATA_FILE_MB, "video_files_size_in_mb": VIDEO_FILE_MB, "fps": fps,
            "splits": {"train": f"0:{len(episodes)}"}, "data_path": DATA_PATH, "video_path": VIDEO_PATH,
            "features": found}
    _write_json(meta / "info.json", info)
    _write_json(meta / "worldline.json", {
        "exported_by": "worldline export lerobot",
        "rows": "one per video frame: the control step in force at the frame's timestamp (tasks/export/frames.py)",
        "observation.state": "joint positions, then joint velocities, at the step's start",
        "action": "the action applied over that step (layout: tasks/sim/control.py)",
        "episodes": provenance})
    result.episodes, result.frames, result.tasks = len(episodes), total, tasks
    return result


def _write_json(path: Path, body: dict) -> None:
    path.write_text(json.dumps(body, indent=4, ensure_ascii=False) + "\n")


def staging_for(out: Path) -> Path:
    """An empty temporary folder beside ``out`` (same file system, so the rename is atomic).
    Staging folders of exports to ``out`` whose process is gone (killed) are removed first."""
    out = out.absolute()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file where a folder above it belongs, no permission
        raise InvalidInput(f"{out}: cannot be created ({exc.strerror or exc}: {exc.filename or out.parent})") from None
    for stale in out.parent.glob(f".{glob.escape(out.name)}.export-*.tmp"):
        pid = stale.name.rsplit("-", 1)[-1].removesuffix(".tmp")
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
            shutil.rmtree(stale, ignore_errors=True)
    staging = out.parent / f".{out.name}.export-{os.getpid()}.tmp"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    return staging


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# What an export writes (the layout above): with --overwrite, a folder holding anything else is
# not replaced, since replacing it would delete what the user put there.
EXPORT_FILES = re.compile(r"meta/(info|stats|worldline)\.json|meta/tasks\.parquet|meta/episodes/chunk-\d+/file-\d+\.parquet"
                          r"|data/chunk-\d+/file-\d+\.parquet|videos/observation\.images\.[^/]+/chunk-\d+/file-\d+\.mp4")


def check_destination(out: Path, overwrite: bool) -> None:
    """A file, or a folder with something in it, is refused; with ``overwrite``, a folder that
    is an earlier export (its meta/worldline.json) holding nothing an export does not write is not."""
    if out.is_symlink():
        raise InvalidInput(f"{out}: a symlink; --out names the folder the dataset is written to, not a link to one")
    if out.exists() and not out.is_dir():
        raise InvalidInput(f"{out}: a file is there; --out names the folder the dataset is written to")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise InvalidInput(f"{out}: not empty; choose an empty or new folder, or pass --overwrite to replace it")
        if not (out / "meta" / "info.json").is_file() or not (out / "meta" / "worldline.json").is_file():
            raise InvalidInput(f"{out}: not an export of this tool (no meta/info.json and meta/worldline.json); "
                               "--overwrite replaces only an earlier export")
        foreign = sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                         if not p.is_dir() and not EXPORT_FILES.fullmatch(p.relative_to(out).as_posix()))
        if foreign:
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise InvalidInput(f"{out}: holds files an export does not write ({shown}); --overwrite would delete "
                               "them: move them out first, or choose another folder")


def publish(staging: Path, out: Path, overwrite: bool = False) -> None:
    """Put the finished ``staging`` folder at ``out``: what is there is checked again (something
    may have been put there, or another export finished there, while this one ran), moved aside,
    and removed only once the new one is in place."""
    out = out.absolute()
    check_destination(out, overwrite)
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.replaced-{os.getpid()}.tmp"
        os.replace(out, old)
    os.replace(staging, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
