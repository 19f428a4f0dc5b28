"""One decode of a source video: scenes, the four filters, captions and dedup signatures.

`analyse_video` is the whole per-video analysis; its result is cached on disk (JSON plus an
npz of signatures) under a key of the file's sha256 and the analysis config, so a re-run
decodes nothing.
"""

from __future__ import annotations

import json
import os
import time
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from schemas.manifest import ScenarioManifest
from schemas.records import ClipRecord, clip_id, raw_video_id
from tasks import faults
from tasks.curate import dedup
from tasks.curate.captions import CaptionConfig, CaptionContext, make_captioner
from tasks.curate.config import CurateConfig
from tasks.curate.decode import DecodeReport
from tasks.curate.exact import frames_at
from tasks.curate.filters import run_filters
from tasks.curate.scenes import scenes_of
from tasks.guard.text import scan_text
from tasks.video import DecodeError, probe


@dataclass
class VideoAnalysis:
    """Every span judged in one source video; `signatures` only for clips the filters kept."""

    source: str
    sha256: str
    bytes: int
    clips: list[ClipRecord] = field(default_factory=list)
    signatures: dict[str, dedup.ClipSignature] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    decode: dict = field(default_factory=dict)
    transitions: int = 0
    seconds: float = 0.0

    @property
    def source_id(self) -> str:
        return raw_video_id(self.sha256)


@lru_cache(maxsize=4)
def _captioner(config: CaptionConfig):
    return make_captioner(config)


def analyse_video(path: Path, sha256: str, config: CurateConfig = CurateConfig(),
                  manifest: ScenarioManifest | None = None, manifest_hash: str | None = None) -> VideoAnalysis:
    """Decode `path` once and judge every span. Raises DecodeError for an unreadable input."""
    t0 = time.perf_counter()
    path = Path(path)
    info = probe(path)
    result = VideoAnalysis(source=str(path), sha256=sha256, bytes=path.stat().st_size,
                           info=info.model_dump(mode="json"))
    report = DecodeReport()
    captioner = _captioner(config.captions)
    context = CaptionContext(manifest=manifest)
    fps = info.fps
    for span in scenes_of(path, config.scenes, config.analysis, report, info):
        if span.kind == "transition":
            result.transitions += 1
            continue
        base = dict(clip_id=clip_id(sha256, span.start_frame, span.end_frame), source_id=result.source_id,
                    source_uri=str(path), start_frame=span.start_frame, end_frame=span.end_frame,
                    start_s=span.start_s, end_s=span.end_s, fps=fps, width=info.display_width,
                    height=info.display_height, manifest_hash=manifest_hash)
        if span.kind == "too_short" or span.frames is None or len(span.frames) < 2:
            result.clips.append(ClipRecord(**base, kept=False, reject_stage="split", reject_reason="too_short",
                                           scores={"duration_s": span.duration}))
            continue
        verdict, _ = run_filters(span.frames, span.times, config.filters())
        scores = {k: v for k, v in verdict.scores.items() if np.isfinite(v)}
        clip = ClipRecord(**base, scores=scores, tags=verdict.tags, kept=verdict.keep,
                          reject_stage=verdict.stage, reject_reason=verdict.reason)
        if verdict.keep:
            signature = dedup.signature(span.frames, config.dedup, positions=span.indices - span.start_frame,
                                        length=span.end_frame - span.start_frame)
            result.signatures[clip.clip_id] = signature
            caption = captioner.caption(span.frames, clip, context)
            clip = clip.model_copy(update={"phash": signature.phash, "caption": caption})
            if blocked := scan_text(caption, config.guard):  # the pre-guard on what a captioner wrote
                del result.signatures[clip.clip_id]
                clip = clip.model_copy(update={
                    "kept": False, "reject_stage": "guard_text", "reject_reason": "blocked_term",
                    "scores": {**clip.scores, "guard_text_matches": float(len(blocked))},
                    "tags": (*clip.tags, *(f"blocked:{m.term}" for m in blocked))})
        result.clips.append(clip)
    if report.frames == 0:
        raise DecodeError(f"{path}: no decodable frames ({'; '.join(report.problems) or 'empty stream'})")
    result.decode = {"frames": report.frames, "unreferenced": report.unreferenced,
                     "corrupt": report.corrupt, "missing": report.missing,
                     "decode_errors": report.decode_errors, "truncated": report.truncated,
                     "problems": report.problems[:20],
                     "smeared": len(report.smeared), "smeared_frames": report.smeared[:20]}
    result.seconds = time.perf_counter() - t0
    return result


