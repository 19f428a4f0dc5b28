"""Control files and their lineage: depth and segmentation of an episode's cameras as compressed
npz, and one `control` artifact per file with a `control_of` edge from the video it controls.

Depth is uint16 millimetres (`depth_mm`), not float16: a millimetre everywhere up to 65.5 m,
where float16 steps 2 mm past 2 m and 8 mm past 8 m, and integers compress better. Segmentation
is uint8 object ids (`ids`) with their names (`legend`, id 0 `background`). Both carry the
camera's name and fps, so a file moved to another episode or camera is told apart
(tasks.controls.check).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from schemas import paths
from schemas.hashing import sha256_file, stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, raw_video_id
from tasks.controls.sources import Source
from tasks.integrity import uri_of

if TYPE_CHECKING:  # the render module loads MuJoCo; edges and blur of a clip need none of it
    from tasks.controls.render import Rendered


def _savez(path: Path, **arrays) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_rendered(rendered: Rendered, episode_dir: Path, fps: dict[str, float]) -> dict[str, dict[str, Path]]:
    """camera -> {"depth": its .depth.npz, "seg": its .seg.npz} under the episode's controls/ folder."""
    out = {}
    for camera in sorted(rendered.depth_mm):
        meta = {"camera": np.array(camera), "fps": np.float64(fps[camera])}
        out[camera] = {
            "depth": _savez(paths.episode_control(episode_dir, camera, "depth"), depth_mm=rendered.depth_mm[camera],
                            **meta),
            "seg": _savez(paths.episode_control(episode_dir, camera, "seg"), ids=rendered.ids[camera],
                          legend=np.array(rendered.legend), **meta),
        }
    return out


def read_depth(path: Path | str) -> np.ndarray:
    """F x H x W float64 metres (0: nothing within the far plane)."""
    with np.load(path, allow_pickle=False) as npz:
        return npz["depth_mm"].astype(np.float64) / 1000.0


def read_segmentation(path: Path | str) -> tuple[np.ndarray, tuple[str, ...]]:
    """(F x H x W uint8 object ids, legend: id -> object name)."""
    with np.load(path, allow_pickle=False) as npz:
        return npz["ids"], tuple(str(n) for n in npz["legend"])


def control_lineage(video_id: str, controls: dict[str, Path], stage_run_id: str, manifest_hash: str | None = None,
                    root: Path | None = None, attrs: dict | None = None) -> LineageBatch:
    """One `control` artifact per file of ``controls`` (control name -> path), each with a
    `control_of` edge from the video artifact ``video_id``."""
    batch = LineageBatch()
    for control, path in sorted(controls.items()):
        sha = sha256_file(str(path))
        control_id = stable_id("control", video_id, control, sha)
        uri = uri_of(path, root) if root is not None else str(path)
        batch.artifacts.append(ArtifactRecord(
            artifact_id=control_id, kind="control", uri=paths.escaped(uri), sha256=sha, bytes=Path(path).stat().st_size,
            manifest_hash=manifest_hash, stage_run_id=stage_run_id, attrs={"control": control, **(attrs or {})}))
        batch.edges.append(EdgeRecord(parent_id=video_id, child_id=control_id, relation="control_of"))
    return batch


def episode_controls_lineage(episode: LineageBatch, controls: dict[str, dict[str, Path]], manifest_hash: str,
                             stage_run_id: str, root: Path | None = None) -> LineageBatch:
    """The controls of an episode's cameras, each from its camera's `episode_video` in ``episode``
    (the batch tasks.sim.files.episode_lineage made)."""
    videos = {a.attrs["camera"]: a.artifact_id for a in episode.artifacts if a.kind == "episode_video"}
    batch = LineageBatch()
    for camera, files in sorted(controls.items()):
        batch.extend(control_lineage(videos[camera], files, stage_run_id, manifest_hash, root, {"camera": camera}))
    return batch


def source_lineage(source: Source, sha256: str, controls: dict[str, Path], stage_run_id: str,
                   root: Path | None = None) -> LineageBatch:
    """The edge and blur controls of one source video. A video that is no episode's camera is
    recorded too, as the `raw_video` curate would record (the same id: its bytes), so the edges
    never hang; an episode's video is already in lineage as its `episode_video`."""
    batch = LineageBatch()
    if source.camera is None:
        batch.artifacts.append(ArtifactRecord(
            artifact_id=raw_video_id(sha256), kind="raw_video",
            uri=paths.escaped(uri_of(source.video, root) if root is not None else str(source.video)), sha256=sha256,
            bytes=source.video.stat().st_size, stage_run_id=stage_run_id))
    attrs = {"camera": source.camera} if source.camera else {}
    return batch.extend(control_lineage(raw_video_id(sha256), controls, stage_run_id, source.manifest_hash, root,
                                        attrs))
