"""The episodes an export reads: found from what the user names, each read and checked whole
before anything is written, a damaged one set aside with its reason.

A source is a manifest YAML (its episodes under the data root), a manifest hash (12 or more hex
digits), a folder of episodes (``episodes/<hash>`` or any folder above episode folders) or one
episode folder. An episode is a folder ``worldline simulate`` finished (tasks/sim/files.py):
``meta.json`` (written last), ``steps.parquet`` (one row per control step) and one H.264 MP4 per
camera. Reading one decodes every frame of every camera once (a video that does not decode to
the frames its episode promises is damaged) and keeps what the export needs of them: the frame
count, whether the file can be copied as it is, and per-channel pixel histograms for the stats.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq

from schemas import paths
from schemas.errors import InvalidInput, StepMissing
from tasks import manifests

# LeRobot looks a frame up by its timestamp and refuses one further than its tolerance_s (1e-4 s
# by default) from the frame the decoder finds; a copied MP4 must put every frame closer than that.
FRAME_TOLERANCE_S = 1e-5
# Frames sampled per episode and camera for the pixel statistics (LeRobot samples about as many).
STATS_FRAMES = 100
# Pixels are subsampled to about this many per side for the statistics (LeRobot: 150).
STATS_SIDE = 150


class Damaged(Exception):
    """An episode that cannot be exported: its folder and the problem, in one line."""


@dataclass(frozen=True)
class Camera:
    """What a camera's video is: LeRobot keeps one shape per video key and one fps per dataset."""

    name: str
    width: int
    height: int
    fps: Fraction

    def __str__(self) -> str:
        return f"{self.name} {self.width}x{self.height}@{float(self.fps):g}"


@dataclass
class Video:
    path: Path
    camera: Camera
    frames: int
    codec: str
    pix_fmt: str
    exact_times: bool  # every frame at i / fps, within FRAME_TOLERANCE_S
    histogram: np.ndarray  # 3 x 256 counts of the sampled pixels' values per RGB channel

    @property
    def copyable(self) -> bool:
        """H.264 in yuv420p with exact frame times: what LeRobot's decoders read, copied as is."""
        return self.codec == "h264" and self.pix_fmt == "yuv420p" and self.exact_times


@dataclass
class Episode:
    folder: Path
    manifest_hash: str
    index: int
    task_kind: str
    control_hz: float
    time: np.ndarray  # (T,) s at the start of each control step
    joint_names: list[str]
    joint_pos: np.ndarray  # T x J
    joint_vel: np.ndarray  # T x J
    action: np.ndarray  # T x A
    object_names: list[str]
    object_pose: np.ndarray  # T x (N * 7): xyz + quaternion wxyz per object
    videos: dict[str, Video] = field(default_factory=dict)

    @property
    def cameras(self) -> tuple[Camera, ...]:
        return tuple(self.videos[name].camera for name in sorted(self.videos))

    @property
    def frames(self) -> int:
        return next(iter(self.videos.values())).frames

    @property
    def fps(self) -> Fraction:
        return next(iter(self.videos.values())).camera.fps


def episode_folders(sources: Sequence[str], root: Path) -> tuple[list[Path], dict[str, manifests.ScenarioManifest]]:
    """(episode folders in order, without repeats; the manifests loaded from YAML sources by hash).
    A source that names nothing, or no episodes, is refused in one line."""
    folders: list[Path] = []
    loaded: dict[str, manifests.ScenarioManifest] = {}
    for source in sources:
        place = Path(source)
        if place.is_file():
            try:
                scenario = manifests.load(place)
            except manifests.ManifestError as exc:
                raise InvalidInput(str(exc)) from None
            loaded[scenario.sha256] = scenario
            place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=scenario.sha256)
            found = _finished(place)
            if not found:
                raise StepMissing(f"{source}: no simulated episodes under {place} (run `worldline simulate` first)")
        elif place.is_dir():
            found = _finished(place)
            if not found:
                raise InvalidInput(f"{source}: no episodes in this folder (folders with meta.json and steps.parquet)")
        elif re.fullmatch(r"[0-9a-f]{12,64}", source):  # as tasks.lookup.is_hex_id, without its torch import
            place = paths.resolve(root, paths.EPISODES_OF_MANIFEST, manifest_hash=source)
            found = _finished(place)
            if not found:
                raise StepMissing(f"{source}: no simulated episodes under {place} (run `worldline simulate` first)")
        else:
            raise InvalidInput(f"{source}: no such file or folder (a manifest YAML, a manifest hash, or a folder "
                               "of episodes)")
        folders.extend(f for f in found if f not in folders)
    return folders, loaded


