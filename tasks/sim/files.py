"""Episode files, LeRobot-like: an H.264 MP4 per camera, a Parquet table of steps, meta.json."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, raw_video_id
from tasks.mp4 import write_mp4
from tasks.sim.rigs import tile


@dataclass(frozen=True)
class EpisodeFiles:
    index: int
    seed: int
    directory: Path
    videos: dict[str, Path]
    table: Path
    meta: Path
    success: bool
    reason: str
    steps: int
    stressor_values: dict
    policy: dict | None = None  # what drove the robot, when not the manifest's scripted controller


def _steps_table(ep) -> pa.Table:
    columns = {
        "step": pa.array(np.arange(ep.steps, dtype=np.int64)),
        "time": pa.array(ep.time.astype(np.float64)),
        "joint_pos": pa.array(list(ep.joint_pos.astype(np.float64)), pa.list_(pa.float64())),
        "joint_vel": pa.array(list(ep.joint_vel.astype(np.float64)), pa.list_(pa.float64())),
        "action": pa.array(list(ep.action.astype(np.float64)), pa.list_(pa.float64())),
        "success_flag": pa.array(ep.success_flag),
        "estop": pa.array(ep.estop),
    }
    for k, name in enumerate(ep.object_names):
        columns[f"pose.{name}"] = pa.array(list(ep.object_pose[:, k].astype(np.float64)), pa.list_(pa.float64(), 7))
    meta = {"joint_names": json.dumps(list(ep.joint_names)), "control_hz": str(ep.control_hz)}
    return pa.table(columns).replace_schema_metadata(meta)


def _atomic(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    write(tmp)
    os.replace(tmp, path)


def write_episode(ep, root: Path, manifest_hash: str, index: int, crf: int = 20,
                  policy: dict | None = None) -> EpisodeFiles:
    """Write one episode under EPISODE_DIR; meta.json is written last and marks it complete.
    Every manifest camera's video is written, and each rig's tiled video (meta.json lists them
    under ``rigs``, apart from ``cameras``): an episode rolled out recording fewer cameras
    (`rollout(..., record=...)`) is refused. ``policy``: what drove the robot, when not the
    manifest's scripted controller (a policy's ``describe()``): the episode goes under
    POLICY_EPISODE_DIR instead, and meta.json names it."""
    missing = [c.name for c in ep.manifest.cameras if c.name not in ep.frames]
    if missing:
        raise ValueError(f"episode of {ep.manifest.name} seed {ep.seed} has no frames of camera(s) "
                         f"{', '.join(missing)}: roll it out recording every camera to write it")
    if policy is None:
        directory = paths.resolve(root, paths.EPISODE_DIR, manifest_hash=manifest_hash, index=index)
    else:
        directory = paths.resolve(root, paths.POLICY_EPISODE_DIR, manifest_hash=manifest_hash, index=index,
                                  policy_id=policy_id(policy))
    directory.mkdir(parents=True, exist_ok=True)
    videos = {}
    for camera, frames in ep.frames.items():
        fps = next(c.fps for c in ep.manifest.cameras if c.name == camera)
        videos[camera] = write_mp4(paths.resolve(directory, paths.CAMERA_VIDEO, camera=camera), frames, fps, crf)
    cameras = sorted(videos)
    for rig in ep.manifest.rigs:  # every view of a rig together, as one video (tasks/sim/rigs.py)
        fps = next(c.fps for c in ep.manifest.cameras if c.name == rig.cameras[0])
        videos[rig.name] = write_mp4(paths.resolve(directory, paths.CAMERA_VIDEO, camera=rig.name),
                                     tile(ep.frames, rig.layout), fps, crf)
    table = directory / Path(paths.EPISODE_TABLE).name
    _atomic(table, lambda p: pq.write_table(_steps_table(ep), p, compression="zstd"))
    meta = directory / Path(paths.EPISODE_META).name
    body = {"manifest_hash": manifest_hash, "index": index, "seed": ep.seed, "success": bool(ep.success),
            "reason": ep.reason, "steps": ep.steps, "control_hz": ep.control_hz,
            "stressors": ep.stressor_values, "cameras": cameras, "task": ep.manifest.task.kind}
    if ep.manifest.rigs:
        body["rigs"] = [rig.name for rig in ep.manifest.rigs]
    if policy is not None:
        body["policy"] = policy
    _atomic(meta, lambda p: p.write_text(json.dumps(body, sort_keys=True, indent=1, default=float)))
    return EpisodeFiles(index=index, seed=ep.seed, directory=directory, videos=videos, table=table, meta=meta,
                        success=bool(ep.success), reason=ep.reason, steps=ep.steps,
                        stressor_values=dict(ep.stressor_values), policy=policy)


def policy_id(policy: dict) -> str:
    """The id of a policy's ``describe()``: names the folder of the episodes it drove."""
    return stable_id("policy", json.dumps(policy, sort_keys=True, default=str))


