"""Generate long raw videos with a ground-truth JSON beside each (format in config.TRUTH_FORMAT).

Frames are made and encoded one at a time (a simulator segment is rendered whole, at most
`sim_max_width` wide and `sim_max_segment_s` long), so memory stays bounded for an hour of 720p.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from schemas import paths
from schemas.errors import InvalidInput
from schemas.hashing import sha256_file, stable_id
from schemas.manifest import ScenarioManifest, manifest_hash
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, raw_video_id
from tasks import progress
from tasks.corpus import nonphysical, procedural
from tasks.corpus.config import TRUTH_FORMAT, CorpusConfig
from tasks.corpus.defects import Defect, transform
from tasks.corpus.plan import SegmentPlan, VideoPlan, plan_corpus
from tasks.video import write_mp4

VIDEO_MINUTES = 2.0  # default length of one raw video


@dataclass(frozen=True)
class CorpusVideo:
    video: Path
    truth: Path
    plan: VideoPlan
    sims: tuple[str, ...]  # hashes of the manifests whose footage it shows


def default_manifests() -> list[ScenarioManifest]:
    from tasks.manifests import load

    folder = Path(__file__).resolve().parents[2] / "manifests"
    return [load(p) for p in sorted(folder.glob("*.yaml"))]


def _strip(manifest: ScenarioManifest, kinds: Sequence[str]) -> ScenarioManifest:
    return manifest.model_copy(update={"stressors": tuple(s for s in manifest.stressors if s.kind not in kinds)})


def _content(seg: SegmentPlan, width: int, height: int, fps: float, sims: Sequence[ScenarioManifest],
             config: CorpusConfig) -> Iterator[np.ndarray]:
    c = seg.content
    n = seg.n_frames
    if c.kind == "procedural":
        scene = procedural.scene(c.seed, width, height)
        return (scene.frame(i) for i in range(n))
    if c.kind == "sim":
        from tasks.sim.segments import sim_segment

        manifest = _strip(sims[c.manifest], config.sim_strip_stressors)
        # Render small and scale each frame up as it is encoded: a 10 s take at 720p would be 830 MB.
        sw = min(width, config.sim_max_width) // 2 * 2
        sh = max(16, round(sw * height / width) // 2 * 2)
        start_s = float(np.random.default_rng([c.seed, 0x7A4E]).uniform(0.0, config.sim_take_start_s))
        small = sim_segment(manifest, c.seed % 2**31, n, sw, sh, c.camera, fps, config.sim_max_width,
                            start_s=round(start_s * fps) / fps)
        if (sh, sw) == (height, width):
            return iter(small)
        return (cv2.resize(f, (width, height), interpolation=cv2.INTER_LINEAR) for f in small)
    source = nonphysical.source(c.kind, c.seed, width, height, fps)
    return (source.frame(i) for i in range(n))


def _segment(seg: SegmentPlan, width: int, height: int, fps: float, sims, config) -> Iterator[np.ndarray]:
    defect = Defect(seg.label, seg.defect_seed, width, height, fps)
    for i, frame in enumerate(_content(seg, width, height, fps, sims, config)):
        frame = defect.apply(frame, i)
        if seg.duplicate_of is not None:
            frame = transform(frame, seg.duplicate_of.transform, seg.duplicate_of.seed)
        yield frame


def _frames(plan: VideoPlan, width: int, height: int, sims, config) -> Iterator[np.ndarray]:
    """The whole video: segments with hard cuts, fades through black and dissolves between them."""
    last = None
    for seg in plan.segments:
        frames = _segment(seg, width, height, plan.fps, sims, config)
        first = next(frames)
        gap = next((tr for tr in plan.transitions if tr.end == seg.start), None)
        if gap is not None and last is not None:
            length = gap.end - gap.start
            for k in range(length):
                w = (k + 1) / (length + 1)
                if gap.kind == "dissolve":
                    yield ((1 - w) * last + w * first.astype(np.float32)).astype(np.uint8)
                elif w < 0.5:
                    yield (last * (1 - 2 * w)).astype(np.uint8)
                else:
                    yield (first.astype(np.float32) * (2 * w - 1)).astype(np.uint8)
        yield first
        final = first
        for final in frames:
            yield final
        last = final.astype(np.float32)


def _truth(plan: VideoPlan, name: str, width: int, height: int) -> dict:
    segments = []
    for seg in plan.segments:
        dup = seg.duplicate_of
        segments.append({
            "start": seg.start, "end": seg.end,
            "source": "sim" if seg.content.kind == "sim" else "procedural",
            "scene": seg.content.scene, "label": seg.label, "content_id": seg.content.content_id,
            "duplicate_of": None if dup is None else {"video": f"raw_{dup.video:04d}.mp4", "segment": dup.segment,
                                                      "transform": dup.transform}})
    return {"format": TRUTH_FORMAT, "video": name, "seed": plan.seed, "index": plan.index, "fps": plan.fps,
            "width": width, "height": height, "n_frames": plan.n_frames, "cuts": plan.cuts,
            "transitions": [{"kind": t.kind, "start": t.start, "end": t.end} for t in plan.transitions],
            "segments": segments}


CORPUS_NAME = re.compile(r"raw_\d{4}(\.truth\.json|\.mp4)")


def check_folder(folder: Path, recorded: Callable[[list[Path]], set[Path]]) -> None:
    """InvalidInput when ``folder`` (a seed's corpus folder about to be written) holds what a new
    corpus would overwrite: files of a corpus lineage recorded (another run's, with other
    settings) or files not named as a corpus names its own. Unrecorded corpus files (an
    interrupted run's) are written over."""
    held = sorted(p for p in Path(folder).iterdir()) if Path(folder).is_dir() else []
    theirs = [p.name for p in held if not CORPUS_NAME.fullmatch(p.name)]
    earlier = sorted(p.name for p in recorded([p for p in held if CORPUS_NAME.fullmatch(p.name)]))
    if theirs or earlier:
        shown = ", ".join((theirs or earlier)[:3]) + (" ..." if len(theirs or earlier) > 3 else "")
        why = "files that are not a corpus's" if theirs else "a corpus of other settings (in lineage)"
        raise InvalidInput(f"{folder}: holds {why} ({shown}); a new corpus would overwrite them: choose another "
                           "--seed, or move them aside")


def generate_corpus(root: Path, seed: int, minutes: float, n_videos: int | None = None, width: int = 1280,
                    height: int = 720, fps: float = 30.0, sim_fraction: float = 0.3,
                    config: CorpusConfig = CorpusConfig(),
                    manifests: Sequence[ScenarioManifest] | None = None) -> list[CorpusVideo]:
    """`minutes` of footage in `n_videos` videos (default: one per 2 minutes), reproducible from `seed`."""
    if width % 2 or height % 2 or width < 32 or height < 32:
        raise ValueError(f"corpus size {width}x{height}: width and height must be even and at least 32")
    total = round(minutes * 60 * fps)
    n_videos = n_videos or max(1, math.ceil(minutes / VIDEO_MINUTES))
    per = [total // n_videos + (1 if i < total % n_videos else 0) for i in range(n_videos)]
    sims = list(manifests if manifests is not None else default_manifests()) if sim_fraction > 0 else []
    plans = plan_corpus(seed, per, fps, config, sims, sim_fraction)
    out = []
    for plan in plans:
        video = paths.resolve(root, paths.CORPUS_VIDEO, seed=seed, index=plan.index)
        truth = paths.resolve(root, paths.CORPUS_TRUTH, seed=seed, index=plan.index)
        frames = progress.counted(_frames(plan, width, height, sims, config), progress.CORPUS_FRAMES)  # a terminal bar
        write_mp4(video, frames, fps, config.crf, config.preset)
        tmp = truth.with_name(f".{truth.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(_truth(plan, video.name, width, height), indent=1, sort_keys=True))
        os.replace(tmp, truth)
        used = sorted({manifest_hash(sims[s.content.manifest]) for s in plan.segments if s.content.kind == "sim"})
        out.append(CorpusVideo(video=video, truth=truth, plan=plan, sims=tuple(used)))
    return out


def corpus_lineage(videos: Sequence[CorpusVideo], stage_run_id: str, manifest_hash: str | None,
                   root: Path | None = None) -> LineageBatch:
    """raw_video and ground_truth artifacts; manifest -> raw_video for simulator footage."""
    batch = LineageBatch()
    for v in videos:
        sha = sha256_file(str(v.video))
        vid = raw_video_id(sha)
        uri = str(v.video.relative_to(root)) if root else str(v.video)
        batch.artifacts.append(ArtifactRecord(
            artifact_id=vid, kind="raw_video", uri=uri, sha256=sha, bytes=v.video.stat().st_size,
            manifest_hash=manifest_hash, stage_run_id=stage_run_id,
            attrs={"seed": v.plan.seed, "index": v.plan.index, "frames": v.plan.n_frames, "generated": True}))
        tsha = sha256_file(str(v.truth))
        tid = stable_id("ground_truth", tsha)
        batch.artifacts.append(ArtifactRecord(
            artifact_id=tid, kind="ground_truth", uri=str(v.truth.relative_to(root)) if root else str(v.truth),
            sha256=tsha, bytes=v.truth.stat().st_size, manifest_hash=manifest_hash, stage_run_id=stage_run_id))
        batch.edges.append(EdgeRecord(parent_id=vid, child_id=tid, relation="labelled_by"))
        batch.edges.extend(EdgeRecord(parent_id=h, child_id=vid, relation="footage_from") for h in v.sims)
    return batch