def _finished(place: Path) -> list[Path]:
    """Episode folders under ``place`` (or ``place`` itself): those with meta.json, the last
    file simulate writes."""
    if (place / "meta.json").is_file():
        return [place.resolve()]
    return sorted(p.parent.resolve() for p in place.rglob("meta.json")) if place.is_dir() else []


def read_episode(folder: Path) -> Episode:
    """One episode read whole and checked, or Damaged naming the folder and the problem."""
    try:
        meta = json.loads((folder / "meta.json").read_text())
        digest, index, cameras = meta["manifest_hash"], int(meta["index"]), list(meta["cameras"])
        task_kind = str(meta.get("task", ""))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise Damaged(f"{folder / 'meta.json'}: unreadable ({_reason(exc)})") from None
    if not cameras:
        raise Damaged(f"{folder}: no camera videos (LeRobot rows are video frames)")
    episode = _steps(folder / "steps.parquet", digest, index, task_kind, folder)
    for name in cameras:
        episode.videos[name] = probe(folder / f"{name}.mp4", name)
    counts = {v.frames for v in episode.videos.values()}
    rates = {v.camera.fps for v in episode.videos.values()}
    if len(rates) > 1:
        raise Damaged(f"{folder}: cameras at different frame rates ({', '.join(map(str, episode.cameras))}); a "
                      "LeRobot dataset has one fps")
    horizon = float(episode.time[-1]) + 1.0 / episode.control_hz
    expected = int(np.floor(horizon * float(episode.fps) + 1e-9))
    if counts != {expected}:
        raise Damaged(f"{folder}: videos hold {sorted(counts)} frames, the episode's {horizon:g} s at "
                      f"{float(episode.fps):g} fps make {expected}")
    return episode


def _steps(table_path: Path, digest: str, index: int, task_kind: str, folder: Path) -> Episode:
    try:
        table = pq.read_table(table_path)
        schema_meta = table.schema.metadata or {}
        joint_names = json.loads(schema_meta[b"joint_names"])
        control_hz = float(schema_meta[b"control_hz"])
        time = table.column("time").to_numpy().astype(np.float64)
        joint_pos = _matrix(table, "joint_pos")
        joint_vel = _matrix(table, "joint_vel")
        action = _matrix(table, "action")
        objects = [c[len("pose."):] for c in table.column_names if c.startswith("pose.")]
        pose = (np.concatenate([_matrix(table, f"pose.{o}") for o in objects], axis=1) if objects
                else np.zeros((len(time), 0)))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise Damaged(f"{table_path}: unreadable ({_reason(exc)})") from None
    if len(time) == 0:
        raise Damaged(f"{table_path}: no steps")
    if not np.all(np.diff(time) > 0):
        raise Damaged(f"{table_path}: step times do not increase")
    if joint_pos.shape[1] != len(joint_names) or joint_vel.shape != joint_pos.shape:
        raise Damaged(f"{table_path}: joint_pos / joint_vel do not match the {len(joint_names)} joint names")
    for name, values in (("joint_pos", joint_pos), ("joint_vel", joint_vel), ("action", action), ("pose", pose)):
        if not np.all(np.isfinite(values)):
            raise Damaged(f"{table_path}: {name} holds NaN or infinite values")
    return Episode(folder=folder, manifest_hash=digest, index=index, task_kind=task_kind, control_hz=control_hz,
                   time=time, joint_names=list(joint_names), joint_pos=joint_pos, joint_vel=joint_vel,
                   action=action, object_names=objects, object_pose=pose)