def episode_lineage(files: EpisodeFiles, manifest_hash: str, stage_run_id: str, root: Path | None = None) -> LineageBatch:
    """manifest -> episode (its step table) -> one episode_video per camera, with success metrics."""
    def uri(path: Path) -> str:
        return str(path.relative_to(root)) if root else str(path)

    table_sha = sha256_file(str(files.table))
    episode_id = stable_id("episode", manifest_hash, str(files.index), table_sha)
    attrs = {"index": files.index, "seed": files.seed, "success": files.success, "reason": files.reason,
             "stressors": files.stressor_values, "meta": uri(files.meta),
             **({"policy": files.policy} if files.policy is not None else {})}
    batch = LineageBatch(
        artifacts=[ArtifactRecord(artifact_id=episode_id, kind="episode", uri=uri(files.table), sha256=table_sha,
                                  bytes=files.table.stat().st_size, manifest_hash=manifest_hash,
                                  stage_run_id=stage_run_id, attrs=attrs)],
        edges=[EdgeRecord(parent_id=manifest_hash, child_id=episode_id, relation="simulated_from")],
        metrics=[MetricRecord(subject_id=episode_id, name=name, value=value, stage_run_id=stage_run_id,
                              manifest_hash=manifest_hash)
                 for name, value in (("success", float(files.success)), ("steps", float(files.steps)))],
    )
    for camera, video in sorted(files.videos.items()):
        sha = sha256_file(str(video))
        # The same id curate gives a raw video with these bytes: curating episode videos then
        # extends this lineage instead of starting a second, disconnected one.
        vid = raw_video_id(sha)
        batch.artifacts.append(ArtifactRecord(artifact_id=vid, kind="episode_video", uri=uri(video), sha256=sha,
                                              bytes=video.stat().st_size, manifest_hash=manifest_hash,
                                              stage_run_id=stage_run_id, attrs={"camera": camera, **attrs}))
        batch.edges.append(EdgeRecord(parent_id=episode_id, child_id=vid, relation="rendered"))
    return batch


def finished(directory: Path) -> bool:
    """Whether the episode folder ``directory`` holds a finished episode: meta.json (written
    last), the step table, and every camera's video it names."""
    try:
        body = json.loads((Path(directory) / Path(paths.EPISODE_META).name).read_text())
        names = [paths.CAMERA_VIDEO.format(camera=c) for c in [*body["cameras"], *body.get("rigs", [])]]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return all((Path(directory) / name).is_file() for name in [Path(paths.EPISODE_TABLE).name, *names])


def read_episode(root: Path, digest: str, index: int) -> EpisodeFiles | None:
    """A finished episode from its files (meta.json is written last), or None."""
    meta = paths.resolve(root, paths.EPISODE_META, manifest_hash=digest, index=index)
    if not meta.is_file():
        return None
    body = json.loads(meta.read_text())
    videos = {c: paths.resolve(root, paths.EPISODE_VIDEO, manifest_hash=digest, index=index, camera=c)
              for c in [*body["cameras"], *body.get("rigs", [])]}
    table = paths.resolve(root, paths.EPISODE_TABLE, manifest_hash=digest, index=index)
    if not table.is_file() or not all(v.is_file() for v in videos.values()):
        return None
    return EpisodeFiles(index=index, seed=body["seed"], directory=meta.parent, videos=videos, table=table,
                        meta=meta, success=body["success"], reason=body["reason"], steps=body["steps"],
                        stressor_values=body.get("stressors", {}))