def exact_signatures(spans: Mapping[str, tuple[str | Path, int, int]],
                     config: CurateConfig = CurateConfig()) -> dict[str, dedup.ClipSignature]:
    """Signatures from exactly the frames they sample, for ``dedup.group(exact=...)``.

    spans: clip id -> (source video, start frame, end frame). Each source is opened once and
    only the sampled frames and what they are predicted from are decoded. A source that can no
    longer be decoded gives no signatures (its clips keep the ones from the analysis pass).
    """
    by_source: dict[str, list[str]] = defaultdict(list)
    for cid, (source, _, _) in spans.items():
        by_source[str(source)].append(cid)
    out = {}
    for source, ids in by_source.items():
        wanted = {cid: spans[cid][1] + dedup.sample_positions(spans[cid][2] - spans[cid][1], config.dedup)
                  for cid in ids}
        try:
            frames = frames_at(source, np.unique(np.concatenate([w.ravel() for w in wanted.values()])),
                               config.analysis)
        except DecodeError:
            continue
        for cid in ids:
            have = [int(i) for i in np.unique(wanted[cid]) if int(i) in frames]
            if have:
                start, end = spans[cid][1], spans[cid][2]
                out[cid] = dedup.signature(np.stack([frames[i] for i in have]), config.dedup,
                                           positions=np.asarray(have) - start, length=end - start)
    return out


def clip_spans(clips: Iterable[ClipRecord]) -> dict[str, tuple[str | Path, int, int]]:
    """clip id -> (source video, start frame, end frame), as ``exact_signatures`` takes them."""
    return {c.clip_id: (c.source_uri, c.start_frame, c.end_frame) for c in clips}


def exact_for(spans: Mapping[str, tuple[str | Path, int, int]], config: CurateConfig = CurateConfig(),
              found: dict[str, dedup.ClipSignature] | None = None):
    """``dedup.group``'s ``exact`` callback for these spans (see ``clip_spans``). What it decodes
    goes into ``found`` (for the caller to keep), and a clip found already is not decoded again."""
    found = {} if found is None else found

    def exact(ids: list[str]) -> dict[str, dedup.ClipSignature]:
        found.update(exact_signatures({cid: spans[cid] for cid in ids if cid in spans and cid not in found}, config))
        return {cid: found[cid] for cid in ids if cid in found}

    return exact


def _atomic_write(path: Path, data: bytes) -> None:
    """Write through a temporary renamed into place; the temporary is gone on every way out, and
    a full disk stops the run (``EnvironmentFault``) rather than blaming the video."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with faults.fatal_when_disk_full(tmp, "saving the analysis"):
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            tmp.write_bytes(data)
            faults.point("analysis", tmp)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)


def save(analysis: VideoAnalysis, json_path: Path) -> None:
    """The analysis as JSON plus an .npz of signatures beside it (npz first: JSON is the marker)."""
    import io

    buf = io.BytesIO()
    arrays = {}
    for cid, sig in analysis.signatures.items():
        arrays[f"{cid}.hashes"] = sig.hashes
        arrays[f"{cid}.thumbs"] = sig.thumbs
        arrays[f"{cid}.exact"] = np.asarray(sig.exact)
    np.savez(buf, **arrays)
    _atomic_write(json_path.with_suffix(".npz"), buf.getvalue())
    body = {"source": analysis.source, "sha256": analysis.sha256, "bytes": analysis.bytes,
            "info": analysis.info, "decode": analysis.decode, "transitions": analysis.transitions,
            "seconds": analysis.seconds, "clips": [c.model_dump(mode="json") for c in analysis.clips]}
    _atomic_write(json_path, json.dumps(body, sort_keys=True).encode())


def load(json_path: Path) -> VideoAnalysis | None:
    """A cached analysis, or None when it is missing or unreadable (then it is redone)."""
    try:
        body = json.loads(json_path.read_text())
        with np.load(json_path.with_suffix(".npz")) as arrays:
            clips = [ClipRecord.model_validate(c) for c in body["clips"]]
            signatures = {c.clip_id: dedup.ClipSignature(hashes=arrays[f"{c.clip_id}.hashes"],
                                                         thumbs=arrays[f"{c.clip_id}.thumbs"],
                                                         exact=bool(arrays[f"{c.clip_id}.exact"]))
                          for c in clips if c.kept}
    except (OSError, ValueError, KeyError):
        return None
    return VideoAnalysis(source=body["source"], sha256=body["sha256"], bytes=body["bytes"], clips=clips,
                         signatures=signatures, info=body["info"], decode=body["decode"],
                         transitions=body["transitions"], seconds=body["seconds"])