def _matrix(table, column: str) -> np.ndarray:
    """A list column as a T x D float64 matrix (ValueError when its rows differ in length)."""
    rows = table.column(column).to_pylist()
    return np.array(rows, dtype=np.float64).reshape(len(rows), -1)


def probe(path: Path, name: str) -> Video:
    """Decode every frame of a camera's MP4 once: its shape, rate, count, whether each frame
    lies at i / fps, and the pixel histograms of up to STATS_FRAMES frames spread over it."""
    if not path.is_file():
        raise Damaged(f"{path}: missing")
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate
            if not rate:
                raise Damaged(f"{path}: no frame rate")
            fps = Fraction(rate).limit_denominator(1001)
            width, height = stream.codec_context.width, stream.codec_context.height
            codec, pix_fmt = stream.codec_context.name, stream.codec_context.pix_fmt or ""
            declared = stream.frames
            keep = set(_spread(declared, STATS_FRAMES)) if declared else None
            histogram = np.zeros((3, 256), np.int64)
            exact, count = True, 0
            for frame in container.decode(stream):
                if frame.pts is None or frame.time is None or abs(frame.time - count / fps) > FRAME_TOLERANCE_S:
                    exact = False
                if keep is None or count in keep:
                    histogram += _histogram(frame.to_ndarray(format="rgb24"))
                count += 1
    except Damaged:
        raise
    except (OSError, av.FFmpegError, IndexError, ValueError) as exc:
        raise Damaged(f"{path}: does not decode ({_reason(exc)})") from None
    if count == 0:
        raise Damaged(f"{path}: no frames")
    return Video(path=path, camera=Camera(name, width, height, fps), frames=count, codec=codec, pix_fmt=pix_fmt,
                 exact_times=exact, histogram=histogram)


def _spread(n: int, most: int) -> list[int]:
    """Up to ``most`` frame numbers spread evenly over ``n`` frames, first and last included."""
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, min(n, most))})


def _histogram(image: np.ndarray) -> np.ndarray:
    step = max(1, max(image.shape[:2]) // STATS_SIDE)
    pixels = image[::step, ::step].reshape(-1, 3)
    return np.stack([np.bincount(pixels[:, c], minlength=256) for c in range(3)])


def _reason(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


@dataclass(frozen=True)
class Shape:
    """What every exported episode must share: LeRobot's features are the same for every row."""

    cameras: tuple[Camera, ...]
    joints: tuple[str, ...]
    actions: int
    objects: tuple[str, ...]

    @staticmethod
    def of(episode: Episode) -> Shape:
        return Shape(episode.cameras, tuple(episode.joint_names), episode.action.shape[1],
                     tuple(episode.object_names))


def check_same_shape(episodes: Sequence[Episode]) -> Shape:
    """The shape all episodes share, or InvalidInput in one line naming two that differ (and,
    where they came from different manifests, both manifests)."""
    first = episodes[0]
    shape = Shape.of(first)
    for other in episodes[1:]:
        theirs = Shape.of(other)
        if theirs == shape:
            continue
        where = (f" (manifests {first.manifest_hash[:12]} and {other.manifest_hash[:12]})"
                 if other.manifest_hash != first.manifest_hash else "")
        for what, ours, them in (("cameras", shape.cameras, theirs.cameras), ("joints", shape.joints, theirs.joints),
                                 ("action sizes", shape.actions, theirs.actions),
                                 ("objects", shape.objects, theirs.objects)):
            if ours != them:
                raise InvalidInput(
                    f"{other.folder}: different {what} from {first.folder}{where}: {_listed(them)} vs {_listed(ours)}; "
                    "a LeRobot dataset has one set of features, so export them separately")
    return shape


def _listed(value) -> str:
    return ", ".join(map(str, value)) if isinstance(value, tuple) else str(value)


def read_all(folders: Sequence[Path], on_damaged: Callable[[str], None]) -> list[Episode]:
    """Each folder read; a damaged one reported through ``on_damaged`` and left out."""
    episodes = []
    for folder in folders:
        try:
            episodes.append(read_episode(folder))
        except Damaged as exc:
            on_damaged(str(exc))
    return episodes
